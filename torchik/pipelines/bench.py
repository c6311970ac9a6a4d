"""`torchik bench`: subject-steps per second of the whole tracking step, batched, against the
per-subject loops a user could assemble from existing libraries today.

For each model (Human66, Human48, iCub) and batch size B, the tracker (kinematics, residuals, the
constrained QP with the batched backend, integration) steps B subjects through a walking-like
motion (`periodic_motion`, every subject with its own phases), and the throughput is B times the
steps per second. With --compile each batch size's step is measured a second time captured and
replayed (``torchik batched compiled``, `TrackerSettings(compile=True)`; from 32 subjects solved on
the joints' tree; the capture, made during the warm-up, is reported below the table, not timed).
In the same run, one subject at a time:

- ``torchik+piqp``: torchik's tracker for one subject with the PIQP backend (qpsolvers);
- ``torchik compiled``: the same with its usual step captured and replayed compiled
  (`TrackerSettings(compile=True)`; the capture's seconds are reported, not timed);
- ``pinocchio+daqp`` and ``pinocchio+piqp``: pinocchio's kinematics (forwardKinematics,
  computeJointJacobians, frame Jacobians in LOCAL_WORLD_ALIGNED), the same residuals, gains,
  damping and tanh velocity bounds (and iCub's coupled rows), the QP by daqp or PIQP through
  qpsolvers, and pinocchio's integrate on the configuration manifold: the fastest CPU pipeline
  we could assemble from existing libraries.

The pinocchio loop uses torchik's residual and feed-forward (the second-order scheme's) but the
Jacobian at the step's start, not mid-step (which would cost a second kinematics pass): a cheaper
step than torchik's, tracking to about 1e-5 MNTE where torchik reaches 1e-9. Every pipeline's final
orientation error is printed beside its speed, so the comparison is between working pipelines.
The loops run on one torch thread, as pinocchio does: one subject's operations are too small for
threads to pay, and on a shared machine waiting threads cost more than they bring. Every step,
batched or looped, is timed alone (its targets made before the clock starts): the table gives a
step's median, 99th percentile and mean, the subject-steps per second at the median and at the mean
(B over the step's time), and the ratio to the best peer loop of the subject-steps per second at
the median (`versus_best_peer`). The line below the table comparing torchik's compiled step with
the best peer's, one subject, is that same ratio (a mean also carries the rare slow steps, a bound
solved by the QP solver or the machine's other work, which a median leaves out).
Results: a table on stdout and, with --json, a file.

    torchik bench [--models human66 human48 icub] [--batch 1 64 1024 8192] [--json bench.json]
    python experiments/bench_step.py ...   (the same)
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import optional
from ..method.capture import CaptureError
from ..method.models import MODELS
from ..method.qp import BatchedBackend
from ..method.settings import TrackerSettings

if TYPE_CHECKING:
    from ..method.tracker import DynamicalIK

BATCHES = (1, 64, 1024, 8192)
LOOPS = ("torchik+piqp", "torchik compiled", "pinocchio+daqp", "pinocchio+piqp")
GAIN, DAMPING, RATE = TrackerSettings.position_gain, TrackerSettings.damping, 100.0


@dataclass
class Measurement:
    model: str
    pipeline: str  # "torchik batched" or one of LOOPS
    batch: int
    steps: int
    seconds: float  # the timed steps' time, summed (each step timed alone)
    subject_steps_per_second: float  # batch * steps / seconds: at the mean step
    active_constraints_per_subject: float | None = None  # mean over the timed steps
    iterations_mean: float | None = None  # batched backend: active-set iterations per step
    rescued_fraction: float | None = None  # batched backend: subjects solved by the interior point
    unsolved_fraction: float | None = None  # subjects that fell back to the clipped velocity
    final_mnte: float | None = None  # the tracking error at the end, to show the pipeline works
    median_step_ms: float | None = None  # a step's median and 99th percentile (ms)
    p99_step_ms: float | None = None
    compile_seconds: float | None = None  # torchik compiled: the capture's time (before the timed steps)


def _motion(model, batch: int, steps: int, seed: int = 0):
    from ..synthetic.motion import periodic_motion

    return periodic_motion(model, (steps + 1) / RATE, RATE, batch=batch, seed=seed, dtype=model.dtype)


def bench_batched(name: str, batch: int, device: str, dtype, min_seconds: float, max_steps: int,
                  warmup: int = 5, compiled: bool = False) -> Measurement:
    """The tracker's whole step for `batch` subjects at once; timed over up to `max_steps` steps
    or `min_seconds`, whichever comes first, after `warmup` steps. compiled: the step captured and
    replayed (`TrackerSettings(compile=True)`; captured during the warm-up, its seconds reported).
    A replayed step's QP is its unconstrained minimiser, one factorisation: one iteration; where a
    bound is active the backend goes on from it and counts it as its first iteration."""
    # enough steps for min_seconds at a first guess of the speed (1e5 subject-steps/s on a CPU, 3e6 on
    # a GPU), at most max_steps: every step's targets are made before the timing starts
    guess = 3e6 if torch.device(device).type == "cuda" else 1e5
    max_steps = max(3, min(max_steps, int(guess * min_seconds / batch) + 1))
    tracker, sequence = prepared_tracker(name, batch, device, dtype, warmup + max_steps, warmup, compiled)
    solver = tracker.backend
    assert isinstance(solver, BatchedBackend)  # asked for: its iterations are measured
    _synchronize(device)
    iterations, rescued, active, unsolved, steps = 0, 0, 0.0, 0, 0
    times: list[float] = []
    targets = [sequence[warmup + k] for k in range(max_steps)]  # sliced before the clock starts
    start = time.perf_counter()
    while steps < max_steps:
        step_start = time.perf_counter()
        _, diagnostics = tracker.step(targets[steps])
        _synchronize(device)
        times.append(time.perf_counter() - step_start)
        steps += 1
        replayed = compiled and math.isnan(diagnostics.kinematics_time)
        solved = not math.isnan(diagnostics.qp_time)  # the backend ran (else its counters are an earlier step's)
        # a replayed step's backend counts the captured factorisation as its first iteration
        iterations += solver.iterations if solved else replayed
        rescued += solver.rescued if solved else 0
        active += float(diagnostics.active_constraints.double().mean())
        unsolved += int((~diagnostics.solved).sum())
        if time.perf_counter() - start > min_seconds:
            break
    seconds, captured = sum(times), tracker.captured
    return Measurement(name, "torchik batched compiled" if compiled else "torchik batched", batch, steps, seconds,
                       batch * steps / seconds, active / steps, iterations / steps, rescued / (batch * steps),
                       unsolved / (batch * steps), float(diagnostics.mnte.max()), **_percentiles(times),
                       compile_seconds=None if captured is None else captured.compile_seconds)


def prepared_tracker(name: str, batch: int, device: str, dtype, steps: int, warmup: int, compiled: bool = False):
    """The batched tracker of model `name` for `batch` subjects of the walking motion (its step
    captured and replayed if `compiled`), after `warmup` of its `steps` steps, and the motion's targets."""
    from ..method.models import TRACKED_LINKS, load_model
    from ..method.tracker import DynamicalIK

    model, links = load_model(name, dtype=dtype, device=device), TRACKED_LINKS[name]
    motion = _motion(model, batch, steps)
    sequence = _targets(model, motion, links, device)
    tracker = DynamicalIK(model, links, position_gain=GAIN, orientation_gain=GAIN, dt=1 / RATE, damping=DAMPING,
                          backend="batched", compile=compiled)
    state = motion.state(0)
    tracker.reset(type(state)(*(x.to(device) for x in vars(state).values())), batch=batch)
    for k in range(warmup):
        tracker.step(sequence[k])
    _require_capture(tracker, compiled)
    return tracker, sequence


def _require_capture(tracker: DynamicalIK, compiled: bool) -> None:
    """Raises where a compiled pipeline's step could not be captured: its steps would run eagerly
    under the compiled pipeline's name."""
    if compiled and (tracker.captured is None or tracker.captured.unavailable):
        raise CaptureError("--compile: the step could not be captured here (the warning above says why), "
                           "so no compiled figure can be measured; run without --compile")


def _targets(model, motion, links, device: str):
    """The motion's targets on `device`."""
    from ..synthetic.motion import Motion, targets_from_motion

    motion = Motion(*(x.to(model.device) for x in vars(motion).values()))
    return targets_from_motion(model, motion, links)


@contextlib.contextmanager
def _threads(count: int):
    """torch on `count` threads for the block."""
    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _synchronize(device: str) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def bench_torchik_loop(name: str, steps: int, warmup: int = 10, compiled: bool = False) -> Measurement:
    """torchik's tracker for one subject with the PIQP backend, step after step; compiled: its usual
    step replayed compiled (captured during the warm-up)."""
    from ..method.models import TRACKED_LINKS, load_model
    from ..method.tracker import DynamicalIK
    from ..synthetic.motion import targets_from_motion

    model, links = load_model(name), TRACKED_LINKS[name]
    motion = _motion(model, 1, warmup + steps)
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, position_gain=GAIN, orientation_gain=GAIN, dt=1 / RATE, damping=DAMPING,
                          backend="piqp", compile=compiled)
    tracker.reset(motion.state(0), batch=1)
    targets = [sequence[k] for k in range(warmup + steps)]  # sliced before the clock starts, as pinocchio's arrays
    for k in range(warmup):
        tracker.step(targets[k])
    _require_capture(tracker, compiled)
    active, times = [], []
    for k in range(warmup, warmup + steps):
        start = time.perf_counter()
        _, diagnostics = tracker.step(targets[k])
        times.append(time.perf_counter() - start)
        active.append(diagnostics.active_constraints)
    captured = tracker.captured
    return Measurement(name, "torchik compiled" if compiled else "torchik+piqp", 1, steps, sum(times),
                       steps / sum(times), float(torch.cat(active).double().mean()),
                       final_mnte=float(diagnostics.mnte.max()), **_percentiles(times),
                       compile_seconds=None if captured is None else captured.compile_seconds)


def _percentiles(times: list[float]) -> dict:
    """A step's median and 99th percentile in ms."""
    ms = 1e3 * np.asarray(times)
    return dict(median_step_ms=float(np.median(ms)), p99_step_ms=float(np.percentile(ms, 99)))


def bench_pinocchio_loop(name: str, solver: str, steps: int, warmup: int = 10) -> Measurement:
    from ..method.models import TRACKED_LINKS
    from ..synthetic.motion import targets_from_motion
    from .bench_pinocchio import PinocchioTracker

    tracker = PinocchioTracker(name, solver, GAIN, DAMPING)
    motion = _motion(tracker.ours, 1, warmup + steps + 1)
    sequence = targets_from_motion(tracker.ours, motion, TRACKED_LINKS[name])
    as_numpy = lambda x: x[:, 0].numpy()  # noqa: E731
    p, v = as_numpy(sequence.position)[:, 0], as_numpy(sequence.linear_velocity)[:, 0]
    R, w = as_numpy(sequence.rotation), as_numpy(sequence.angular_velocity)
    q = tracker.configuration(motion.base_position[0, 0].numpy(), motion.base_rotation[0, 0].numpy(),
                              motion.joint_positions[0, 0].numpy())
    dt = 1 / RATE
    # torchik's second-order scheme: q at sample k-1 against the targets of k-1, the mean velocity
    # of k-1 and k fed forward; q then estimates sample k
    mean = lambda x, k: (x[k - 1] + x[k]) / 2  # noqa: E731
    for k in range(1, warmup + 1):
        q = tracker.step(q, p[k - 1], mean(v, k), R[k - 1], mean(w, k), dt)
    times = []
    for k in range(warmup + 1, warmup + steps + 1):
        start = time.perf_counter()
        q = tracker.step(q, p[k - 1], mean(v, k), R[k - 1], mean(w, k), dt)
        times.append(time.perf_counter() - start)
    error = tracker.orientation_error(q, R[warmup + steps])
    return Measurement(name, f"pinocchio+{solver}", 1, steps, sum(times), steps / sum(times), final_mnte=error,
                       **_percentiles(times))


def run(models=MODELS, batches=BATCHES, device: str = "cpu", dtype=torch.float64, loops: bool = True,
        loop_steps: int = 200, min_seconds: float = 2.0, max_steps: int = 50, progress: bool = True,
        compiled: bool = False) -> list[Measurement]:
    """Every measurement of the benchmark, in the order of the table (with `compiled`, each batch
    size's captured step after its eager one)."""
    import qpsolvers

    batched = ("batched", "batched compiled") if compiled else ("batched",)
    plan = [(name, kind, B) for name in models for B in batches for kind in batched]
    if loops:  # before any measurement: a missing library is said at once
        optional("pinocchio", "bench", "torchik bench's per-subject loops (or --no-loops)")
        plan += [(name, loop, 1) for name in models for loop in LOOPS
                 if loop.startswith("torchik") or loop.split("+")[1] in qpsolvers.available_solvers]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(plan), desc="bench", unit="run", leave=False)
    results = []
    for name, pipeline, B in plan:
        if bar is not None:
            bar.set_postfix_str(f"{name} {pipeline} B={B}")
            bar.update()
        if pipeline.startswith("batched"):
            results.append(bench_batched(name, B, device, dtype, min_seconds, max_steps,
                                         compiled=pipeline == "batched compiled"))
        elif pipeline.startswith("torchik"):
            with _threads(1):
                results.append(bench_torchik_loop(name, loop_steps, compiled=pipeline == "torchik compiled"))
        else:
            with _threads(1):
                results.append(bench_pinocchio_loop(name, pipeline.split("+")[1], loop_steps))
    if bar is not None:
        bar.close()
    return results


def versus_best_peer(results: list[Measurement]) -> dict[tuple[str, str, int], tuple[str, float]]:
    """Per measurement (model, pipeline, batch): the best peer loop of its model (the pinocchio loop
    with the shortest median step) and the ratio of the measurement's subject-steps per second at its
    median step to that loop's (B times the peer's median step over the measurement's). The table's
    "vs best peer" column and its one-subject lines both read this: one quantity, the median step."""
    best: dict[str, Measurement] = {}
    for r in results:
        if r.pipeline.startswith("pinocchio") and r.median_step_ms:
            if r.model not in best or r.median_step_ms < (best[r.model].median_step_ms or math.inf):
                best[r.model] = r
    ratios = {}
    for r in results:
        peer = best.get(r.model)
        if peer is not None and peer.median_step_ms and r.median_step_ms:
            ratios[(r.model, r.pipeline, r.batch)] = (peer.pipeline, r.batch * peer.median_step_ms / r.median_step_ms)
    return ratios


def table(results: list[Measurement]) -> str:
    """The measurements as a table: a step's median, 99th percentile and mean, the subject-steps per
    second at the median and at the mean, and the ratio at the median to the best peer loop
    (pinocchio's, assembled from existing libraries; `versus_best_peer`); then one line per model
    comparing torchik's compiled step, one subject, with that peer's: the same ratio."""
    lines = [f"{'model':8s} {'pipeline':24s} {'B':>6s} {'p50 ms':>8s} {'p99 ms':>8s} {'mean ms':>8s} "
             f"{'subj-steps/s p50':>16s} {'mean':>10s} {'vs best peer p50':>16s} {'active/subj':>11s} {'iters':>6s} "
             f"{'rescued':>8s} {'final MNTE':>10s}"]
    fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    ratios = versus_best_peer(results)
    for r in results:
        mean_ms = 1e3 * r.seconds / r.steps
        at_median = None if not r.median_step_ms else 1e3 * r.batch / r.median_step_ms
        ratio = ratios.get((r.model, r.pipeline, r.batch))
        lines.append(f"{r.model:8s} {r.pipeline:24s} {r.batch:>6d} {fmt(r.median_step_ms, '.3f'):>8s} "
                     f"{fmt(r.p99_step_ms, '.3f'):>8s} {mean_ms:>8.3f} {fmt(at_median, ',.0f'):>16s} "
                     f"{r.subject_steps_per_second:>10,.0f} {'-' if ratio is None else f'{ratio[1]:.2f}x':>16s} "
                     f"{fmt(r.active_constraints_per_subject, '.2f'):>11s} {fmt(r.iterations_mean, '.2f'):>6s} "
                     f"{fmt(r.rescued_fraction, '.1%'):>8s} {fmt(r.final_mnte, '.1e'):>10s}")
    lines.append("p50, p99, mean: a step's median, 99th percentile and mean over the timed steps, each timed alone; "
                 "subj-steps/s: B over the median step (p50) and over the mean one (mean); vs best peer p50: the "
                 "subject-steps/s at the median over the fastest pinocchio loop's")
    captures = [f"{r.model} B={r.batch} {fmt(r.compile_seconds, '.1f')} s" for r in results
                if r.pipeline == "torchik batched compiled"]
    if captures:
        lines.append("batched compiled, the capture's time (not timed): " + ", ".join(captures))
    by = {(r.model, r.pipeline, r.batch): r for r in results}
    for model in dict.fromkeys(r.model for r in results):
        ours = by.get((model, "torchik compiled", 1))
        ratio = ratios.get((model, "torchik compiled", 1))
        if ours is None or ratio is None:
            continue
        peer = by[(model, ratio[0], 1)]
        lines.append(f"{model}, one subject: torchik compiled {ours.median_step_ms:.3f} ms median step (p99 "
                     f"{ours.p99_step_ms:.3f}), best peer {peer.pipeline} {peer.median_step_ms:.3f} ms: {ratio[1]:.2f}x "
                     f"(the table's vs best peer p50; capture {fmt(ours.compile_seconds, '.1f')} s)")
    return "\n".join(lines)

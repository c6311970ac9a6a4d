"""`torchik experiment paper`: the paper's comparison of dynamical IK with instantaneous IK.

On the same data, three models (Human66, Human48, and iCub through the human-to-iCub map) track
three motions (a held T-pose, walking at 4 km/h, running at 10 km/h) with four methods:

- whole-body instantaneous IK (`WholeBodyIK`: constrained Gauss-Newton to convergence every step);
- pair-wise instantaneous IK (`PairwiseIK`: one small problem per pair of adjacent targets);
- dynamical IK (`DynamicalIK`), in the paper's literal discretisation and in the default
  second-order one ('midpoint').

The data are one person's: the built-in scenarios generated on Human66 (the full human model),
read by Human66 and Human48 as they are and by iCub through `models/maps/human_to_icub.toml`,
or recordings given with --data (through --map first when their segments are not the human
models' links). Human48 (fewer axes, clinical limits) and iCub (another body) cannot reach every
target: their errors have a floor that any method meets at best.

Every method starts from the same state (the zero configuration, the base at its first target),
uses the same QP backend (default 'batched': torch, one call per QP batch, also the pairs' batch;
PIQP per problem with --backend piqp) on one thread (one subject's problems are too small to gain
from more, and on a shared machine extra threads only wait for each other), gains K = 20 1/s.
Per-step time is the whole step (the dynamical step, or all iterations of an instantaneous solve)
in processor time of the process: what the step computes, which other programs on a shared
machine do not inflate as they do wall-clock time (results.csv has the wall-clock times too).
Each method runs twice and each step counts with its faster time, with Python's garbage collector
paused (as timeit does): interference from elsewhere is not the method's. Statistics are taken
after the first 2 s, as in the paper. Velocities of the instantaneous methods
are central differences of their solutions; the midpoint scheme's are centred too.

Outputs in DIR: results.csv and results.md (the table, the ratios of dynamical to instantaneous
IK and where the paper's expected shape holds), box_mnte.png, box_rmse.png, box_time.png (per
model, scenario and method), convergence.png (MNTE from the zero configuration to a static T-pose
for several gains, one beyond the stability bound K dt < 2), phase_plane.png (an iCub elbow's
angle and rate with the tanh velocity bounds).
"""

from __future__ import annotations

import csv
import gc
import platform
import time
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from ..method.baselines import PairwiseIK, WholeBodyIK
from ..errors import InputError
from ..io.maps import apply_map, load_map
from ..io.recording import Recording
from ..method.kinematics import KinematicModel
from ..method.limits import LimitSettings, velocity_bounds
from ..method.metrics import after_transient, angular_velocity_rmse, mnte
from ..method.models import MODELS, TRACKED_LINKS, load_model
from ..io.targets import recording_targets
from ..synthetic.scenarios import SCENARIOS, scenario
from ..method.tracker import DynamicalIK
from .retarget import human_to_icub
from ..method.state import TargetSequence, Trajectory

METHODS = ("whole-body", "pair-wise", "dynamical (paper)", "dynamical (midpoint)")
DYNAMICAL = {"dynamical (paper)": "paper", "dynamical (midpoint)": "midpoint"}
PERSON = "human66"  # the model the built-in scenarios are generated on: the person being tracked
# 1/s; at 100 Hz K dt = 0, 0.05, 0.2, 1 (one step), 1.9 (oscillating), 2.2 (unstable); the error
# shrinks by |1 - K dt| per step, so no two of these share a rate
CONVERGENCE_GAINS = (0.0, 5.0, 20.0, 100.0, 190.0, 220.0)
NAMES = {"human66": "Human66", "human48": "Human48", "icub": "iCub"}
OUTPUTS = ("results.csv", "results.md", "box_mnte.png", "box_rmse.png", "box_time.png", "convergence.png",
           "phase_plane.png")


@dataclass(frozen=True)
class Settings:
    """duration (s) and rate (Hz) of the built-in scenarios; transient: seconds left out of the
    statistics; gain: K (1/s) of the dynamical method for positions and orientations; backend: the
    QP backend of every method; tolerance, step_tolerance, max_iterations: the instantaneous
    methods' stopping rule (see WholeBodyIK); threads: torch's threads while timing; repeats: runs
    of each method, each step timed by its fastest; seed; convergence_seconds: length of the
    convergence runs to a static T-pose."""

    duration: float = 10.0
    rate: float = 100.0
    transient: float = 2.0
    gain: float = 20.0
    backend: str = "batched"
    tolerance: float = 1e-10
    step_tolerance: float = 1e-6
    max_iterations: int = 50
    threads: int = 1
    repeats: int = 2
    seed: int = 0
    convergence_seconds: float = 3.0


@dataclass(frozen=True)
class Case:
    """One model tracking one motion: the recording in the model's link names."""

    model: str
    scenario: str
    recording: Recording
    links: tuple[str, ...]


@dataclass
class Run:
    """One method on one case: per-sample time [T], mnte [T], rmse [T] (rad/s), step_time [T] (s of
    processor time: the whole step, or every iteration of an instantaneous solve), iterations [T]
    (ones for the dynamical method), the trajectory, and wall_time [T] (s, wall clock)."""

    model: str
    scenario: str
    method: str
    time: torch.Tensor
    mnte: torch.Tensor
    rmse: torch.Tensor
    step_time: torch.Tensor
    iterations: torch.Tensor
    trajectory: Trajectory = field(repr=False)
    wall_time: torch.Tensor | None = None


# ---------------------------------------------------------------------------------------- data
@lru_cache(maxsize=None)
def _model(name: str) -> KinematicModel:
    """The default models, built once (a human model's URDF takes half a second to generate)."""
    return load_model(name)


def scenario_cases(settings: Settings, models=MODELS, scenarios=tuple(SCENARIOS)) -> list[Case]:
    """The built-in scenarios generated on the person (Human66), for each model."""
    person = _model(PERSON)
    motions = {name: scenario(name, person, TRACKED_LINKS[PERSON], settings.duration, settings.rate, settings.seed)
               for name in scenarios}
    return [case for name, recording in motions.items() for case in _model_cases(name, recording, models)]


def data_cases(paths, models=MODELS, map_name: str | None = None, calibration_frame=None) -> list[Case]:
    """Recordings (any format `torchik track` reads), through `map_name` to the human models'
    links when given, for each model; the scenario is the file's name."""
    from ..io import read

    cases = []
    for path in paths:
        recording = read(str(path))
        if map_name:
            recording = apply_map(recording, load_map(map_name), _model(PERSON), calibration_frame)
        cases += _model_cases(Path(path).stem, recording, models)
    return cases


def _model_cases(name: str, recording: Recording, models) -> list[Case]:
    cases = []
    for model_name in models:
        if model_name == "icub":
            mapped = human_to_icub(recording, _model("icub"))
            cases.append(Case(model_name, name, mapped, mapped.links))
            continue
        if recording.base_link != "Pelvis" or "Pelvis" not in recording.links:
            raise InputError(f"{name}: the human models need the Pelvis as base and target; the recording's links "
                             f"are {list(recording.links)} (give --map to convert them)")
        cases.append(Case(model_name, name, recording, recording.links))
    return cases


# ---------------------------------------------------------------------------------------- runs
def link_motion(model: KinematicModel, trajectory: Trajectory, links, centred: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Link rotations [T,L,3,3] and world angular velocities [T,L,3] of subject 0 of a trajectory:
    omega_L = omega_B + sum_j M_Lj s_dot_j a_j. centred: the velocity nu_k is the mean over
    [t_{k-1}, t_k] (the midpoint scheme), and the estimate at t_k the mean of the two around it."""
    nu = trajectory.velocity[:, 0]
    if centred and len(nu) > 1:
        nu = torch.cat((0.5 * (nu[:-1] + nu[1:]), nu[-1:]))
    mask = model.select(tuple(links)).ancestor_mask  # [L,n]
    with torch.inference_mode():
        kin = model(trajectory.base_position[:, 0].clone(), trajectory.base_rotation[:, 0].clone(),
                    trajectory.joint_positions[:, 0].clone(), tuple(links), jacobian=False, joint_axes=True)
        omega = nu[:, None, 3:6] + mask @ (nu[:, 6:, None] * kin.joint_axes)
    return kin.rotation.clone(), omega.clone()


def errors(model: KinematicModel, trajectory: Trajectory, sequence: TargetSequence, links,
           centred: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """MNTE [T] and angular-velocity RMSE [T] against the targets; NaN where a target is missing."""
    R_hat, w_hat = link_motion(model, trajectory, links, centred)
    R, w = sequence.rotation[:, 0], sequence.angular_velocity[:, 0]
    known = torch.isfinite(R).flatten(-3).all(-1) & torch.isfinite(w).flatten(-2).all(-1)
    nan = torch.tensor(float("nan"), dtype=R.dtype)
    eye = torch.eye(3, dtype=R.dtype)
    R = torch.where(known[:, None, None, None], R, eye)
    w = torch.where(known[:, None, None], w, 0.0)
    return (torch.where(known, mnte(R, R_hat), nan), torch.where(known, angular_velocity_rmse(w, w_hat), nan))


def run_method(case: Case, method: str, settings: Settings) -> Run:
    """Track `case` with `method`, every method from the tracker's initial state."""
    model = _model(case.model)
    sequence = recording_targets(case.recording, case.links, dtype=model.dtype, device=model.device)
    dt = float(np.median(np.diff(case.recording.time))) if len(case.recording.time) > 1 else 1.0 / settings.rate
    tracker = DynamicalIK(model, case.links, position_gain=settings.gain, orientation_gain=settings.gain, dt=dt,
                          scheme=DYNAMICAL.get(method, "midpoint"), backend=settings.backend)
    initial = tracker.initial_state(sequence[0])
    cpu = []
    if method in DYNAMICAL:
        tracker.step = _cpu_timed(tracker.step, cpu)
        trajectory = tracker.run(sequence, initial, progress=False)
        iterations = torch.ones(len(sequence), dtype=torch.long)
    else:
        kind = WholeBodyIK if method == "whole-body" else PairwiseIK
        ik = kind(model, case.links, tolerance=settings.tolerance, step_tolerance=settings.step_tolerance,
                  max_iterations=settings.max_iterations, backend=settings.backend)
        ik.solve = _cpu_timed(ik.solve, cpu)
        trajectory = ik.run(sequence, initial)
        iterations = trajectory.diagnostics["iterations"][:, 0]
    error, rmse = errors(model, trajectory, sequence, case.links, centred=DYNAMICAL.get(method) == "midpoint")
    return Run(case.model, case.scenario, method, sequence.time, error, rmse, torch.tensor(cpu, dtype=torch.float64),
               iterations, trajectory, trajectory.diagnostics["step_time"])


def timed_run(case: Case, method: str, settings: Settings) -> Run:
    """`run_method` `settings.repeats` times, each step's time the least of its repeats, with
    Python's garbage collector paused, as timeit does. A step does the same work in every repeat
    (the methods are deterministic); what varies is interference: other programs on the machine,
    or a collection landing on whichever step allocates the object that triggers it. Neither says
    anything about the method, and either would dominate the 99th percentile of the fastest one."""
    runs = []
    for _ in range(settings.repeats):
        gc.collect()
        gc.disable()
        try:
            runs.append(run_method(case, method, settings))
        finally:
            gc.enable()
    run = runs[0]
    run.step_time = torch.stack([r.step_time for r in runs]).amin(0)
    run.wall_time = torch.stack([r.wall_time for r in runs]).amin(0)
    return run


def _cpu_timed(step, times: list):
    """`step` recording the processor time each call takes into `times` (s): the compute time,
    which other programs on a shared machine do not inflate as they do the wall-clock time."""
    def timed(*args, **kwargs):
        began = time.process_time()
        result = step(*args, **kwargs)
        times.append(time.process_time() - began)
        return result

    return timed


def statistics(run: Run, transient: float) -> dict:
    """One row of the table: medians, 99th percentiles and the spread after the transient."""
    pick = lambda v: after_transient(v, run.time, transient).double()  # noqa: E731
    known = lambda v: v[torch.isfinite(v)]  # noqa: E731
    m, r, t = known(pick(run.mnte)), known(pick(run.rmse)), pick(run.step_time) * 1e3
    median = lambda v: float(v.median()) if len(v) else float("nan")  # noqa: E731  (no frame with every target)
    p99 = lambda v: float(v.quantile(0.99)) if len(v) else float("nan")  # noqa: E731
    row = dict(model=run.model, scenario=run.scenario, method=run.method, samples=len(t),
               mnte_median=median(m), mnte_p99=p99(m), rmse_median=median(r), rmse_p99=p99(r),
               time_median_ms=median(t), time_p99_ms=p99(t))
    row["spread"] = row["time_p99_ms"] / row["time_median_ms"]
    wall = pick(run.wall_time) * 1e3
    row["wall_median_ms"], row["wall_p99_ms"] = float(wall.median()), float(wall.quantile(0.99))
    iterations = pick(run.iterations)
    row["iterations_mean"], row["iterations_p99"] = float(iterations.mean()), p99(iterations)
    return row


def ratios(rows: list[dict], scheme: str) -> list[dict]:
    """Per model and scenario: baseline / dynamical step times (median, p99), each method's spread
    (p99/median), MNTE of dynamical / whole-body, and which of the paper's expectations hold."""
    by = {(r["model"], r["scenario"], r["method"]): r for r in rows}
    out = []
    for model, name in dict.fromkeys((r["model"], r["scenario"]) for r in rows):
        dyn, wb, pw = (by.get((model, name, m)) for m in (f"dynamical ({scheme})", "whole-body", "pair-wise"))
        if dyn is None or wb is None or pw is None:
            continue
        item = dict(model=model, scenario=name, scheme=scheme,
                    wb_median=wb["time_median_ms"] / dyn["time_median_ms"], wb_p99=wb["time_p99_ms"] / dyn["time_p99_ms"],
                    pw_median=pw["time_median_ms"] / dyn["time_median_ms"], pw_p99=pw["time_p99_ms"] / dyn["time_p99_ms"],
                    spread_dyn=dyn["spread"], spread_wb=wb["spread"], spread_pw=pw["spread"],
                    mnte_ratio=dyn["mnte_median"] / max(wb["mnte_median"], 1e-300))
        item["faster"] = min(item["wb_median"], item["wb_p99"], item["pw_median"], item["pw_p99"]) > 1.0
        item["steadiest"] = item["spread_dyn"] < min(item["spread_wb"], item["spread_pw"])
        item["accurate"] = item["mnte_ratio"] <= 2.0
        out.append(item)
    return out


# ---------------------------------------------------------------------------------------- figures
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


COLOURS = {"whole-body": "tab:blue", "pair-wise": "tab:orange", "dynamical (paper)": "tab:green",
           "dynamical (midpoint)": "tab:red"}


def _save(fig, path: Path, tight: bool = True) -> Path:
    """Write a figure as PNG and free it."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def box_plots(runs: list[Run], transient: float, out: Path) -> list[Path]:
    """box_mnte.png, box_rmse.png, box_time.png: one panel per model, scenarios along x, a box per method."""
    plt = _pyplot()
    models = list(dict.fromkeys(r.model for r in runs))
    scenarios = list(dict.fromkeys(r.scenario for r in runs))
    methods = [m for m in METHODS if any(r.method == m for r in runs)]
    by = {(r.model, r.scenario, r.method): r for r in runs}
    quantities = (("box_mnte.png", "log10 MNTE", lambda r: torch.log10(r.mnte.clamp(min=1e-30))),
                  ("box_rmse.png", "log10 angular-velocity RMSE (rad/s)", lambda r: torch.log10(r.rmse.clamp(min=1e-30))),
                  ("box_time.png", "step compute time (ms)", lambda r: r.step_time * 1e3))
    width = 0.8 / len(methods)
    written = []
    for filename, label, value in quantities:
        fig, axes = plt.subplots(1, len(models), figsize=(4.5 * len(models), 4), squeeze=False)
        for ax, model in zip(axes[0], models):
            for i, method in enumerate(methods):
                data, positions = [], []
                for j, name in enumerate(scenarios):
                    run = by.get((model, name, method))
                    if run is None:
                        continue
                    v = after_transient(value(run), run.time, transient)
                    data.append(v[torch.isfinite(v)].numpy())
                    positions.append(j + (i - (len(methods) - 1) / 2) * width)
                if data:
                    parts = ax.boxplot(data, positions=positions, widths=width * 0.9, patch_artist=True,
                                       showfliers=True, flierprops=dict(markersize=1.5, alpha=0.4))
                    for box in parts["boxes"]:
                        box.set_facecolor(COLOURS[method])
                        box.set_alpha(0.7)
            ax.set_xticks(range(len(scenarios)), scenarios)
            ax.set_title(NAMES.get(model, model))
            ax.set_ylabel(label)
            if filename == "box_time.png":
                ax.set_yscale("log")
            ax.grid(axis="y", alpha=0.3)
        handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[m], alpha=0.7) for m in methods]
        fig.legend(handles, methods, loc="lower center", ncol=len(methods), frameon=False)
        fig.tight_layout(rect=(0, 0.07, 1, 1))
        written.append(_save(fig, out / filename, tight=False))
    return written


def static_tpose(seconds: float, rate: float, seed: int = 0) -> tuple[KinematicModel, tuple[str, ...], TargetSequence]:
    """Human66 and targets of a person holding a T-pose for `seconds`: the t-pose scenario's first
    frame, each link turned by a seeded random rotation of about 0.1 rad per axis (a person's T-pose
    is not the model's, and sensors sit a little askew), velocities zero."""
    model, links = _model(PERSON), TRACKED_LINKS[PERSON]
    recording = scenario("tpose", model, links, duration=1.0 / rate, rate=rate, seed=seed, orientation_noise=0.1)
    frame = recording_targets(recording, links)
    T = int(round(seconds * rate)) + 1
    still = lambda x: x[:1].expand(T, *x.shape[1:]).clone()  # noqa: E731
    sequence = TargetSequence(torch.arange(T, dtype=torch.float64) / rate, still(frame.position),
                              torch.zeros_like(still(frame.linear_velocity)), still(frame.rotation),
                              torch.zeros_like(still(frame.angular_velocity)))
    return model, links, sequence


def convergence(settings: Settings, seconds: float = 3.0, gains=CONVERGENCE_GAINS) -> dict:
    """MNTE over time from the zero configuration (base at its target) to a static T-pose, for each
    scheme and gain: {(scheme, gain): (time [T], mnte [T])}, the state at the start of each step.

    The base rotation is integrated with the exponential map here: beyond the stability bound the
    base spins at about 1 rad per step (its velocity has no bound, the joints' have), where the
    Baumgarte step leaves SO(3) and the integration breaks down; the exponential map stays on it,
    so the unstable run shows what it does (an error that never settles) to the end. Below the
    bound both integrators give the same curves."""
    model, links, sequence = static_tpose(seconds, settings.rate, settings.seed)
    curves = {}
    for scheme in ("paper", "midpoint"):
        for gain in gains:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # beyond the stability bound on purpose
                tracker = DynamicalIK(model, links, position_gain=gain, orientation_gain=gain, dt=1.0 / settings.rate,
                                      scheme=scheme, rotation_integrator="exp", backend=settings.backend)
            tracker.reset(tracker.initial_state(sequence[0]))
            error = []
            for k in range(len(sequence)):  # time steps
                q = tracker.state
                R_hat = model(q.base_position, q.base_rotation, q.joint_positions, links, jacobian=False).rotation
                error.append(float(mnte(sequence.rotation[k], R_hat)))  # accurate down to 1e-30, unlike the trace
                tracker.step(sequence[k])
            curves[(scheme, gain)] = (sequence.time, torch.tensor(error, dtype=torch.float64))
    return curves


def convergence_figure(curves: dict, rate: float, out: Path) -> Path:
    plt = _pyplot()
    schemes = list(dict.fromkeys(scheme for scheme, _ in curves))
    fig, axes = plt.subplots(1, len(schemes), figsize=(5.5 * len(schemes), 4), squeeze=False, sharey=True)
    for ax, scheme in zip(axes[0], schemes):
        for (s, gain), (time_, error) in curves.items():
            if s != scheme:
                continue
            beyond = gain / rate >= 2.0
            ax.semilogy(time_.numpy(), error.clamp(min=1e-30).numpy(), ls="--" if beyond else "-",
                        label=f"K = {gain:g} 1/s, K dt = {gain / rate:g}" + (" > 2: unstable" if beyond else ""))
        ax.set_title(f"Human66 to a static T-pose, {scheme} scheme, {rate:g} Hz")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("MNTE")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    return _save(fig, out / "convergence.png")


def phase_plane_figure(run: Run, joint: str, out: Path, transient: float = 2.0,
                       limits: LimitSettings = LimitSettings()) -> Path:
    """An iCub joint's angle against its rate along `run` after the transient, over the region the
    velocity bounds allow (the tracker's LimitSettings, at the run's time step):
    -min(b tanh(K_g (s - s_min)), (s - s_min)/dt) <= s_dot <= min(b tanh(K_g (s_max - s)), (s_max - s)/dt)."""
    plt = _pyplot()
    model = _model(run.model)
    j = model.joint_names.index(joint)
    lower, upper = float(model.lower[j]), float(model.upper[j])
    dt = float((run.time[1:] - run.time[:-1]).median())
    grid = torch.linspace(lower, upper, 400, dtype=model.dtype)
    s = torch.zeros(len(grid), model.n_dof, dtype=model.dtype) + (model.lower + model.upper) / 2
    s[:, j] = grid
    lb, ub = velocity_bounds(s, model.lower, model.upper, limits, torch.full((len(grid), 1), dt, dtype=model.dtype))
    # step k's rate was bounded at the angle the step started from: pair rate k with angle k - 1
    keep = run.time[1:] >= run.time[0] + transient
    if not bool(keep.any()):  # a recording shorter than the transient: all of it
        keep[:] = True
    angle = run.trajectory.joint_positions[:-1, 0, j][keep]
    rate = run.trajectory.velocity[1:, 0, 6 + j][keep]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    ax.fill_between(grid.numpy(), lb[:, 6 + j].numpy(), ub[:, 6 + j].numpy(), color="tab:gray", alpha=0.15,
                    label="allowed by the tanh velocity bounds")
    ax.plot(grid.numpy(), ub[:, 6 + j].numpy(), color="tab:gray", lw=1)
    ax.plot(grid.numpy(), lb[:, 6 + j].numpy(), color="tab:gray", lw=1)
    for x in (lower, upper):
        ax.axvline(x, color="black", lw=0.8, ls=":")
    ax.plot(angle.numpy(), rate.numpy(), color="tab:red", lw=0.8,
            label=f"{run.method}, {run.scenario}, after {transient:g} s (angle at the step's start)")
    reach = max(float(rate.abs().max()) * 1.5, 1.0)
    ax.set_ylim(-reach, reach)
    # the trajectory's neighbourhood and the limits near it
    low, high = float(angle.min()), float(angle.max())
    span = max(high - low, 0.2)
    ax.set_xlim(max(lower, low - span) - 0.05, min(upper, high + span) + 0.05)
    ax.set_xlabel(f"{joint} angle (rad)")
    ax.set_ylabel(f"{joint} rate (rad/s)")
    ax.set_title(f"iCub {joint}: limits [{lower:.3f}, {upper:.3f}] rad, b = {limits.max_rate:g} rad/s, "
                 f"K_g = {limits.gain:g}", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    return _save(fig, out / "phase_plane.png")


# ---------------------------------------------------------------------------------------- tables
COLUMNS = ("model", "scenario", "method", "samples", "mnte_median", "mnte_p99", "rmse_median", "rmse_p99",
           "time_median_ms", "time_p99_ms", "spread", "iterations_mean", "iterations_p99", "wall_median_ms",
           "wall_p99_ms")


def write_csv(rows: list[dict], path: Path) -> Path:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows({k: row[k] for k in COLUMNS} for row in rows)
    return path


def markdown(rows: list[dict], settings: Settings, source: str, wall_time: float) -> str:
    """The table, the ratios for each discretisation, and the settings."""
    length = f"{settings.duration:g} s at {settings.rate:g} Hz per run, " if source.startswith("built-in") else ""
    lines = [f"# Dynamical IK against instantaneous IK ({source})", "",
             f"{length}statistics after {settings.transient:g} s; K = {settings.gain:g} 1/s; "
             f"QP backend '{settings.backend}' for every method; "
             f"torch threads {settings.threads}; instantaneous IK: tolerance {settings.tolerance:g}, step tolerance "
             f"{settings.step_tolerance:g}, at most {settings.max_iterations} iterations; step times are processor "
             f"time, the least of {settings.repeats} runs (wall-clock in results.csv); "
             f"{platform.processor() or platform.machine()}, torch {torch.__version__}; wall time {wall_time:.0f} s.", "",
             "| model | scenario | method | MNTE median | MNTE p99 | ω RMSE median (rad/s) | ω RMSE p99 | "
             "step median (ms) | step p99 (ms) | spread p99/median | iterations mean, p99 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['scenario']} | {r['method']} | {r['mnte_median']:.2e} | {r['mnte_p99']:.2e} | "
                     f"{r['rmse_median']:.2e} | {r['rmse_p99']:.2e} | {r['time_median_ms']:.2f} | {r['time_p99_ms']:.2f} | "
                     f"{r['spread']:.2f} | {r['iterations_mean']:.1f}, {r['iterations_p99']:.0f} |")
    for scheme in ("midpoint", "paper"):
        table = ratios(rows, scheme)
        if not table:
            continue
        lines += ["", f"## Ratios, dynamical ({scheme})", "",
                  "Step time of whole-body (WB) and pair-wise (PW) over the dynamical method's (above 1: the dynamical "
                  "method is faster); spreads p99/median; MNTE of the dynamical method over whole-body's (where "
                  "whole-body's is below 1e-12 the targets are reachable and reached to its tolerance: the ratio then "
                  "compares two errors far below any sensor's accuracy).", "",
                  "| model | scenario | WB/dyn median | WB/dyn p99 | PW/dyn median | PW/dyn p99 | spread dyn | spread WB | "
                  "spread PW | MNTE dyn/WB | faster | steadiest | MNTE within 2x |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        mark = lambda ok: "yes" if ok else "**no**"  # noqa: E731
        for r in table:
            lines.append(f"| {r['model']} | {r['scenario']} | {r['wb_median']:.1f} | {r['wb_p99']:.1f} | "
                         f"{r['pw_median']:.1f} | {r['pw_p99']:.1f} | {r['spread_dyn']:.2f} | {r['spread_wb']:.2f} | "
                         f"{r['spread_pw']:.2f} | {r['mnte_ratio']:.3g} | {mark(r['faster'])} | "
                         f"{mark(r['steadiest'])} | {mark(r['accurate'])} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------- the whole
def run_paper(out: str | Path, settings: Settings = Settings(), cases: list[Case] | None = None,
              methods=METHODS, progress: bool = True, source: str = "built-in scenarios") -> tuple[list[dict], list[Path]]:
    """Run every method on every case (default: the built-in scenarios on every model), then the
    convergence runs, and write the table and figures into `out`. Returns the rows and the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(settings.threads)
    try:
        cases = scenario_cases(settings) if cases is None else cases
        jobs = [(case, method) for case in cases for method in methods]
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(jobs) + 1, desc="experiment paper", unit="run")
        runs = []
        for case, method in jobs:  # runs one after the other: their timings must not share the cores
            if bar is not None:
                bar.set_postfix_str(f"{case.model} {case.scenario} {method}")
            runs.append(timed_run(case, method, settings))
            if bar is not None:
                bar.update()
        if bar is not None:
            bar.set_postfix_str("convergence to a static T-pose")
        curves = convergence(settings, settings.convergence_seconds)
        if bar is not None:
            bar.update()
            bar.close()
    finally:
        torch.set_num_threads(threads)
    rows = [statistics(run, settings.transient) for run in runs]
    files = [write_csv(rows, out / "results.csv")]
    files += box_plots(runs, settings.transient, out)
    files.append(convergence_figure(curves, settings.rate, out))
    elbow = [r for r in runs if r.model == "icub" and r.method == "dynamical (midpoint)"]
    if elbow:
        # the motion in which the elbow moves most after the transient (running, of the built-in ones)
        j = _model("icub").joint_names.index("r_elbow")
        pick = max(elbow, key=lambda r: float(after_transient(r.trajectory.joint_positions[:, 0, j], r.time,
                                                                 settings.transient).std()))
        files.append(phase_plane_figure(pick, "r_elbow", out, settings.transient))
    text = markdown(rows, settings, source, time.perf_counter() - began)
    (out / "results.md").write_text(text)
    files.insert(1, out / "results.md")
    return rows, files

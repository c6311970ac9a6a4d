"""The experiment's runs: each method on a case, timed step by step, and the convergence of the
dynamical method to a static T-pose for several gains.

Every method starts from the same state (the zero configuration, the base at its first target)
and uses the same QP backend. Per-step time is processor time of the process: what the step
computes, which other programs on a shared machine do not inflate as they do wall-clock time.
Velocities of the instantaneous methods are central differences of their solutions; the
midpoint scheme's are centred too.
"""

from __future__ import annotations

import gc
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from ...io.targets import recording_targets
from ...method.baselines import PairwiseIK, WholeBodyIK
from ...method.kinematics import KinematicModel
from ...method.metrics import mnte
from ...method.models import TRACKED_LINKS
from ...method.state import TargetSequence, Trajectory
from ...method.tracker import DynamicalIK
from ...synthetic.scenarios import scenario
from ..evaluation import tracking_errors
from .cases import PERSON, Case, Settings, cached_model

METHODS = ("whole-body", "pair-wise", "dynamical (paper)", "dynamical (midpoint)")
DYNAMICAL = {"dynamical (paper)": "paper", "dynamical (midpoint)": "midpoint"}  # method -> scheme
# 1/s; at 100 Hz K dt = 0, 0.05, 0.2, 1 (one step), 1.9 (oscillating), 2.2 (unstable); the error
# shrinks by |1 - K dt| per step, so no two of these share a rate
CONVERGENCE_GAINS = (0.0, 5.0, 20.0, 100.0, 190.0, 220.0)


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
    wall_time: torch.Tensor = field(default_factory=lambda: torch.zeros(0))  # [T] s: the step's wall-clock time


def run_method(case: Case, method: str, settings: Settings) -> Run:
    """Track `case` with `method`, every method from the tracker's initial state."""
    model = cached_model(case.model)
    sequence = recording_targets(case.recording, case.links, dtype=model.dtype, device=model.device)
    dt = float(np.median(np.diff(case.recording.time))) if len(case.recording.time) > 1 else 1.0 / settings.rate
    tracker = DynamicalIK(model, case.links, position_gain=settings.gain, orientation_gain=settings.gain, dt=dt,
                          scheme=DYNAMICAL.get(method, "midpoint"), backend=settings.backend)
    initial = tracker.initial_state(sequence[0])
    cpu: list[float] = []
    if method in DYNAMICAL:
        tracker.step = _cpu_timed(tracker.step, cpu)  # type: ignore[method-assign]  # timed on this instance only
        trajectory = tracker.run(sequence, initial, progress=False)
        iterations = torch.ones(len(sequence), dtype=torch.long)
    else:
        kind = WholeBodyIK if method == "whole-body" else PairwiseIK
        ik = kind(model, case.links, tolerance=settings.tolerance, step_tolerance=settings.step_tolerance,
                  max_iterations=settings.max_iterations, backend=settings.backend)
        ik.solve = _cpu_timed(ik.solve, cpu)  # type: ignore[method-assign]  # timed on this instance only
        trajectory = ik.run(sequence, initial)
        iterations = trajectory.diagnostics["iterations"][:, 0]
    # the instantaneous methods' velocities are central differences, meant at t_k: no scheme
    errors = tracking_errors(model, trajectory, sequence, case.links, DYNAMICAL.get(method))
    return Run(case.model, case.scenario, method, sequence.time, errors["mnte"][:, 0], errors["rmse"][:, 0],
               torch.tensor(cpu, dtype=torch.float64), iterations, trajectory, trajectory.diagnostics["step_time"])


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


def static_tpose(seconds: float, rate: float, seed: int = 0) -> tuple[KinematicModel, tuple[str, ...], TargetSequence]:
    """Human66 and targets of a person holding a T-pose for `seconds`: the t-pose scenario's first
    frame, each link turned by a seeded random rotation of about 0.1 rad per axis (a person's T-pose
    is not the model's, and sensors sit a little askew), velocities zero."""
    model, links = cached_model(PERSON), TRACKED_LINKS[PERSON]
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
    for scheme in DYNAMICAL.values():
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

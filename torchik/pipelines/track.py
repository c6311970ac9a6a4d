"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`."""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording
from ..io.targets import recording_targets
from ..method.kinematics import KinematicModel
from ..method.tracker import DynamicalIK
from ..method.state import State, TargetSequence, Trajectory
from .evaluation import summary, tracking_errors, tracking_statistics


def run_interruptible(tracker: DynamicalIK, sequence: TargetSequence, initial: State | None = None,
                      progress: bool = False) -> tuple[Trajectory, bool]:
    """`tracker.run(sequence, initial)` that Ctrl-C stops between steps: returns the trajectory of
    the steps done [T' <= T] and whether it was interrupted. Re-raises KeyboardInterrupt when no
    step was done. progress: a bar on the terminal once the run has lasted a second.

    Why not tracker.run: it keeps nothing when interrupted, and an interrupted `torchik track`
    must still write its shorter outputs."""
    T = len(sequence)
    if T == 0:
        raise InputError("the sequence is empty")
    if T > 1 and not bool((sequence.time[1:] > sequence.time[:-1]).all()):
        raise InputError("sequence.time must be strictly increasing")
    B = sequence.rotation.shape[1] if sequence.rotation.numel() else sequence.position.shape[1]
    tracker.reset(initial if initial is not None else tracker.initial_state(sequence[0]), batch=B)
    steps = range(T)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="tracking", unit="step", leave=False, delay=1.0)
    states, diags, interrupted = [], [], False
    try:
        for k in steps:
            state, diag = tracker.step(sequence[k], None if k == 0 else sequence.time[k] - sequence.time[k - 1])
            states.append(state)  # the tracker replaces its state every step: these stay valid
            diags.append(diag)
    except KeyboardInterrupt:
        if not states:
            raise
        interrupted = True
    finally:
        if progress:
            steps.close()
    stack = lambda items, name: torch.stack([getattr(x, name) for x in items])  # noqa: E731
    diagnostics = {name: stack(diags, name)
                   for name in ("mnte", "residual_norm", "active_constraints", "solved", "dropped", "projected")}
    for name in ("step_time", "kinematics_time", "qp_time"):
        diagnostics[name] = torch.tensor([getattr(d, name) for d in diags], dtype=torch.float64)
    trajectory = Trajectory(sequence.time[:len(states)], stack(states, "base_position"), stack(states, "base_rotation"),
                            stack(states, "joint_positions"), stack(states, "velocity"), diagnostics)
    return trajectory, interrupted


def track_recording(model: KinematicModel, recording: Recording, links, position_gain: float = 20.0,
                    orientation_gain: float = 20.0, scheme: str = "midpoint", backend: str = "auto",
                    progress: bool = False, transient: float = 2.0) -> tuple[Trajectory, dict]:
    """Track `recording` (link names already the model's) and return the trajectory and a report
    (metrics after `transient` seconds, step times, failures).

    The trajectory's diagnostics mnte and rmse [T,1] are the paper's metrics (`tracking_errors`:
    the estimate at t_k against the targets at t_k). Ctrl-C stops the tracking early: the
    trajectory and report then cover the frames done and report["interrupted"] is True."""
    links = tuple(links)
    sequence = recording_targets(recording, links, dtype=model.dtype, device=model.device)
    dt = float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else 0.01
    tracker = DynamicalIK(model, links, position_gain=position_gain, orientation_gain=orientation_gain, dt=dt,
                          scheme=scheme, backend=backend)
    trajectory, interrupted = run_interruptible(tracker, sequence, progress=progress)
    done = len(trajectory.time)
    trajectory.diagnostics.update(tracking_errors(model, trajectory, sequence, links, scheme))
    time = trajectory.time
    d = trajectory.diagnostics
    report = dict(
        model=model.name, links=len(links), frames=done, duration_s=float(time[-1] - time[0]),
        rate_hz=1.0 / dt, scheme=scheme, backend=backend, gains=dict(position=position_gain, orientation=orientation_gain),
        transient_s=transient,
        **tracking_statistics(trajectory, sequence, recording, model, transient),
        step_time_ms={k: v * 1e3 for k, v in summary(d["step_time"], time, 0.0).items()},
        qp_fallbacks=int((~d["solved"]).sum()), dropped_targets=int(d["dropped"].sum()),
        active_constraints_mean=float(d["active_constraints"].double().mean()), interrupted=interrupted,
    )
    return trajectory, report

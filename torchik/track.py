"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from .errors import InputError
from .io.recording import Recording
from .kinematics import KinematicModel
from .metrics import angular_velocity_rmse, mnte, summary
from .scenarios import recording_targets
from .tracker import DynamicalIK, State, TargetSequence, Trajectory


def time_chunks(model: KinematicModel, trajectory: Trajectory, chunk: int = 4096) -> Iterator[tuple]:
    """The trajectory's configurations a few whole time steps at a time, for batched kinematics.

    Yields (steps, m, p [t*B,3], R [t*B,3,3], s [t*B,n]): `steps` a slice of the time axis, row
    t*B + b subject b at step t, and `m` the model to call on those rows (a stack of subjects
    repeated once per step when `model` holds several). About `chunk` rows per call."""
    T, B = trajectory.joint_positions.shape[:2]
    per_call = max(chunk // B, 1)
    stacked: dict[int, KinematicModel] = {}
    for start in range(0, T, per_call):
        steps = slice(start, min(start + per_call, T))
        t = steps.stop - steps.start
        m = model if model.n_subjects == 1 else stacked.setdefault(t, KinematicModel.stack([model] * t))
        p, R, s = (x[steps].reshape(t * B, *x.shape[2:])
                   for x in (trajectory.base_position, trajectory.base_rotation, trajectory.joint_positions))
        yield steps, m, p, R, s


def link_motion(model: KinematicModel, trajectory: Trajectory, links, scheme: str = "midpoint", chunk: int = 4096):
    """Estimated link rotations [T,B,L,3,3] and world angular velocities [T,B,L,3], computed a few
    time steps at a time from the joint axes (omega_L = omega_B + sum_j M_Lj s_dot_j a_j).

    The midpoint scheme's nu_k is the mean velocity over [t_{k-1}, t_k]; its estimate at t_k is the
    mean of the two steps around it. The paper's nu_k is meant at t_k and is taken as it is."""
    links = tuple(links)
    mask = model.select(links).ancestor_mask  # [L,n]
    velocity = trajectory.velocity  # [T,B,6+n]
    if scheme == "midpoint" and len(velocity) > 1:
        velocity = torch.cat((0.5 * (velocity[:-1] + velocity[1:]), velocity[-1:]))
    B, L = velocity.shape[1], len(links)
    rotations, omegas = [], []
    with torch.inference_mode():
        for steps, m, p, R, s in time_chunks(model, trajectory, chunk):
            kin = m(p, R, s, links, jacobian=False, joint_axes=True)
            nu = velocity[steps].reshape(-1, velocity.shape[-1])
            omega = nu[:, None, 3:6] + mask @ (nu[:, 6:, None] * kin.joint_axes)
            rotations.append(kin.rotation.view(-1, B, L, 3, 3))
            omegas.append(omega.view(-1, B, L, 3))
    return torch.cat(rotations), torch.cat(omegas)


def tracking_errors(model: KinematicModel, trajectory: Trajectory, sequence: TargetSequence, links,
                    scheme: str = "midpoint") -> dict[str, torch.Tensor]:
    """The paper's metrics of every subject at every sample: mnte [T,B] and rmse [T,B] (rad/s),
    estimate at t_k against the targets at t_k (`sequence` cut to the trajectory's length).
    NaN where a target is missing."""
    T = len(trajectory.time)
    R_hat, w_hat = link_motion(model, trajectory, links, scheme)
    return dict(mnte=mnte(sequence.rotation[:T], R_hat), rmse=angular_velocity_rmse(sequence.angular_velocity[:T], w_hat))


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


def tracking_statistics(trajectory: Trajectory, sequence: TargetSequence, recording: Recording,
                        model: KinematicModel, transient: float) -> dict:
    """What `torchik track` reports of subject 0's accuracy, after `transient` seconds and over the
    frames whose targets are all known: mnte and angular_velocity_rmse (`metrics.summary` dicts,
    None when no frame is known) and, when the recording carries the model's joint angles,
    joint_error_rad (max, rms). trajectory: [T,1,...] with the mnte and rmse diagnostics
    (`tracking_errors`); sequence: its targets (at least T frames)."""
    done, time, d = len(trajectory.time), trajectory.time, trajectory.diagnostics
    known = (torch.isfinite(sequence.rotation[:done, 0]).flatten(-3).all(-1)
             & torch.isfinite(sequence.angular_velocity[:done, 0]).flatten(-2).all(-1))  # [T]
    any_known = bool(known.any())
    out = dict(mnte=summary(d["mnte"][known, 0], time[known], transient) if any_known else None,
               angular_velocity_rmse=summary(d["rmse"][known, 0], time[known], transient) if any_known else None)
    if recording.joint_positions is not None and recording.joint_names == model.joint_names:
        truth = torch.from_numpy(recording.joint_positions[:done]).to(trajectory.joint_positions)
        err = (trajectory.joint_positions[:, 0] - truth).abs()
        keep = time >= time[0] + transient
        err = err[keep] if bool(keep.any()) else err
        out["joint_error_rad"] = dict(max=float(err.max()), rms=float(err.square().mean().sqrt()))
    return out


def save_trajectory(trajectory: Trajectory, model: KinematicModel, path: str | Path) -> Path:
    """The estimated trajectory of subject 0 as .npz: time [T], joint_names, joint_positions [T,n],
    base_position [T,3], base_rotation [T,3,3], velocity [T,6+n], and mnte [T], rmse [T] when the
    diagnostics have them."""
    path = Path(path)
    host = lambda t: t.detach().cpu().numpy()  # noqa: E731
    arrays = dict(time=host(trajectory.time), joint_names=np.array(model.joint_names, dtype=str),
                  joint_positions=host(trajectory.joint_positions[:, 0]),
                  base_position=host(trajectory.base_position[:, 0]), base_rotation=host(trajectory.base_rotation[:, 0]),
                  velocity=host(trajectory.velocity[:, 0]))
    for name in ("mnte", "rmse"):
        if name in trajectory.diagnostics:
            arrays[name] = host(trajectory.diagnostics[name][:, 0])
    with replacing(path) as part, open(part, "wb") as f:
        np.savez(f, **arrays)
    return path


def write_report(report: dict, path: str | Path) -> Path:
    """The report as indented JSON at `path`, replacing it whole."""
    path = Path(path)
    with replacing(path) as part:
        part.write_text(json.dumps(report, indent=2) + "\n")
    return path


@contextmanager
def replacing(path: str | Path):
    """Write to the temporary path this yields; it replaces `path` when the block completes. A write
    interrupted (Ctrl-C) or failed leaves the old file or none, never a truncated one."""
    path = Path(path)
    part = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        yield part
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)

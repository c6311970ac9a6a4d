"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from .io.recording import Recording
from .kinematics import KinematicModel
from .metrics import angular_velocity_rmse, mnte, summary
from .scenarios import recording_targets
from .tracker import DynamicalIK, Trajectory


def link_motion(model: KinematicModel, trajectory: Trajectory, links, scheme: str = "midpoint", chunk: int = 2000):
    """Estimated link rotations [T,L,3,3] and world angular velocities [T,L,3] of subject 0, computed
    in chunks of time from the joint axes (omega_L = omega_B + sum_j M_Lj s_dot_j a_j).

    The midpoint scheme's nu_k is the mean velocity over [t_{k-1}, t_k]; its estimate at t_k is the
    mean of the two steps around it. The paper's nu_k is meant at t_k and is taken as it is."""
    mask = model.select(tuple(links)).ancestor_mask  # [L,n]
    velocity = trajectory.velocity[:, 0]
    if scheme == "midpoint" and len(velocity) > 1:
        velocity = torch.cat((0.5 * (velocity[:-1] + velocity[1:]), velocity[-1:]))
    rotations, omegas = [], []
    for start in range(0, len(trajectory.time), chunk):
        part = slice(start, start + chunk)
        p, R, s = (x[part, 0] for x in (trajectory.base_position, trajectory.base_rotation, trajectory.joint_positions))
        nu = velocity[part]
        with torch.inference_mode():
            kin = model(p.clone(), R.clone(), s.clone(), links, jacobian=False, joint_axes=True)
            omega = nu[:, None, 3:6] + mask @ (nu[:, 6:, None] * kin.joint_axes)
        rotations.append(kin.rotation.clone())
        omegas.append(omega)
    return torch.cat(rotations), torch.cat(omegas)


def track_recording(model: KinematicModel, recording: Recording, links, position_gain: float = 20.0,
                    orientation_gain: float = 20.0, scheme: str = "midpoint", backend: str = "piqp",
                    progress: bool | None = None, transient: float = 2.0) -> tuple[Trajectory, dict]:
    """Track `recording` (link names already the model's) and return the trajectory and a report
    (metrics after `transient` seconds, step times, failures)."""
    links = tuple(links)
    sequence = recording_targets(recording, links, dtype=model.dtype, device=model.device)
    dt = float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else 0.01
    tracker = DynamicalIK(model, links, position_gain=position_gain, orientation_gain=orientation_gain, dt=dt,
                          scheme=scheme, backend=backend)
    trajectory = tracker.run(sequence, progress=progress)
    R_hat, w_hat = link_motion(model, trajectory, links, scheme)
    R_target, w_target = sequence.rotation[:, 0], sequence.angular_velocity[:, 0]
    known = torch.isfinite(R_target).flatten(-2).all(-1).all(-1) & torch.isfinite(w_target).all(-1).all(-1)
    errors = dict(mnte=mnte(R_target, R_hat), rmse=angular_velocity_rmse(w_target, w_hat))
    time = trajectory.time
    d = trajectory.diagnostics
    report = dict(
        model=model.name, links=len(links), frames=len(time), duration_s=float(time[-1] - time[0]),
        rate_hz=1.0 / dt, scheme=scheme, backend=backend, gains=dict(position=position_gain, orientation=orientation_gain),
        transient_s=transient,
        mnte=summary(errors["mnte"][known], time[known], transient) if bool(known.any()) else None,
        angular_velocity_rmse=summary(errors["rmse"][known], time[known], transient) if bool(known.any()) else None,
        step_time_ms={k: v * 1e3 for k, v in summary(d["step_time"], time, 0.0).items()},
        qp_fallbacks=int((~d["solved"]).sum()), dropped_targets=int(d["dropped"].sum()),
        active_constraints_mean=float(d["active_constraints"].double().mean()),
    )
    if recording.joint_positions is not None and recording.joint_names == model.joint_names:
        truth = torch.from_numpy(recording.joint_positions).to(trajectory.joint_positions)
        err = (trajectory.joint_positions[:, 0] - truth).abs()
        keep = time >= time[0] + transient
        err = err[keep] if bool(keep.any()) else err
        report["joint_error_rad"] = dict(max=float(err.max()), rms=float(err.square().mean().sqrt()))
    trajectory.diagnostics.update(errors)
    return trajectory, report


def save_trajectory(trajectory: Trajectory, model: KinematicModel, path: str | Path) -> Path:
    """The estimated trajectory of subject 0 as .npz: time [T], joint_names, joint_positions [T,n],
    base_position [T,3], base_rotation [T,3,3], velocity [T,6+n], mnte [T], rmse [T]."""
    path = Path(path)
    host = lambda t: t.detach().cpu().numpy()  # noqa: E731
    arrays = dict(time=host(trajectory.time), joint_names=np.array(model.joint_names, dtype=str),
                  joint_positions=host(trajectory.joint_positions[:, 0]),
                  base_position=host(trajectory.base_position[:, 0]), base_rotation=host(trajectory.base_rotation[:, 0]),
                  velocity=host(trajectory.velocity[:, 0]))
    for name in ("mnte", "rmse"):
        if name in trajectory.diagnostics:
            arrays[name] = host(trajectory.diagnostics[name])
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path


def write_report(report: dict, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(report, indent=2) + "\n")
    return path

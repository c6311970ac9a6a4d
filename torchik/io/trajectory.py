"""The estimated trajectory as a file: what `torchik track --out` writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..method.kinematics import KinematicModel
from ..method.state import Trajectory
from .files import replacing


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

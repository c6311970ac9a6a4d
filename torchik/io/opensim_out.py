"""What `torchik track` writes for OpenSim: the joint angles as a motion file (`--out estimate.mot`)
and the per-IMU orientation errors in OpenSense's layout (`--out errors.sto`), so that torchik's
outputs and OpenSense's IMU IK outputs compare column by column.

- the motion (.mot, OpenSim's Storage format, read by OpenSim's `TimeSeriesTable` and its GUI's
  "Load Motion"): `inDegrees=yes`, a column per model joint (its torchik name, degrees), and the
  base's pose: `base_x`, `base_y`, `base_z` (m, world, z up) and `base_roll`, `base_pitch`,
  `base_yaw` (degrees, R = Rz(yaw) Ry(pitch) Rx(roll)). A recording without base positions says
  in the header how the base was tracked (`base_position=...`).
- the orientation errors (.sto, as OpenSense's `<trial>_orientationErrors.sto`): a column per
  tracked IMU, named as in the source (the link map's segment) or the link, each the angle (rad)
  between the model link's orientation and its target; nan where the target was missing.

`read_motion` reads a motion back (angles in radians).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..method import so3
from ..method.kinematics import KinematicModel
from ..method.state import TargetSequence, Trajectory
from .opensim_table import read_table, write_table
from .recording import RecordingError

BASE_COLUMNS = ("base_x", "base_y", "base_z", "base_roll", "base_pitch", "base_yaw")
ANGULAR = ("base_roll", "base_pitch", "base_yaw")


@dataclass(frozen=True)
class OpenSimMotion:
    """A motion file read back: time [T] s, the base's pose [T,6] (m and rad, BASE_COLUMNS' order),
    joint names [n] and joint positions [T,n] (rad), the header."""

    time: np.ndarray
    base: np.ndarray
    joint_names: tuple[str, ...]
    joint_positions: np.ndarray
    header: dict[str, str]


class MotionWriter:
    """The estimated trajectory (subject 0) as an OpenSim motion: `write` each part, then `commit`."""

    def __init__(self, path: str | Path, model: KinematicModel, notes: dict[str, str] | None = None):
        self.path, self.joint_names, self.notes = Path(path), tuple(model.joint_names), dict(notes or {})
        self._time: list[np.ndarray] = []
        self._rows: list[np.ndarray] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence | None = None) -> None:
        """A part of the run; targets: unused (an output's signature)."""
        host = lambda t: t.detach().cpu().double()  # noqa: E731
        rpy = so3.matrix_to_rpy(host(trajectory.base_rotation[:, 0]))
        rows = torch.cat((host(trajectory.base_position[:, 0]), torch.rad2deg(rpy),
                          torch.rad2deg(host(trajectory.joint_positions[:, 0]))), dim=-1)
        self._time.append(host(trajectory.time).numpy())
        self._rows.append(rows.numpy())

    def commit(self) -> Path:
        if not self._time:
            raise ValueError("no part of the trajectory was written")
        header = dict(version="1", inDegrees="yes", DataType="double", **self.notes)
        return write_table(self.path, np.concatenate(self._time), BASE_COLUMNS + self.joint_names,
                           np.concatenate(self._rows), header, name="Coordinates")

    def __enter__(self) -> "MotionWriter":
        return self

    def __exit__(self, *exc) -> None:
        self._time, self._rows = [], []


class OrientationErrorWriter:
    """Each tracked link's orientation error (rad) against its target, a column per IMU (`names`:
    the source's name for each of `links`), as OpenSense writes them: `write` each part, then `commit`."""

    def __init__(self, path: str | Path, model: KinematicModel, links, names=None):
        self.path, self.model, self.links = Path(path), model, tuple(links)
        self.names = tuple(names) if names is not None else self.links
        self._time: list[np.ndarray] = []
        self._rows: list[np.ndarray] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None:
        """A part of the run (subject 0) and the targets it was tracked on."""
        with torch.no_grad():
            kin = self.model(trajectory.base_position[:, 0], trajectory.base_rotation[:, 0],
                             trajectory.joint_positions[:, 0], self.links, jacobian=False)
        target = targets.rotation[:, 0]  # [T,n,3,3]
        known = torch.isfinite(target).flatten(-2).all(-1)
        eye = torch.eye(3, dtype=target.dtype, device=target.device)
        relative = torch.where(known[..., None, None], target, eye).transpose(-1, -2) @ kin.rotation
        angle = torch.where(known, so3.log(relative).norm(dim=-1), torch.nan)
        self._time.append(trajectory.time.detach().cpu().double().numpy())
        self._rows.append(angle.detach().cpu().double().numpy())

    def commit(self) -> Path:
        if not self._time:
            raise ValueError("no part of the trajectory was written")
        time = np.concatenate(self._time)
        rate = 1.0 / float(np.median(np.diff(time))) if len(time) > 1 else 0.0
        header = dict(name="OrientationErrors", DataRate=f"{rate:.6f}", DataType="double", version="3",
                      OpenSimVersion="4.6", inDegrees="no")
        return write_table(self.path, time, self.names, np.concatenate(self._rows), header)

    def __enter__(self) -> "OrientationErrorWriter":
        return self

    def __exit__(self, *exc) -> None:
        self._time, self._rows = [], []


def read_motion(path: str | Path) -> OpenSimMotion:
    """A motion file torchik wrote (or any OpenSim .mot of the same columns): joint angles in radians
    (converted from degrees when `inDegrees=yes`), the base pose when its columns are there (NaN
    otherwise). RecordingError naming the file when it is not such a table."""
    table = read_table(path)
    in_degrees = (table.header_value("inDegrees") or "no").lower() == "yes"
    if not table.labels:
        raise RecordingError(f"{table.path}: no coordinate columns after 'time'")
    values = np.stack([table.column(label, 1)[:, 0] for label in table.labels], axis=1)
    index = {label: i for i, label in enumerate(table.labels)}
    base = np.full((len(table.time), len(BASE_COLUMNS)), np.nan)
    for k, label in enumerate(BASE_COLUMNS):
        if label in index:
            base[:, k] = values[:, index[label]]
            if label in ANGULAR and in_degrees:
                base[:, k] = np.deg2rad(base[:, k])
    joints = tuple(label for label in table.labels if label not in BASE_COLUMNS)
    positions = values[:, [index[j] for j in joints]]
    return OpenSimMotion(table.time, base, joints, np.deg2rad(positions) if in_degrees else positions, table.header)

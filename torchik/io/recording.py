"""The recording format every reader writes and the tracker, the experiments and the diagnosis read.

One `.npz` file (NumPy, no pickles):

| key | type | meaning |
|---|---|---|
| `time` | float64 [T] | seconds, strictly increasing |
| `links` | str [n] | the source's segment names |
| `orientation` | float64 [T,n,3,3] | rotation from segment frame to world; NaN where missing |
| `angular_velocity` | float64 [T,n,3] | world frame, rad/s; NaN where missing |
| `base_link` | str | the segment whose position is given (one of `links`) |
| `base_position` | float64 [T,3] | m, world |
| `base_linear_velocity` | float64 [T,3] | m/s, world |
| `joint_names` | str [dof] | optional, with `joint_positions` |
| `joint_positions` | float64 [T,dof] | optional ground truth (synthetic data) |
| `position` | float64 [T,n,3] | optional: each segment's origin (its proximal joint), m, world; NaN where missing |
| `meta` | str | JSON: source file, subject, units, frame rate, calibration frames, ... |

A frame that a source could not measure (an occluded marker, a dropped packet) holds NaN for the
segments concerned: marked, never filled with made-up values.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import InputError
from ..method import so3
from ..method.targets import PROJECT_TOLERANCE


class RecordingError(InputError):
    """A recording (or a source file) that is missing, malformed or inconsistent."""


@dataclass
class Recording:
    """A motion recording in world coordinates (see the module docstring for the format)."""

    time: np.ndarray
    links: tuple[str, ...]
    orientation: np.ndarray
    angular_velocity: np.ndarray
    base_link: str
    base_position: np.ndarray
    base_linear_velocity: np.ndarray
    joint_names: tuple[str, ...] | None = None
    joint_positions: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    position: np.ndarray | None = None  # [T,n,3] each segment's origin, m, world (position targets off the base)

    def __post_init__(self):
        self.links = tuple(self.links)
        if self.joint_names is not None:
            self.joint_names = tuple(self.joint_names)
        validate(self)

    @property
    def frame_rate(self) -> float:
        """Median frames per second."""
        return float(1.0 / np.median(np.diff(self.time))) if len(self.time) > 1 else float("nan")

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0]) if len(self.time) else 0.0

    def gaps(self) -> dict[str, int]:
        """Frames with missing (NaN) orientation, per segment that has any."""
        missing = np.isnan(self.orientation).any(axis=(-1, -2)).sum(axis=0)
        return {name: int(m) for name, m in zip(self.links, missing) if m}


def validate(rec: Recording, where: str = "recording") -> None:
    """Shapes, dtypes, time and rotations; RecordingError naming the first problem found."""
    def fail(message: str):
        raise RecordingError(f"{where}: {message}")

    arrays: dict[str, Any] = dict(time=rec.time, orientation=rec.orientation, angular_velocity=rec.angular_velocity,
                  base_position=rec.base_position, base_linear_velocity=rec.base_linear_velocity)
    for name, a in arrays.items():
        if not isinstance(a, np.ndarray) or a.dtype != np.float64:
            fail(f"{name} must be a float64 NumPy array, got {getattr(a, 'dtype', type(a).__name__)}")
    T, n = rec.time.shape[0] if rec.time.ndim == 1 else -1, len(rec.links)
    expected = dict(time=(T,), orientation=(T, n, 3, 3), angular_velocity=(T, n, 3), base_position=(T, 3),
                    base_linear_velocity=(T, 3))
    for name, shape in expected.items():
        if arrays[name].shape != shape:
            fail(f"{name} has shape {list(arrays[name].shape)}, expected {list(shape)} (T={T} frames, n={n} links)")
    if T < 1:
        fail("no frames")
    if not np.all(np.isfinite(rec.time)):
        fail("time holds NaN or Inf")
    steps = np.diff(rec.time)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        fail(f"time must be strictly increasing: frame {k} at {float(rec.time[k])} s follows {float(rec.time[k - 1])} s")
    if len(set(rec.links)) != n:
        fail(f"duplicate link names in {list(rec.links)}")
    if rec.base_link not in rec.links:
        fail(f"base_link {rec.base_link!r} is not one of the links {list(rec.links)}")
    R = rec.orientation
    known = ~np.isnan(R).any(axis=(-1, -2))
    if np.isinf(R).any() or np.isinf(rec.angular_velocity).any():
        fail("orientation or angular_velocity holds Inf (use NaN to mark missing data)")
    if known.any():
        # the tracker projects rotations this close to SO(3) (noise, float32 exports) and counts them
        Rk = R[known]
        with np.errstate(over="ignore", invalid="ignore"):  # huge entries: an infinite error, refused below
            error = np.linalg.norm(np.swapaxes(Rk, -1, -2) @ Rk - np.eye(3), axis=(-1, -2))
            det = np.linalg.det(Rk)
        bad = (error > PROJECT_TOLERANCE) | (det < 0)
        if bad.any():
            t, i = np.argwhere(known)[int(np.argmax(bad))]
            fail(f"orientation of {rec.links[i]!r} at frame {t} is not a rotation (||R^T R - I|| = "
                 f"{error[int(np.argmax(bad))]:.2g}, det = {det[int(np.argmax(bad))]:.3g})")
    if (rec.joint_names is None) != (rec.joint_positions is None):
        fail("joint_names and joint_positions come together")
    if rec.joint_positions is not None and rec.joint_names is not None:
        if rec.joint_positions.dtype != np.float64 or rec.joint_positions.shape != (T, len(rec.joint_names)):
            fail(f"joint_positions must be float64 [{T},{len(rec.joint_names)}], got "
                 f"{rec.joint_positions.dtype} {list(rec.joint_positions.shape)}")
    if rec.position is not None and (rec.position.dtype != np.float64 or rec.position.shape != (T, n, 3)):
        fail(f"position must be float64 [{T},{n},3], got {rec.position.dtype} {list(rec.position.shape)}")
    try:
        json.dumps(rec.meta)
    except TypeError as exc:
        fail(f"meta must be JSON-serialisable: {exc}")


def save_recording(rec: Recording, path: str | Path) -> Path:
    """Write a recording as `.npz` (no pickles). Returns the path."""
    path = Path(path)
    arrays: dict[str, Any] = dict(time=rec.time, links=np.array(rec.links, dtype=str), orientation=rec.orientation,
                  angular_velocity=rec.angular_velocity, base_link=np.array(rec.base_link, dtype=str),
                  base_position=rec.base_position, base_linear_velocity=rec.base_linear_velocity,
                  meta=np.array(json.dumps(rec.meta), dtype=str))
    if rec.joint_positions is not None:
        arrays.update(joint_names=np.array(rec.joint_names, dtype=str), joint_positions=rec.joint_positions)
    if rec.position is not None:
        arrays.update(position=rec.position)
    with open(path, "wb") as f:  # a file object: np.savez would append .npz to other suffixes
        np.savez(f, **arrays)
    return path


REQUIRED = ("time", "links", "orientation", "angular_velocity", "base_link", "base_position", "base_linear_velocity")


def readable_file(path: str | Path) -> Path:
    """`path` as a Path when it is a file to read; RecordingError saying what it is otherwise."""
    path = Path(path)
    if path.is_dir():
        raise RecordingError(f"{path}: is a folder; give a recording file")
    if not path.is_file():
        raise RecordingError(f"{path}: no such file" if not path.exists() else f"{path}: not a regular file")
    return path


def load_recording(path: str | Path) -> Recording:
    """Read and validate a recording; RecordingError naming the file and the problem."""
    path = readable_file(path)
    if not zipfile.is_zipfile(path):  # np.load takes any other bytes for a pickle, which it refuses
        raise RecordingError(f"{path}: not a torchik recording (.npz, a zip archive of arrays); "
                             "is it another format under the wrong suffix?")
    try:
        with np.load(path, allow_pickle=False) as data:
            contents = {k: data[k] for k in data.files}
    except Exception as exc:  # zip and format errors of every kind
        raise RecordingError(f"{path}: not a torchik recording (.npz): {type(exc).__name__}: {exc}") from exc
    missing = [k for k in REQUIRED if k not in contents]
    if missing:
        raise RecordingError(f"{path}: missing {missing}; a recording holds {list(REQUIRED)}")
    try:
        meta = json.loads(str(contents["meta"])) if "meta" in contents else {}
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{path}: meta is not valid JSON: {exc}") from exc
    try:
        return Recording(
            time=contents["time"], links=tuple(str(x) for x in contents["links"]),
            orientation=contents["orientation"], angular_velocity=contents["angular_velocity"],
            base_link=str(contents["base_link"]), base_position=contents["base_position"],
            base_linear_velocity=contents["base_linear_velocity"],
            joint_names=tuple(str(x) for x in contents["joint_names"]) if "joint_names" in contents else None,
            joint_positions=contents.get("joint_positions"), meta=meta, position=contents.get("position"))
    except RecordingError as exc:
        raise RecordingError(f"{path}: {str(exc).removeprefix('recording: ')}") from None


def angular_velocity_from_orientations(orientation: np.ndarray, time: np.ndarray) -> np.ndarray:
    """World-frame angular velocity by central differences on SO(3): log(R_{k+1} R_{k-1}^T) / (t_{k+1} - t_{k-1}),
    one-sided at the ends. orientation: [T,n,3,3]; time: [T] -> [T,n,3]. NaN where a neighbour is missing."""
    R = torch.from_numpy(np.ascontiguousarray(orientation))
    t = torch.from_numpy(np.ascontiguousarray(time))
    if R.shape[0] < 2:
        return np.zeros(orientation.shape[:-1])
    ahead = torch.cat((R[1:], R[-1:]))
    behind = torch.cat((R[:1], R[:-1]))
    span = (torch.cat((t[1:], t[-1:])) - torch.cat((t[:1], t[:-1])))[:, None, None]
    finite = torch.isfinite(ahead).flatten(-2).all(-1) & torch.isfinite(behind).flatten(-2).all(-1)
    eye = torch.eye(3, dtype=R.dtype)
    relative = torch.where(finite[..., None, None], ahead @ behind.transpose(-1, -2), eye)
    w = so3.log(relative) / span
    return torch.where(finite[..., None], w, torch.nan).numpy()

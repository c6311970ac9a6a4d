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
| `external_wrench` | float64 [T,n,6] | optional: measured external force (N), moment about the world origin (N m) |
| `meta` | str | JSON: source file, subject, units, frame rate, calibration frames, `clock`, ... |

`meta["clock"]`: `"shared"` where one clock samples every segment (optical markers: the C3D and BVH
readers write it), `"per_sensor"` where each sensor streams on its own; absent where unknown.
`meta["angular_velocity"]`: `"derived"` where a reader computed it from the orientations (C3D, BVH);
the diagnosis also tells a derivative from a gyro on the data themselves.

`external_wrench` (world frame; zero where none is measured, NaN where one is measured but cannot be
given to one segment) is what force plates measure (the C3D reader, force_plates.py and foot_contacts.py):
the force the ground exerts on the body, summed over the plates whose contact is on the segment.
Its moment is about the world origin, so wrenches add and a map may move them to another segment;
the centre of pressure p on a floor of normal n follows from it (n x (M - c x F) / (n . F) + c for
a point c of the floor).

`save_recording` writes it; `load_recording` (recording_file.py) reads it whole, `RecordingFile` a
chunk of frames at a time.

A frame that a source could not measure (an occluded marker, a dropped packet) holds NaN for the
segments concerned: marked, never filled with made-up values.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

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
    external_wrench: np.ndarray | None = None  # [T,n,6] force N, moment N m about the world origin, world
    first_frame: int = 0  # of a chunk read from a longer recording: where it starts (what messages count from)

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

    def chunks(self, size: int) -> Iterator["Recording"]:
        """The recording `size` frames at a time (itself when it has no more), as RecordingFile.chunks
        gives a file's."""
        if size < 1:
            raise ValueError(f"chunk size must be positive, got {size}")
        if len(self.time) <= size:
            yield self
            return
        for start in range(0, len(self.time), size):
            yield self.part(start, start + size)

    def part(self, start: int, stop: int) -> "Recording":
        """Frames [start, stop) (views), with first_frame saying where they start."""
        cut = lambda a: None if a is None else a[start:stop]  # noqa: E731
        return dataclasses.replace(self, time=self.time[start:stop], orientation=self.orientation[start:stop],
                                   angular_velocity=self.angular_velocity[start:stop],
                                   base_position=self.base_position[start:stop],
                                   base_linear_velocity=self.base_linear_velocity[start:stop],
                                   joint_positions=cut(self.joint_positions), position=cut(self.position),
                                   external_wrench=cut(self.external_wrench), first_frame=self.first_frame + start)

    def gaps(self) -> dict[str, int]:
        """Frames with missing (NaN) orientation, per segment that has any."""
        missing = np.isnan(self.orientation).any(axis=(-1, -2)).sum(axis=0)
        return {name: int(m) for name, m in zip(self.links, missing) if m}


def validate(rec: Recording, where: str = "recording") -> None:
    """Shapes, dtypes, time and rotations; RecordingError naming the first problem found."""
    check_layout(rec.time, rec.links, rec.base_link, per_frame_arrays(rec), rec.joint_names, rec.meta, where,
                 rec.first_frame)
    check_frames(rec.orientation, rec.angular_velocity, rec.links, where, rec.first_frame)
    if rec.external_wrench is not None and np.isinf(rec.external_wrench).any():
        raise RecordingError(f"{where}: external_wrench holds Inf (use NaN to mark an unknown wrench)")


def per_frame_arrays(rec: Recording) -> dict[str, Any]:
    """The recording's arrays with a leading frame axis, by their names in the file (the optional ones when given)."""
    arrays: dict[str, Any] = dict(orientation=rec.orientation, angular_velocity=rec.angular_velocity,
                                  base_position=rec.base_position, base_linear_velocity=rec.base_linear_velocity)
    if rec.joint_positions is not None:
        arrays["joint_positions"] = rec.joint_positions
    if rec.position is not None:
        arrays["position"] = rec.position
    if rec.external_wrench is not None:
        arrays["external_wrench"] = rec.external_wrench
    return arrays


def check_layout(time: Any, links: tuple[str, ...], base_link: str, arrays: dict[str, Any],
                 joint_names: tuple[str, ...] | None, meta: dict, where: str = "recording", first_frame: int = 0) -> None:
    """What is not checked frame by frame: the time stamps, the names, and the dtypes and shapes of
    `arrays` (per_frame_arrays', or a file's array headers as shaped views: nothing is read for them).
    Frame numbers in messages count from `first_frame`."""
    def fail(message: str):
        raise RecordingError(f"{where}: {message}")

    for name, a in dict(time=time, **{k: v for k, v in arrays.items() if k in REQUIRED}).items():
        if not isinstance(a, np.ndarray) or a.dtype != np.float64:
            fail(f"{name} must be a float64 NumPy array, got {getattr(a, 'dtype', type(a).__name__)}")
    T, n = time.shape[0] if time.ndim == 1 else -1, len(links)
    expected = dict(time=(T,), orientation=(T, n, 3, 3), angular_velocity=(T, n, 3), base_position=(T, 3),
                    base_linear_velocity=(T, 3))
    for name, shape in expected.items():
        found = time if name == "time" else arrays[name]
        if found.shape != shape:
            fail(f"{name} has shape {list(found.shape)}, expected {list(shape)} (T={T} frames, n={n} links)")
    if T < 1:
        fail("no frames")
    if not np.all(np.isfinite(time)):
        fail("time holds NaN or Inf")
    steps = np.diff(time)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        fail(f"time must be strictly increasing: frame {first_frame + k} at {float(time[k])} s follows "
             f"{float(time[k - 1])} s")
    if len(set(links)) != n:
        fail(f"duplicate link names in {list(links)}")
    if base_link not in links:
        fail(f"base_link {base_link!r} is not one of the links {list(links)}")
    if (joint_names is None) != ("joint_positions" not in arrays):
        fail("joint_names and joint_positions come together")
    if joint_names is not None and "joint_positions" in arrays:
        q = arrays["joint_positions"]
        if q.dtype != np.float64 or q.shape != (T, len(joint_names)):
            fail(f"joint_positions must be float64 [{T},{len(joint_names)}], got {q.dtype} {list(q.shape)}")
    position = arrays.get("position")
    if position is not None and (position.dtype != np.float64 or position.shape != (T, n, 3)):
        fail(f"position must be float64 [{T},{n},3], got {position.dtype} {list(position.shape)}")
    wrench = arrays.get("external_wrench")
    if wrench is not None and (wrench.dtype != np.float64 or wrench.shape != (T, n, 6)):
        fail(f"external_wrench must be float64 [{T},{n},6], got {wrench.dtype} {list(wrench.shape)}")
    try:
        json.dumps(meta)
    except TypeError as exc:
        fail(f"meta must be JSON-serialisable: {exc}")


def check_frames(R: np.ndarray, angular_velocity: np.ndarray, links: tuple[str, ...], where: str = "recording",
                 first_frame: int = 0) -> None:
    """No Inf, and every known orientation R [T,n,3,3] a rotation to the tracker's projection
    tolerance; frame numbers in messages count from `first_frame`."""
    known = ~np.isnan(R).any(axis=(-1, -2))
    if np.isinf(R).any() or np.isinf(angular_velocity).any():
        raise RecordingError(f"{where}: orientation or angular_velocity holds Inf (use NaN to mark missing data)")
    if known.any():
        # the tracker projects rotations this close to SO(3) (noise, float32 exports) and counts them
        Rk = R[known]
        with np.errstate(over="ignore", invalid="ignore"):  # huge entries: an infinite error, refused below
            error = np.linalg.norm(np.swapaxes(Rk, -1, -2) @ Rk - np.eye(3), axis=(-1, -2))
            det = np.linalg.det(Rk)
        bad = (error > PROJECT_TOLERANCE) | (det < 0)
        if bad.any():
            first = int(np.argmax(bad))
            t, i = np.argwhere(known)[first]
            raise RecordingError(f"{where}: orientation of {links[i]!r} at frame {first_frame + t} is not a rotation "
                                 f"(||R^T R - I|| = {error[first]:.2g}, det = {det[first]:.3g})")


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
    if rec.external_wrench is not None:
        arrays.update(external_wrench=rec.external_wrench)
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

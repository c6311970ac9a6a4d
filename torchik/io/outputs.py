"""What an estimated trajectory is written as, by its file's suffix (`torchik track --out FILE`):
torchik's `.npz` (trajectory.py), OpenSim's motion `.mot` and OpenSense's orientation errors `.sto`
(opensim_out.py). Each writer takes the run a part at a time (`write(trajectory, targets)`) and
writes its file on `commit`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..method.kinematics import KinematicModel
from .opensim_out import MotionWriter, OrientationErrorWriter
from .recording import RecordingError
from .trajectory import TrajectoryWriter

OUT_SUFFIXES = (".npz", ".mot", ".sto")  # torchik's trajectory, OpenSim's motion, OpenSense's orientation errors


def check_output_suffix(path: str | Path, option: str = "") -> None:
    """RecordingError, before any work, for a path whose suffix names no output (the message starts
    with `option`, the command's option that gave it, when given)."""
    if Path(path).suffix.lower() not in OUT_SUFFIXES:
        raise RecordingError(f"{option + ' ' if option else ''}{path}: the suffix says what to write: "
                             f"{', '.join(OUT_SUFFIXES)}")


def trajectory_writer(path: str | Path, model: KinematicModel, links, names: dict[str, str] | None = None,
                      notes: dict[str, str] | None = None) -> Any:
    """The writer of `path` by its suffix. links: the tracked links (the orientation errors' columns),
    named by `names` (link -> the source's name, e.g. an IMU's; default the link's); notes:
    header lines of a motion (how its base was tracked)."""
    check_output_suffix(path)
    suffix = Path(path).suffix.lower()
    if suffix == ".npz":
        return TrajectoryWriter(path, model)
    if suffix == ".mot":
        return MotionWriter(path, model, notes)
    return OrientationErrorWriter(path, model, links, [(names or {}).get(link, link) for link in links])

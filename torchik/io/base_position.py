"""Recordings that measure no base position (an IMU set: OpenSense tables), and what the tracker
does about it: hold the base at a chosen point or leave it free, said in the report, never zeros
taken as data.

- `held`: the base's position target is a constant point (the model's standing base position at
  the origin, or the one given), its velocity zero: the body stays in place, as OpenSense's IMU IK
  does (it does not solve for the pelvis translation).
- `free`: no position target at all: the base translation goes where the orientations and the
  model's regularisation take it (nothing measures it).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .recording import Recording

BASE_POSITION_MODES = ("held", "free")
NOT_MEASURED = "not measured"  # meta["base_position"] of a recording whose reader had no positions


def measures_base_position(recording: Recording) -> bool:
    """Whether the recording's base position is measured: its reader did not declare it missing
    (meta["base_position"]) and some frame holds one."""
    if recording.meta.get("base_position") == NOT_MEASURED:
        return False
    return bool(np.isfinite(recording.base_position).all(-1).any())


def hold_base(recording: Recording, position) -> Recording:
    """The recording with its base position target held at `position` [3] (m, world) and its
    velocity zero, meta["base_position"] saying where it is held (not measured)."""
    T = len(recording.time)
    point = np.asarray(position, dtype=np.float64).reshape(3)
    meta = dict(recording.meta, base_position=f"held at {np.round(point, 4).tolist()} m (not measured)")
    return dataclasses.replace(recording, base_position=np.tile(point, (T, 1)),
                               base_linear_velocity=np.zeros((T, 3)), meta=meta)


def base_position_note(mode: str, position=None) -> str:
    """The report's line for a recording without base positions tracked in `mode` (held at `position`)."""
    if mode == "held":
        return f"not measured: held at {np.round(np.asarray(position, dtype=float), 4).tolist()} m"
    return "not measured: free (no position target; the base translation is not an estimate)"


def standing_base_position(model) -> np.ndarray:
    """[3] m: the base position at which the model's zero posture stands on the ground plane z = 0 at the
    origin: its lowest link origin (an ankle, a toe) on the ground. Where `held` holds the base."""
    import torch

    p, R, s = model.zero_configuration(1)
    with torch.no_grad():
        origins = model(p, R, s, tuple(model.link_names), jacobian=False).position[0]
    return np.array([0.0, 0.0, -float(origins[:, 2].min())])


def unmeasured_base(recording: Recording, mode: str, standing) -> tuple[Recording, str]:
    """A recording that measures no base position made ready to track in `mode` ("held": held at
    `standing` [3], m, the model's standing base position; "free": left as it is, NaN, for a run
    without position targets), with the report's line saying so."""
    if mode not in BASE_POSITION_MODES:
        raise ValueError(f"base position mode {mode!r}: expected one of {', '.join(BASE_POSITION_MODES)}")
    if mode == "held":
        return hold_base(recording, standing), base_position_note("held", standing)
    return recording, base_position_note("free")

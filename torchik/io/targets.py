"""Tracker targets from a recording: the conversion of measured data to what a step consumes."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..errors import InputError
from ..method.state import TargetSequence
from .recording import Recording


def recording_targets(recording: Recording, orientation_links, position_links=None, dtype=torch.float64,
                      device="cpu") -> TargetSequence:
    """Tracker targets from a recording whose link names are the model's (B = 1). Missing links: an
    error listing them. The position targets: the base link's (default), or those of `position_links`
    (the recording's `position` for links other than the base)."""
    orientation_links = tuple(orientation_links)
    position_links = tuple(position_links) if position_links is not None else (recording.base_link,)
    index = {name: i for i, name in enumerate(recording.links)}
    missing = [name for name in orientation_links if name not in index]
    if missing:
        raise InputError(f"the recording has no {missing}; it has {list(recording.links)} (use a link map)")
    off_base = [name for name in position_links if name != recording.base_link]
    if off_base and recording.position is None:
        raise InputError(f"the recording gives the position of its base link {recording.base_link!r} only; "
                         f"it has none for {off_base}")
    unknown = [name for name in off_base if name not in index]
    if unknown:
        raise InputError(f"no position targets for {unknown}: the recording has no such links; "
                         f"it has {list(recording.links)}")
    ids = [index[name] for name in orientation_links]
    kw: dict[str, Any] = dict(dtype=dtype, device=device)
    as_tensor = lambda a: torch.as_tensor(np.ascontiguousarray(a), **kw)  # noqa: E731
    position, velocity = _positions(recording, [index[name] for name in position_links])
    return TargetSequence(
        as_tensor(recording.time),
        as_tensor(position)[:, None],
        as_tensor(velocity)[:, None],
        as_tensor(recording.orientation[:, ids])[:, None],
        as_tensor(recording.angular_velocity[:, ids])[:, None])


def _positions(recording: Recording, ids: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Positions and linear velocities [T,n_p,3] of the links `ids`: the base's as recorded, the others
    from `position` with velocities by central differences (NaN next to a gap)."""
    base = recording.links.index(recording.base_link)
    T = len(recording.time)
    measured = recording.position if recording.position is not None else np.full((T, len(recording.links), 3), np.nan)
    position, velocity = np.empty((T, len(ids), 3)), np.empty((T, len(ids), 3))
    for k, i in enumerate(ids):  # a handful of targets, once per recording
        if i == base:
            position[:, k], velocity[:, k] = recording.base_position, recording.base_linear_velocity
        else:
            position[:, k] = measured[:, i]
            velocity[:, k] = np.gradient(position[:, k], recording.time, axis=0) if T > 1 else 0.0
    return position, velocity

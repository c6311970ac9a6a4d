"""Tracker targets from a recording: the conversion of measured data to what a step consumes."""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..method.state import TargetSequence
from .recording import Recording


def recording_targets(recording: Recording, orientation_links, position_links=None, dtype=torch.float64,
                      device="cpu") -> TargetSequence:
    """Tracker targets from a recording whose link names are the model's (B = 1). Missing links: an
    error listing them. The base position target is the recording's base link."""
    orientation_links = tuple(orientation_links)
    position_links = tuple(position_links) if position_links is not None else (recording.base_link,)
    index = {name: i for i, name in enumerate(recording.links)}
    missing = [name for name in orientation_links if name not in index]
    if missing:
        raise InputError(f"the recording has no {missing}; it has {list(recording.links)} (use a link map)")
    if any(name != recording.base_link for name in position_links):
        raise InputError(f"a recording gives the position of its base link {recording.base_link!r} only")
    ids = [index[name] for name in orientation_links]
    kw = dict(dtype=dtype, device=device)
    as_tensor = lambda a: torch.as_tensor(np.ascontiguousarray(a), **kw)  # noqa: E731
    n_p = len(position_links)
    return TargetSequence(
        as_tensor(recording.time),
        as_tensor(recording.base_position)[:, None, None].expand(-1, 1, n_p, 3).clone(),
        as_tensor(recording.base_linear_velocity)[:, None, None].expand(-1, 1, n_p, 3).clone(),
        as_tensor(recording.orientation[:, ids])[:, None],
        as_tensor(recording.angular_velocity[:, ids])[:, None])

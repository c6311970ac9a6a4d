"""Tracker targets from a recording: the conversion of measured data to what a step consumes."""

from __future__ import annotations

from typing import Any, Iterable, Iterator

import numpy as np
import torch

from ..errors import InputError
from ..method.state import TargetSequence
from .recording import Recording


def recording_targets(recording: Recording, orientation_links, position_links=None, dtype=torch.float64,
                      device="cpu", before: Recording | None = None, after: Recording | None = None) -> TargetSequence:
    """Tracker targets from a recording whose link names are the model's (B = 1). Missing links: an
    error listing them. The position targets: the base link's (default), or those of `position_links`
    (the recording's `position` for links other than the base). before, after: the chunks around
    `recording` when it is one of a longer recording's (`target_chunks`): their frames next to it
    make its velocities by central differences those of the whole."""
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
    position, velocity = _positions(recording, [index[name] for name in position_links], before, after)
    return TargetSequence(
        as_tensor(recording.time),
        as_tensor(position)[:, None],
        as_tensor(velocity)[:, None],
        as_tensor(recording.orientation[:, ids])[:, None],
        as_tensor(recording.angular_velocity[:, ids])[:, None])


def target_chunks(chunks: Iterable[Recording], orientation_links, position_links=None, dtype=torch.float64,
                  device="cpu") -> Iterator[tuple[Recording, TargetSequence]]:
    """`recording_targets` of a recording given in chunks (in order): each chunk with its targets,
    equal to the whole recording's over its frames. A chunk is read ahead of the one returned."""
    previous = current = None
    for upcoming in chunks:
        if current is not None:
            yield current, recording_targets(current, orientation_links, position_links, dtype, device, previous, upcoming)
        previous, current = current, upcoming
    if current is not None:
        yield current, recording_targets(current, orientation_links, position_links, dtype, device, previous)


def _positions(recording: Recording, ids: list[int], before: Recording | None = None,
               after: Recording | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions and linear velocities [T,n_p,3] of the links `ids`: the base's as recorded, the others
    from `position` with velocities by central differences (NaN next to a gap), over the recording's
    frames and the frames of `before` and `after` next to them."""
    base = recording.links.index(recording.base_link)
    T = len(recording.time)
    first = 1 if before is not None else 0
    time, measured = recording.time, None
    if any(i != base for i in ids):
        frames = ([(before.time[-1:], _measured(before)[-1:])] if before is not None else []) + [
            (recording.time, _measured(recording))] + ([(after.time[:1], _measured(after)[:1])] if after is not None else [])
        time, measured = (np.concatenate(parts) for parts in zip(*frames))
    position, velocity = np.empty((T, len(ids), 3)), np.empty((T, len(ids), 3))
    for k, i in enumerate(ids):  # a handful of targets, once per recording
        if i == base:
            position[:, k], velocity[:, k] = recording.base_position, recording.base_linear_velocity
        else:
            assert measured is not None  # made above for the links off the base
            position[:, k] = measured[first:first + T, i]
            velocity[:, k] = central_differences(measured[:, i], time)[first:first + T] if len(time) > 1 else 0.0
    return position, velocity


def _measured(recording: Recording) -> np.ndarray:
    """The segment origins [T,n,3] (NaN where the recording has none)."""
    if recording.position is not None:
        return recording.position
    return np.full((len(recording.time), len(recording.links), 3), np.nan)


def central_differences(values: np.ndarray, time: np.ndarray) -> np.ndarray:
    """d values / d time [T,...] (T >= 2): np.gradient's second-order differences for uneven steps at
    every inner sample, one-sided at the ends. Written out because np.gradient switches to another
    formula when the steps are exactly even: a chunk's few samples would then differ, in the last
    bits, from the same samples in the whole recording."""
    step = np.diff(time).reshape(-1, *(1,) * (values.ndim - 1))
    before, after = step[:-1], step[1:]
    out = np.empty_like(values)
    out[1:-1] = (-after / (before * (before + after)) * values[:-2] + (after - before) / (before * after) * values[1:-1]
                 + before / (after * (before + after)) * values[2:])
    out[0] = (values[1] - values[0]) / step[0]
    out[-1] = (values[-1] - values[-2]) / step[-1]
    return out

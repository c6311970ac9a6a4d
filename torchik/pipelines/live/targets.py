"""Tracker targets from live samples: which of a source's segments are the tracked links
(`Selection`), and the batch's targets of one step, with the arithmetic of `apply_map` and
`recording_targets` offline (rows picked, offsets applied, rotations projected), for all characters
at once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...errors import InputError
from ...io.maps import LinkMap
from ...live.mvn import rotations
from ...live.sample import Sample
from ...method import so3
from ...method.targets import Targets


@dataclass(frozen=True)
class Selection:
    """Which of a source's segments are the tracked links, in the model's frames: source rows
    `rows` [n_o] turned by `offsets` [n_o,3,3] (R_link = R_segment C); the base segment's row."""

    links: tuple[str, ...]
    rows: np.ndarray
    offsets: np.ndarray | None
    base_row: int

    @classmethod
    def build(cls, source_links, links, link_map: LinkMap | None = None) -> "Selection":
        """From a map (its offsets calibrated), or, without one, the source's segments named as `links`."""
        index = {name: i for i, name in enumerate(source_links)}
        if link_map is None:
            missing = [name for name in links if name not in index]
            if missing:
                raise InputError(f"the stream has no segments {missing} (it has {list(source_links)}); give --map")
            return cls(tuple(links), np.array([index[n] for n in links]), None, index[links[0]])
        missing = sorted({e.segment for e in link_map.entries} - set(index))
        if missing:
            raise InputError(f"map {link_map.name!r} needs segments {missing} that the stream lacks; "
                             f"it has {list(source_links)}")
        offsets = [e.offset for e in link_map.entries if e.offset is not None]
        if len(offsets) < len(link_map.entries):
            raise InputError(f"map {link_map.name!r} calibrates its offsets: give --calibration STATIC_TRIAL")
        return cls(link_map.links, np.array([index[e.segment] for e in link_map.entries]),
                   np.stack(offsets), index[link_map.base_segment])


def sample_targets(samples: list[Sample | None], selection: Selection, dtype=torch.float64, device="cpu") -> Targets:
    """Tracker targets [B,...] from one sample per character (None: all its targets dropped)."""
    B, rows = len(samples), selection.rows
    present = [b for b, s in enumerate(samples) if s is not None]
    given = [s for s in samples if s is not None]
    quaternion = _stacked(given, present, B, "quaternion", rows)
    angular_velocity = _stacked(given, present, B, "angular_velocity", rows)
    base = np.array([selection.base_row])
    position = _stacked(given, present, B, "position", base)[:, 0]
    velocity = _stacked(given, present, B, "velocity", base)[:, 0]
    return mapped_targets(rotations(quaternion), angular_velocity, position, velocity, selection.offsets, dtype, device)


def _stacked(given: list[Sample], present: list[int], B: int, name: str, rows: np.ndarray) -> np.ndarray:
    """Field `name` of the given samples at segment rows `rows`, as [B,len(rows),k]; NaN for the
    characters without a sample or without the field."""
    values = [getattr(s, name) for s in given]
    every_field = all(v is not None for v in values)
    if values and every_field and len(given) == B:  # the usual step: one stack, no fill
        return np.stack(values)[:, rows]
    width = 4 if name == "quaternion" else 3
    out = np.full((B, len(rows), width), np.nan)
    if values and every_field:  # some characters without a sample: one stack into their rows
        out[present] = np.stack(values)[:, rows]
    else:  # a source that carries the field for some characters only (rare): row by row
        for b, v in zip(present, values):
            if v is not None:
                out[b] = v[rows]
    return out


def mapped_targets(rotation: np.ndarray, angular_velocity: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                   offsets: np.ndarray | None, dtype=torch.float64, device="cpu") -> Targets:
    """Targets of the links from their segments' rotation [B,n,3,3], angular velocity [B,n,3] and the
    base's position and velocity [B,3]: R_link = R_segment C (offsets C [n,3,3] or None), projected
    onto SO(3) where known, as `apply_map` does offline."""
    if offsets is not None:
        rotation = rotation @ offsets
        known = ~np.isnan(rotation).any(axis=(-1, -2))
        if known.any():
            rotation[known] = so3.project(torch.from_numpy(rotation[known])).numpy()
    as_tensor = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(dtype=dtype, device=device)  # noqa: E731
    return Targets(as_tensor(position[:, None]), as_tensor(velocity[:, None]), as_tensor(rotation),
                   as_tensor(angular_velocity))


def retargeted(targets: Targets, selection: Selection, dtype=torch.float64, device="cpu") -> Targets:
    """Targets in another model's links from `targets` in the tracked ones (a second map, e.g.
    human_to_icub), the base's position and velocity carried over."""
    host = lambda t: t.detach().to("cpu", torch.float64).numpy()  # noqa: E731
    rotation = host(targets.rotation)[:, selection.rows]
    return mapped_targets(rotation, host(targets.angular_velocity)[:, selection.rows], host(targets.position)[:, 0],
                          host(targets.linear_velocity)[:, 0], selection.offsets, dtype, device)

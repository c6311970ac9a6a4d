"""The plates' contacts given to the feet: which link each ground reaction acts on.

A contact is a run of frames in which a plate is loaded (`GroundReactions.contact`). A foot is the
segment from its heel to its toe (for Plug-in Gait, the markers LHEE-LTOE and RHEE-RTOE), and its
distance to a contact is the median, over the contact's frames where the foot is seen, of the
distance from the centre of pressure to that segment in the plate's plane. The contact goes to the
nearest foot within `MAX_DISTANCE` (0.15 m); to none beyond it (a hand, a walking aid, a foot
whose markers are lost), said in the contact.

Unless two feet stand on the plate: a foot stands on a plate in a frame when its heel and toe both
lie over the surface (within `MARGIN`, 0.03 m, of its edges) and the lower of them within
`STANDING_HEIGHT` (0.1 m) of it, and over a contact when it does in half its frames or more (a
swinging foot crosses a plate in a few frames). One plate cannot tell two feet's loads apart: such
a contact is `shared`, given to no foot, and the feet on it have an unknown (NaN) wrench over it.

`link_wrenches` gives each link the sum of its contacts' wrenches: [T,n,6], the force (N) and the
moment about the world origin (N m), world frame; zero where no plate's contact is on the link (a
foot in the air, or on the floor off the plates: the plates do not see it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .force_plates import ForcePlate, GroundReactions

MAX_DISTANCE = 0.15  # m from the centre of pressure to the heel-toe segment
MARGIN = 0.03  # m beyond a plate's edges that a marker still counts as over it
STANDING_HEIGHT = 0.1  # m above a plate's surface


@dataclass(frozen=True)
class Contact:
    """Plate `plate` (numbered from 1) loaded over frames [start, stop), given to `link` (None: to no
    foot), whose distance to the centre of pressure is `distance` m (the nearest foot's when none is
    given; NaN when no foot is seen); `shared`: the feet standing on the plate when more than one."""

    plate: int
    start: int
    stop: int
    link: str | None
    distance: float
    shared: tuple[str, ...] = ()
    overhang: tuple[tuple[int, int], ...] = ()  # the runs [start, stop) of frames its foot overhangs the plate

    def to_json(self) -> dict:
        return dict(plate=self.plate, start_frame=self.start, stop_frame=self.stop, link=self.link,
                    distance_m=None if np.isnan(self.distance) else round(self.distance, 4), shared=list(self.shared),
                    overhang_frames=[list(run) for run in self.overhang])


def runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """The runs [start, stop) of True in flags [T]."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], flags.astype(np.int8), [0]))))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def assign_contacts(reactions: GroundReactions, feet: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[Contact]:
    """Each plate's contacts given to one of `feet` (link name -> heel [T,3], toe [T,3], m, world,
    NaN where not seen), as the module docstring says; in the order of the plates, then of time."""
    found = []
    for k, plate in enumerate(reactions.plates):  # a few plates
        for start, stop in runs(reactions.contact[:, k]):
            cop = reactions.cop[start:stop, k]
            distance = {link: _median_distance(plate, cop, heel[start:stop], toe[start:stop])
                        for link, (heel, toe) in feet.items()}
            standing = tuple(link for link, (heel, toe) in feet.items()
                             if _stands(plate, heel[start:stop], toe[start:stop]))
            seen = {link: d for link, d in distance.items() if np.isfinite(d)}
            nearest = min(seen, key=seen.__getitem__) if seen else None
            d = seen[nearest] if nearest else float("nan")
            if len(standing) > 1:
                found.append(Contact(plate.number, start, stop, None, d, standing))
            else:
                link = nearest if d <= MAX_DISTANCE else None
                overhang = () if link is None else tuple(
                    (start + a, start + b) for a, b in runs(_overhangs(plate, *(x[start:stop] for x in feet[link]))))
                found.append(Contact(plate.number, start, stop, link, d, overhang=overhang))
    return found


def link_wrenches(reactions: GroundReactions, contacts: list[Contact], links: tuple[str, ...]) -> np.ndarray:
    """[T,n,6]: each link's contacts' force and moment about the world origin summed (module docstring)."""
    out = np.zeros((len(reactions.time), len(links), 6))
    column = {plate.number: k for k, plate in enumerate(reactions.plates)}
    for c in contacts:
        k = column[c.plate]
        if c.link in links:
            i = links.index(c.link)
            out[c.start:c.stop, i, :3] += reactions.force[c.start:c.stop, k]
            out[c.start:c.stop, i, 3:] += reactions.moment[c.start:c.stop, k]
        for link in c.shared:
            if link in links:
                out[c.start:c.stop, links.index(link)] = np.nan
    return out


def _in_plane(plate: ForcePlate, v: np.ndarray) -> np.ndarray:
    """v [...,3] without its component along the plate's normal."""
    return v - (v @ plate.up)[..., None] * plate.up


def _median_distance(plate: ForcePlate, cop: np.ndarray, heel: np.ndarray, toe: np.ndarray) -> float:
    """The median over frames of the in-plane distance from cop [F,3] to the segment heel-toe [F,3] (NaN if never seen)."""
    a, v = _in_plane(plate, heel - cop), _in_plane(plate, toe - heel)  # the segment from the COP: a + t v
    length = (v * v).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip(-(a * v).sum(-1) / np.where(length > 0, length, np.inf), 0.0, 1.0)
    d = np.linalg.norm(a + t[:, None] * v, axis=-1)
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size else float("nan")


def _overhangs(plate: ForcePlate, heel: np.ndarray, toe: np.ndarray) -> np.ndarray:
    """[F] whether the heel or the toe [F,3] lies beyond the plate's edges, in its plane (False where unseen)."""
    local = (np.stack((heel, toe), 1) - plate.centre) @ plate.rotation  # [F,2,3] in the plate's frame
    half = np.abs((plate.corners - plate.centre) @ plate.rotation).max(0)[:2]
    with np.errstate(invalid="ignore"):
        return (np.abs(local[..., :2]) > half).any(-1).any(-1)


def stands_on(plate: ForcePlate, heel: np.ndarray, toe: np.ndarray, margin: float = MARGIN) -> np.ndarray:
    """[F] whether the foot (heel, toe [F,3]) stands on the plate in each frame: both lie over its
    surface, within `margin` m beyond its edges (a negative margin: that far inside them), and the
    lower within STANDING_HEIGHT of it (False where unseen)."""
    local = (np.stack((heel, toe), 1) - plate.centre) @ plate.rotation  # [F,2,3] in the plate's frame
    half = np.abs((plate.corners - plate.centre) @ plate.rotation).max(0)[:2]
    with np.errstate(invalid="ignore"):
        over = (np.abs(local[..., :2]) <= half + margin).all(-1).all(-1)
        low = ((np.stack((heel, toe), 1) - plate.centre) @ plate.up).min(-1) <= STANDING_HEIGHT
    return over & low


def _stands(plate: ForcePlate, heel: np.ndarray, toe: np.ndarray) -> bool:
    """Whether the foot (heel, toe [F,3]) stands on the plate in half the frames or more."""
    return bool(stands_on(plate, heel, toe).sum() * 2 >= len(heel))

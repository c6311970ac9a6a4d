"""The subject weighed on the force plates: what a static trial's plates say of the body mass.

A subject standing still with every foot on a plate puts its whole weight on the plates, so its
mass is the plates' summed vertical force over g, averaged over those frames (the centre of mass'
vertical acceleration averages out over a still stretch). A frame counts when

- every foot stands on a plate, its heel and toe within the plate's edges (no `MARGIN` beyond them:
  a foot overhanging its plate puts part of its weight on the floor) and low over it
  (`foot_contacts.stands_on`);
- the subject is still: the base (the pelvis' origin) moves slower than `STILL_SPEED` (0.05 m/s; a
  walk's pelvis moves at 1 m/s or more, a static trial's at a few mm/s);
- some plate is loaded and every plate's wrench is finite.

`weigh` needs `MIN_STILL` (0.2 s) of such frames, else it gives no mass and says why (a walk, a
trial without plates, a foot off the plates or unseen): the subject's mass then comes from
elsewhere (the file's PROCESSING:Bodymass, io/subjects.py). The plates see only what stands on
them: a hand on a rail off the plates would go unweighed, which no check here can tell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..method.dynamics.inverse import GRAVITY
from .foot_contacts import stands_on
from .force_plates import GroundReactions

STILL_SPEED = 0.05  # m/s of the base: slower is standing still
MIN_STILL = 0.2  # s of still frames with every foot on a plate


@dataclass(frozen=True)
class Weighing:
    """What the plates weigh the subject at: `mass` (kg) and the standard deviation of the plates'
    vertical force over g across the frames (`sd`, kg), over `frames` frames; mass None with
    `why_not` saying why where the plates cannot weigh the subject."""

    mass: float | None
    sd: float | None
    frames: int
    why_not: str | None = None

    def to_json(self) -> dict:
        return dict(mass_kg=self.mass, sd_kg=self.sd, frames=self.frames, why_not=self.why_not)


def weigh(reactions: GroundReactions, feet: dict[str, tuple[np.ndarray, np.ndarray]],
          base_position: np.ndarray, time: np.ndarray) -> Weighing:
    """The subject weighed on `reactions`' plates (module docstring). feet: every foot's link name ->
    heel [T,3], toe [T,3] (m, world, NaN where unseen); base_position [T,3] m (NaN where unseen);
    time [T] s."""
    if not reactions.plates:
        return Weighing(None, None, 0, "the file has no force plates")
    T = len(time)
    if len(feet) < 2:
        return Weighing(None, None, 0, f"the file marks the heel and toe of {', '.join(feet) or 'no foot'} only")
    on = {link: np.zeros(T, dtype=bool) for link in feet}
    for link, (heel, toe) in feet.items():
        for plate in reactions.plates:  # a few plates
            on[link] |= stands_on(plate, heel, toe, margin=0.0)
    every = np.logical_and.reduce(list(on.values()))
    if not every.any():
        counts = ", ".join(f"{link} in {int(flags.sum())}" for link, flags in on.items())
        return Weighing(None, None, 0, f"no frame has every foot wholly on a plate (of {T} frames: {counts})")
    speed = np.linalg.norm(np.gradient(base_position, time, axis=0), axis=-1) if T > 1 else np.full(T, np.nan)
    with np.errstate(invalid="ignore"):
        still = speed < STILL_SPEED
    vertical = reactions.force[..., 2].sum(-1)  # [T] N, world z up
    frames = every & still & np.isfinite(vertical) & reactions.contact.any(-1)
    if not frames.any():
        return Weighing(None, None, 0, f"the subject moves: the pelvis goes {STILL_SPEED} m/s or faster (or is unseen) in "
                                       f"all {int(every.sum())} frames with every foot on a plate")
    rate = (T - 1) / (time[-1] - time[0]) if T > 1 else 1.0
    n = int(frames.sum())
    if n < MIN_STILL * rate:
        return Weighing(None, None, n, f"only {n} still frames with every foot on a plate ({n / rate:.2f} s; "
                                       f"{MIN_STILL} s needed)")
    g = float(np.linalg.norm(GRAVITY))
    return Weighing(float(vertical[frames].mean() / g), float(vertical[frames].std() / g), n)

"""Refinement: the effects of a round fitted again on the data they corrected, and the earlier ones
of their kind beside them.

The fits are linearised and the tracker absorbs part of an effect, so the loop refines each round's
effects: each is fitted again (Subject.refit) on its subject's data corrected by every kept effect,
and the correction found (a Gauss-Newton step) is added to it and to the data. An effect kept in
an earlier round was fitted before a related effect of its kind was in place, and kept the share of
that effect's residual it took; it is refined in the same pass (`neighbours_kept`).
"""

from __future__ import annotations

import copy
from typing import Sequence

from . import elimination, joints
from .effect import Effect
from .subject import Subject, analyse_subjects


def refine(rounds: Sequence[tuple[Subject, list[Effect]]], links, gain: float, progress: bool,
           max_samples: int) -> set[int]:
    """One refinement pass over the subjects and the effects their round chose (`rounds`), with the
    earlier effects of their kind beside them; the subjects that moved are tracked again (one batch
    per model). A missing axis is not refined (its angle is fitted sample by sample already), nor an
    earlier effect whose refinement would leave a body's or a sensor's bounds: the loop's check of
    plausibility judges this round's effects once refined, not the earlier ones. Returns the ids of
    the subjects whose earlier effects were refined (a round taken back leaves those as refined)."""
    moved, earlier = {}, set()  # those left as they were keep their analysis: re-tracking would give it again
    for s, chosen in rounds:
        neighbours = neighbours_kept(s, chosen, links)
        for effect in chosen + neighbours:
            update = None if isinstance(effect, joints.MissingDof) else s.refit(effect)
            if update is None or update.within_error():
                continue
            neighbour = any(effect is n for n in neighbours)
            if neighbour and _refined_beyond(effect, update):
                continue
            s.add(update)
            effect.refine(update)
            moved[id(s)] = s
            if neighbour:
                earlier.add(id(s))
    analyse_subjects(list(moved.values()), links, gain, progress, max_samples)
    return earlier


def neighbours_kept(s: Subject, chosen: list[Effect], links) -> list[Effect]:
    """The measurement effects of subject s kept in earlier rounds that share a residual with one of
    `chosen` of their kind (elimination.related). 10007's L5 sensor, turned 21 deg beside a turned
    L3, was fitted at 42 deg before L3's turn was taken out, and missing twist axes at both its
    joints then took up the rest. Of every kind (tried first), 15007's forearm drift, refined in the
    round that added a wrist's missing axis, went from -3.4 to -4.0 deg/s (-2.7 injected)."""
    return [e for e in s.effects if not e.model_effect  # the round's own are not among them until _check
            and any(c.kind == e.kind and elimination.related(e, c, s.model, s.urdf, links) for c in chosen)]


def _refined_beyond(effect: Effect, update: Effect) -> bool:
    """Whether `effect` refined by `update` would be implausible (beyond a body's or a sensor's bounds)."""
    return bool(copy.deepcopy(effect).refine(update).implausible())

"""A sensor's effect taken by its neighbour's sensor.

A strap turned on a lumbar segment, or a marker cluster on a toe, leaves its residual on both sides
of the segment's joints: the joints follow what they can of the turn, and what they cannot is shared
between the turned segment and its neighbours. In the first rounds the neighbour's candidate can
score best (L3 between a turned T12 and the pelvis takes a share of both), and once it is kept the
turned segment's own candidate explains only what is left and is not significant. Greedy selection
keeps the first; the data tell the two apart only once the right one is fitted with everything else
in place.

So once the loop has ended, each kept misalignment is tried on each tracked neighbour of its link
that carries none: the recording without it, the misalignment fitted on the neighbour, then on the
first link again (both sensors may be turned), re-tracked. Where the tracking error the effect acts
on is then lower by more than CLEARLY_BETTER, the neighbour's effect replaces it. The margin is wide:
where the two are confounded (the data see the two sensors' difference, not which one turned;
Diagnosis.confounded), the first stays.
"""

from __future__ import annotations

from typing import Callable

from .crossing import fitted, rebuilt
from .effect import Effect
from .result import Step, errors
from .subject import Subject, analyse_subjects

KINDS = ("misalignment",)  # heading drifts too, by the same code; on the study's recordings none moved
CLEARLY_BETTER = 0.05  # the share by which the neighbour's version must lower the error to replace the first


def moved_to_neighbours(s: Subject, links, gain: float, threshold: float, progress: bool, max_samples: int,
                        say: Callable[[str], None]) -> int:
    """Try each kept effect of KINDS of subject s on its link's neighbours (module
    docstring) and adopt the clearly better. Returns how many were moved."""
    moved = 0
    for first in [e for e in s.effects if e.kind in KINDS]:
        if not any(first is e for e in s.effects):  # replaced by an earlier move
            continue
        taken = {e.target for e in s.effects if e.kind == first.kind}
        others = [n for n in s.neighbours(first.target) if n in links and n not in taken]
        if others and _move(s, first, others, links, gain, threshold, progress, max_samples, say):
            moved += 1
    return moved


def _move(s: Subject, first: Effect, others: list[str], links, gain: float, threshold: float, progress: bool,
          max_samples: int, say: Callable[[str], None]) -> bool:
    """moved_to_neighbours' try of `first` on each of `others` (the variants tracked as one batch);
    adopts the best into s where it is clearly better. Returns whether one was adopted."""
    variants = [rebuilt(s, (first,)) for _ in others]
    analyse_subjects(variants, links, gain, progress, max_samples)
    tried = []
    for v, other in zip(variants, others):
        effect, why = fitted(v, first.kind, other, threshold, links)
        if effect is None:
            say(f"{first.kind} at {first.target} stays: at {other} it does not fit ({why})")
        else:
            tried.append((v, other, effect))
    if not tried:
        return False
    _add_tracked([(v, effect) for v, _, effect in tried], links, gain, progress, max_samples)
    # both sensors may be turned; a drift tried beside the same drift on the first would split one
    # sensor's drift across a joint that cannot tell them apart (a knee, about the vertical)
    again = [(v, fitted(v, first.kind, first.target, threshold, links)[0]) for v, *_ in tried
             if first.kind == "misalignment"]
    _add_tracked([(v, e) for v, e in again if e is not None], links, gain, progress, max_samples)
    before = errors(*s.current).overall[first.error]
    scored = sorted(((errors(*v.current).overall[first.error], v, other, effect) for v, other, effect in tried),
                    key=lambda t: t[0])
    for after, _, other, _ in scored:
        say(f"{first.kind} at {first.target} tried at {other}: the {first.error} {before:.4g} -> {after:.4g}")
    after, v, other, effect = scored[0]
    if after >= before * (1 - CLEARLY_BETTER):
        return False
    first.notes = "; ".join(filter(None, [first.notes, f"replaced by a {first.kind} at {other}: with it, the "
                                                       f"{first.error} went from {before:.4g} to {after:.4g}"]))
    s.rejected.append(first)
    effect.notes = "; ".join(filter(None, [effect.notes, f"in place of a {first.kind} at {first.target}, which "
                                                         f"took a share of its residual across their joint"]))
    s.recording, s.urdf, s.model, s.analysis, s.steps = v.recording, v.urdf, v.model, v.analysis, v.steps
    say(f"{first.kind} at {first.target} moved to {other} ({first.error} {before:.4g} -> {after:.4g})")
    return True


def _add_tracked(added: list[tuple[Subject, Effect]], links, gain: float, progress: bool, max_samples: int) -> None:
    """crossing.add_tracked for several variants at once: each effect added to its variant, the variants
    tracked as one batch, each addition's step recorded."""
    before = [errors(*v.current) for v, _ in added]
    for v, effect in added:
        v.add(effect)
    analyse_subjects([v for v, _ in added], links, gain, progress, max_samples)
    for (v, effect), b in zip(added, before):
        v.steps.append(Step(effect, b, errors(*v.current)))

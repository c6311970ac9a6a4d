"""A sensor's effect taken by its neighbour's sensor.

A strap turned on a lumbar segment, or a marker cluster on a toe, leaves its residual on both sides
of the segment's joints: the joints follow what they can of the turn, and what they cannot is shared
between the turned segment and its neighbours. In the first rounds the neighbour's candidate can
score best (L3 between a turned T12 and the pelvis takes a share of both), and once it is kept the
turned segment's own candidate explains only what is left and is not significant. Greedy selection
keeps the first; the data tell the two apart only once the right one is fitted with everything else
in place.

So once the loop has ended, each kept misalignment is tried on each tracked neighbour of its link
that carries none and whose residual is still above the misalignment's floor (a degree): the
recording without it, the misalignment fitted on the neighbour, re-tracked. Where the tracking error
the effect acts on is then lower by more than CLEARLY_BETTER, the neighbour's effect replaces it, and
the first link's is fitted again beside it (both sensors may be turned). The margin is wide: where
the two are confounded (the data see the two sensors' difference, not which one turned;
Diagnosis.confounded), the first stays.
"""

from __future__ import annotations

from typing import Callable

from .analysis import link_summary
from .crossing import add_tracked, add_tracked_all, fitted, rebuilt, take
from .placement import MISALIGNMENT_FLOOR, Misalignment
from .result import errors
from .subject import Subject, analyse_subjects

CLEARLY_BETTER = 0.05  # the share by which the neighbour's version must lower the error to replace the first


def moved_to_neighbours(s: Subject, links, gain: float, threshold: float, progress: bool, max_samples: int,
                        say: Callable[[str], None]) -> int:
    """Try each kept misalignment of subject s on its link's neighbours (module docstring) and adopt
    the clearly better. Returns how many were moved."""
    moved = 0
    for first in [e for e in s.effects if isinstance(e, Misalignment)]:
        if not any(first is e for e in s.effects):  # replaced by an earlier move
            continue
        taken = {e.target for e in s.effects if isinstance(e, Misalignment)}
        # the first's turn, fitted on its neighbour's residual, does not take it all: where the neighbour's
        # sensor is the turned one, its residual stays above what a turn that matters leaves
        residual = {row["link"]: row.get("rms_deg", 0.0) for row in link_summary(*s.current)}
        others = [n for n in s.neighbours(first.target)
                  if n in links and n not in taken and residual.get(n, 0.0) >= MISALIGNMENT_FLOOR]
        if others and _move(s, first, others, links, gain, threshold, progress, max_samples, say):
            moved += 1
    return moved


def _move(s: Subject, first: Misalignment, others: list[str], links, gain: float, threshold: float, progress: bool,
          max_samples: int, say: Callable[[str], None]) -> bool:
    """moved_to_neighbours' try of `first` on each of `others` (the variants tracked as one batch);
    adopts the best into s where it is clearly better. Returns whether one was adopted."""
    without = rebuilt(s, (first,))
    analyse_subjects([without], links, gain, progress, max_samples)
    tried = []
    for other in others:
        effect, why = fitted(without, first.kind, other, threshold, links)
        if effect is None:
            say(f"{first.kind} at {first.target} stays: at {other} it does not fit ({why})")
        else:
            tried.append((rebuilt(s, (first,)), other, effect))
    if not tried:
        return False
    add_tracked_all([(v, effect) for v, _, effect in tried], errors(*without.current), links, gain, progress,
                    max_samples)
    before = errors(*s.current).overall[first.error]
    scored = sorted(((errors(*v.current).overall[first.error], v, other, effect) for v, other, effect in tried),
                    key=lambda t: t[0])
    for after, _, other, _ in scored:
        say(f"{first.kind} at {first.target} tried at {other}: the {first.error} {before:.4g} -> {after:.4g}")
    after, v, other, effect = scored[0]
    if after >= before * (1 - CLEARLY_BETTER):
        return False
    # both sensors may be turned: the first's own turn, fitted again beside the neighbour's
    again, _ = fitted(v, first.kind, first.target, threshold, links)
    if again is not None:
        add_tracked(v, again, links, gain, progress, max_samples)
        after = errors(*v.current).overall[first.error]
    first.notes = "; ".join(filter(None, [first.notes, f"replaced by a {first.kind} at {other}: with it, the "
                                                       f"{first.error} went from {before:.4g} to {after:.4g}"]))
    s.rejected.append(first)
    effect.notes = "; ".join(filter(None, [effect.notes, f"in place of a {first.kind} at {first.target}, which "
                                                         f"took a share of its residual across their joint"]))
    take(s, v)
    say(f"{first.kind} at {first.target} moved to {other} ({first.error} {before:.4g} -> {after:.4g})")
    return True


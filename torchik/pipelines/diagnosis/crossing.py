"""A sensor's turn taken by the wrong side of a joint, and the axis it then asks for.

Where the joints cannot turn two neighbouring segments against each other about some axis (a knee's
ab/adduction, an elbow's), a turn of one segment's sensor about it and a turn of the other's leave
nearly the same residual at the joint's mean angle (Diagnosis.confounded). The loop fits the better
scoring first; where that is the wrong side (a thigh whose own offset adds to its score), the turn it
takes is right at the joint's mean angle and wrong by the joint's swing away from it, and a later
round finds an axis moving with the joint: a knee's missing ab/adduction, a few degrees back and forth
with flexion, or an elbow's with its bend. A sensor's frame turned on its segment is the likelier
cause (a strap, a marker cluster), and the data can tell the two once the turn is on the right side.

The wrong side can also be across the first segment's other joint. A hand's sensor turned about the
hand's long axis, which the wrist cannot follow, leaves a residual between hand and forearm that a
turn of the forearm's sensor the other way explains as well at the elbow's mean pronation; the turn
taken by the forearm is then wrong by the forearm's pronation away from it, and the elbow asks for an
axis. So the first segment's other tracked neighbours (those without a misalignment of their own
kept) are tried after the joint's other side.

So once such an axis is kept beside a misalignment of one of its two segments, each of these
segments is tried in turn: the recording without both, a misalignment of that segment fitted first,
then the first segment's again (its own offset, if any), and the axis fitted once more. Where the
axis is then no longer significant, or no longer plausible, the misalignments replace it and the
first one; where it still is after every try, it was a joint's motion and stays.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import torch

from ...method.kinematics import KinematicModel
from . import elimination
from .analysis import noise_floor
from .effect import Effect
from .joints import MissingDof
from .placement import Misalignment
from .result import Errors, Step, errors
from .subject import Subject, analyse_subjects


def rebuilt(s: Subject, leave_out: Sequence[Effect]) -> Subject:
    """Subject s from its source with every kept effect but `leave_out` (their steps kept, in order)."""
    assert s.source is not None, "set by the loop"
    recording, urdf = s.source
    steps = [st for st in s.steps if not any(st.effect is e for e in leave_out)]
    for st in steps:
        if st.effect.model_effect:
            urdf = st.effect.augment(urdf)
        else:
            recording = st.effect.correct(recording)
    model = KinematicModel.from_urdf(urdf, name=s.model.name, dtype=s.model.dtype)
    v = Subject(recording, urdf, model, steps=steps, source=s.source, chunking=s.chunking)
    v.derived = s.derived
    return v


def fitted(v: Subject, kind: str, target: str, threshold: float, links, calibrated: bool = True
           ) -> tuple[Effect | None, str]:
    """The candidate of `kind` on `target` fitted on v's current analysis and refitted on all of it,
    when it is significant, at or above its floor and plausible; else None and why not. calibrated:
    significant as Effect.significant says (False: its held-out score above `threshold` suffices, not
    corrected for how its gains scatter across stretches of time)."""
    noise = noise_floor(*v.current)
    found = [c for c in v.candidates((kind,), target=target) if c.fit is not None]
    if not found:
        return None, "it cannot be fitted"
    c = found[0]
    dt = float(torch.diff(v.current[0].time).median())
    significant = (c.significant(threshold, noise.axis_rms) if calibrated
                   else f"score {c.score:.1f}, not above {threshold:g}" if c.score <= threshold else "")
    why = (significant
           or elimination.hanger_on(c, v.effects, v.model, v.urdf, links, noise.axis_rms) or c.below_floor(dt))
    if why:
        return None, why
    final, why = v.adopted(c)
    return (None, f"implausible: {why}") if why else (final, "")


def moving_over(axis: MissingDof) -> str:
    """'a missing axis at J (moving over a, b deg)': what a note says of the axis an effect replaced."""
    low, high = (math.degrees(x) for x in axis.params["angle_range"])
    return f"a missing axis at {axis.target} (moving over {low:.1f}, {high:.1f} deg)"


def take(s: Subject, v: Subject) -> None:
    """s becomes its variant v (recording, URDF, model, analysis and steps)."""
    s.recording, s.urdf, s.model, s.analysis, s.steps = v.recording, v.urdf, v.model, v.analysis, v.steps


def add_tracked(v: Subject, effect: Effect, links, gain: float, progress: bool, max_samples: int) -> None:
    """`effect` added to v, v tracked again and the step recorded."""
    add_tracked_all([(v, effect)], errors(*v.current), links, gain, progress, max_samples)


def add_tracked_all(added: Sequence[tuple[Subject, Effect]], before: Errors, links, gain: float, progress: bool,
                    max_samples: int) -> None:
    """Each effect added to its subject, whose errors were `before` (the subjects rebuilt alike, not
    yet tracked), the subjects tracked as one batch, each step recorded."""
    for v, effect in added:
        v.add(effect)
    analyse_subjects([v for v, _ in added], links, gain, progress, max_samples)
    for v, effect in added:
        v.steps.append(Step(effect, before, errors(*v.current)))


def other_side(s: Subject, axis: MissingDof, links, gain: float, threshold: float, progress: bool, max_samples: int,
               say: Callable[[str], None]) -> bool:
    """Try the kept `axis`'s neighbouring misalignment on the joint's other segment, then on the first
    segment's other neighbours (module docstring); adopt the first that leaves the axis standing no
    longer. Returns whether one was adopted."""
    sides = (axis.params["parent"], axis.params["child"])
    turned = [e for e in s.effects if isinstance(e, Misalignment) and e.target in sides]
    if len(turned) != 1 or not all(side in links for side in sides):
        return False
    first = turned[0]
    kept = {e.target for e in s.effects if isinstance(e, Misalignment)}
    others = [sides[1] if first.target == sides[0] else sides[0]]
    others += [n for n in s.neighbours(first.target) if n not in sides and n in links and n not in kept]
    return any(_moved(s, first, axis, other, links, gain, threshold, progress, max_samples, say) for other in others)


def _moved(s: Subject, first: Misalignment, axis: MissingDof, other: str, links, gain: float, threshold: float,
           progress: bool, max_samples: int, say: Callable[[str], None]) -> bool:
    """other_side's try of `other`'s sensor turned in place of `first`'s: adopted into s where the axis no
    longer stands. Returns whether it was."""
    v = rebuilt(s, (first, axis))
    analyse_subjects([v], links, gain, progress, max_samples)
    moved, why = fitted(v, "misalignment", other, threshold, links)
    if moved is None:
        say(f"the axis at {axis.target} stays: a misalignment of {other} in place of {first.target}'s does not fit ({why})")
        return False
    add_tracked(v, moved, links, gain, progress, max_samples)
    again, _ = fitted(v, "misalignment", first.target, threshold, links)
    if again is not None:
        add_tracked(v, again, links, gain, progress, max_samples)
    still, why_not = fitted(v, "missing_dof", axis.target, threshold, links)
    if still is not None:
        say(f"the axis at {axis.target} stays: with {other}'s sensor turned instead of {first.target}'s, it is "
            f"still significant")
        return False
    replaced = [e for e in (moved, again) if e is not None]
    what = " and ".join(f"{e.kind} at {e.target}" for e in replaced)
    for e in (first, axis):
        e.notes = "; ".join(filter(None, [e.notes, f"replaced by {what}: with {other}'s sensor turned, the axis at "
                                                   f"{axis.target} is no longer needed ({why_not})"]))
        s.rejected.append(e)
    moved.notes = "; ".join(filter(None, [moved.notes, (
        f"in place of a misalignment of {first.target} and {moving_over(axis)}: the joints cannot turn the two "
        f"segments against each other about that axis, and a turn on the wrong side of them asks for one moving "
        f"with the joint")]))
    take(s, v)
    say(f"{first.kind} at {first.target} and the axis at {axis.target} replaced by {what}")
    return True

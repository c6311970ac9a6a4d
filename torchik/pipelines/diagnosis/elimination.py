"""Backward elimination: whether each kept effect still pays for its parameters with the others in place.

An effect chosen early can be the echo of a cause found later (a drift on a foot taken first as a
toe's, a wrist's misalignment first put on the forearm): once the cause is in, the echo explains
nothing more. When a round adds an effect, for every effect kept before it and related to it (on
the same links or across one joint: `related`) the subject is rebuilt from its original recording
and URDF with all the kept effects but that one (`variants`). They are
tracked in the same batch as the subject itself (`track`: one batch per model; the variants of
MODEL_FREE effects need no tracking), so they carry the new effect at its first fit, before the
loop refines it. Once the new effect is kept, each effect's kind and target are fitted again on a
variant's train half and scored on its test half (`rescore`) with the test of the loop's choice
(Effect.significant). Of those that fail, the weakest is dropped (`eliminate`): the subject is
rebuilt and re-tracked without it, the effect is listed as rejected, as an echo of the effect added
last, and the others are re-scored again; unless, re-tracked without it, the subject's error rose
(the loop's test: an echo explains nothing the others do not), when it is put back and stays.
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import torch

from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from . import frames, joints
from .analysis import Analysis, analyse, noise_floor
from .candidates import candidates
from .effect import Effect, halves
from .placement import Misalignment
from .subject import Subject, analyse_subjects, trajectory_of

# effects fitted on a sensor's streams against each other (gyro.py, position.py), which no model or
# tracking changes: their variants are analysed on the subject's trajectory as it is, not re-tracked
MODEL_FREE = ("gyro_bias", "gyro_scale", "stream_delay", "position_offset")

def depends(later: Effect, earlier: Effect) -> bool:
    """Whether `later` was fitted on a URDF that only `earlier` gives: a model effect on the joint
    that a missing axis `earlier` added (removing `earlier` would leave it nowhere to go)."""
    if not (later.model_effect and isinstance(earlier, joints.MissingDof)):
        return False
    added = earlier.joint_name()
    return later.target == added or later.params.get("first_joint") == added


def removable(kept: Sequence[Effect], last: bool = False) -> list[Effect]:
    """The kept effects (in the order added) that can be taken out alone: all but the last added (it
    was just chosen with the others in place; with `last`, it too), those a later model effect depends
    on, and flipped frames and swapped segments (frames.py: scored by re-tracking, with no fit for
    `rescore`)."""
    return [e for k, e in enumerate(kept if last else kept[:-1]) if e.kind not in frames.KINDS
            and not any(depends(later, e) for later in kept[k + 1:])]


def reach(effect: Effect, model: KinematicModel, links: Sequence[str]) -> set[str]:
    """The tracked links whose residual `effect` moves: its sensor's (every sensor of a device's), or,
    for a model effect, those below the joint it adds or changes (in `model`, which has it)."""
    if not effect.model_effect:
        return set(effect.params.get("links", [effect.target]))
    joint = effect.joint_name() if isinstance(effect, joints.MissingDof) else effect.target
    below = model.select(links).ancestor_mask[:, model.joint_names.index(joint)]
    return {name for name, moved in zip(links, below.tolist()) if moved}


def neighbourhood(effect: Effect, model: KinematicModel, urdf: str, links: Sequence[str]) -> set[str]:
    """The links `effect` reaches (reach) and those one joint away from them: the tracker shares a
    target's inconsistency between the links the joints between them connect."""
    reached = reach(effect, model, links)
    near = set(reached)
    for group in joints.joint_groups(urdf, links):
        if group.child in reached or group.parent in reached:  # one joint away from what it reaches, no further
            near |= {group.child, group.parent}
    return near


def related(a: Effect, b: Effect, model: KinematicModel, urdf: str, links: Sequence[str]) -> bool:
    """Whether a and b can explain the same residual: they move a link in common, or links on either
    side of one joint (neighbourhood). Effects on links further apart are not each other's echoes,
    and their variants need not be tracked."""
    return bool(reach(a, model, links) & neighbourhood(b, model, urdf, links))


WITHIN_NOISE = 2.0  # a misalignment beside a kept effect must exceed this many times the noise's rms (hanger_on)


def hanger_on(candidate: Effect, kept: Sequence[Effect], model: KinematicModel, urdf: str, links: Sequence[str],
              noise_rms: float) -> str:
    """Why `candidate` is what a kept effect leaves beside it ("" when it is not): a misalignment
    within WITHIN_NOISE times the noise's rms (rad; one sample's 95 % range) on a link related to a
    kept effect. That effect fitted a few per cent off (a drift, a delay) leaves the links next to
    it turned by a fraction of a degree, steady enough to score; alone, so small an offset may be a
    strap's, and is kept."""
    if not isinstance(candidate, Misalignment):
        return ""
    angle = float(torch.tensor(candidate.params["rotation_vector"]).norm())
    if angle > WITHIN_NOISE * noise_rms:
        return ""
    near = [e for e in kept if related(candidate, e, model, urdf, links)]
    return (f"its angle, {math.degrees(angle):.2f} deg, is within {WITHIN_NOISE:g} times the noise's "
            f"{math.degrees(noise_rms):.2f} deg rms, beside the kept {near[0].kind} at {near[0].target}: what "
            f"that leaves" if near else "")


def without(recording: Recording, urdf: str, kept: Sequence[Effect], drop: Effect | None) -> tuple[Recording, str]:
    """The original recording and URDF with every kept effect but `drop` (None: all) added again, in their order."""
    for effect in kept:
        if effect is drop:
            continue
        if effect.model_effect:
            urdf = effect.augment(urdf)
        else:
            recording = effect.correct(recording)
    return recording, urdf


def rescore(analysis: Analysis, b: int, effect: Effect, urdf: str, derived: torch.Tensor | None,
            threshold: float) -> tuple[str, Effect | None]:
    """Why `effect` no longer pays for its parameters on subject b of an analysis without it ("" when
    it still does: significant, and at or above its family's floor), and its fit there (its kind and
    target on the train half, scored on the test half; None when the data no longer give one)."""
    train, test = halves(analysis.time)
    every = candidates(analysis, b, train, test, urdf, (effect.kind,), derived, effect.target)
    found = [c for c in every if c.fit is not None]
    if not found:
        notes = "; ".join(c.notes for c in every if c.notes) or "no fit"
        return f"with the others in place it cannot be fitted ({notes})", None
    why = found[0].significant(threshold, noise_floor(analysis, b).axis_rms)
    if not why:  # significant, but what the others leave it may be too small to matter (Effect.below_floor)
        small = found[0].below_floor(float(torch.diff(analysis.time).median()))
        why = f"is negligible: {small}" if small else ""
    return (f"with the others in place {why}" if why else ""), found[0]


Variant = tuple[Subject, Effect, Subject]  # (the subject, the kept effect left out, the subject without it)


def variants(s: Subject, kept: Sequence[Effect], every: bool = False) -> list[Variant]:
    """Subject s rebuilt from its source without each of the `kept` effects that can be taken out
    alone (removable) and is related to the last one (with `every`: each one, the last included: the
    loop's last check); those of measurement effects share s's model, so that they track as one batch."""
    assert s.source is not None, "set by the loop"
    links = s.current[0].links
    out = []
    for effect in removable(kept, every):
        if not every and not related(effect, kept[-1], s.model, s.urdf, links):
            continue
        recording, urdf = without(*s.source, kept, effect)
        model = KinematicModel.from_urdf(urdf, name=s.model.name, dtype=s.model.dtype) if effect.model_effect \
            else s.model
        out.append((s, effect, Subject(recording, urdf, model, chunking=s.chunking)))
    return out


def track(subjects: Sequence[Subject], found: Sequence[Variant], links, gain: float, progress: bool,
          max_samples: int) -> None:
    """Track and analyse `subjects` and the variants `found` as batches, one per model; the variants of
    MODEL_FREE effects analysed on their subject's trajectory instead (after it is tracked)."""
    analyse_subjects(list(subjects) + [v for _, effect, v in found if effect.kind not in MODEL_FREE], links, gain,
                     progress, max_samples)
    for s, effect, v in found:
        if effect.kind in MODEL_FREE:
            v.analysis = (analyse(v.model, [v.recording], links, trajectory_of(*s.current), gain, max_samples), 0)


def eliminate(found: list[Variant], links, gain: float, threshold: float, progress: bool, max_samples: int,
              say: Callable[[str], None], measure: Callable[[Subject, str], float] | None = None,
              worse: float = 0.0) -> None:
    """Backward elimination on the variants `found` (tracked): for each subject, of the kept effects
    that no longer pay without it and with the others in place, the weakest is dropped; that subject is
    rebuilt without it and tracked, and its kept effects re-scored again, until none is dropped.

    measure(s, key): subject s's current error `key` (Effect.error). When given, a drop that raises
    the dropped effect's error by more than the share `worse` is undone: an echo explains nothing the
    others do not, so taking it out cannot cost; one whose removal costs was re-scored low only
    because its cause and an effect fitted to part of it share the residual. It stays, and is not
    re-scored again."""
    stays: set[int] = set()
    while found:
        failing: dict[int, list[tuple[float, Subject, Effect, str]]] = {}
        for s, effect, v in found:
            if id(effect) in stays:
                continue
            why, fit = rescore(*v.current, effect, v.urdf, s.derived, threshold)
            if why:
                failing.setdefault(id(s), []).append((-math.inf if fit is None else fit.score, s, effect, why))
        dropped = []
        for weakest in failing.values():
            _, s, effect, why = min(weakest, key=lambda x: x[0])
            assert s.source is not None, "set by the loop"
            echo_of = s.effects[-1]
            before = None if measure is None else measure(s, effect.error)
            saved = (s.recording, s.urdf, s.model, s.analysis, list(s.steps), effect.notes)
            original, urdf = s.source
            s.recording, s.urdf = without(original, urdf, s.effects, effect)
            if effect.model_effect:
                s.model = KinematicModel.from_urdf(s.urdf, name=s.model.name, dtype=s.model.dtype)
            s.steps = [st for st in s.steps if st.effect is not effect]
            effect.notes = "; ".join(filter(None, [effect.notes, f"dropped as an echo of {echo_of.kind} at "
                                                                 f"{echo_of.target}: {why}"]))
            s.rejected.append(effect)
            say(f"{effect.kind} at {effect.target} dropped as an echo of {echo_of.kind} at {echo_of.target} ({why})")
            dropped.append((s, effect, before, saved))
        found = [v for s, *_ in dropped for v in variants(s, s.effects)]
        track([s for s, *_ in dropped], found, links, gain, progress, max_samples)
        for s, effect, before, saved in dropped:
            after = None if measure is None else measure(s, effect.error)
            if before is None or after is None or after <= before * (1 + worse):
                continue
            s.recording, s.urdf, s.model, s.analysis, s.steps, effect.notes = saved
            s.rejected = [e for e in s.rejected if e is not effect]
            stays.add(id(effect))
            found = [v for v in found if v[0] is not s]  # built without it
            say(f"{effect.kind} at {effect.target} kept: without it the {effect.error} went from {before:.4g} to "
                f"{after:.4g}")

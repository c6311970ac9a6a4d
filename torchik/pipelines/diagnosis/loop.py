"""The loop: track, analyse, fit every candidate effect, add the significant ones that explain disjoint
residuals, repeat.

    for each round:
        analyse the residuals of the current recording and model
        fit every candidate on the train half of the time, score it on the test half (effect.py)
        keep those significant (Effect.significant: the held-out score above SIGNIFICANT, also once
        calibrated on how its gains scatter across stretches of the test time (Score.calibrated), or
        for an angle fitted sample by sample, a size above the noise that analysis.noise_floor
        estimates) and relevant (Effect.below_floor: the others are listed as negligible), in the
        order of their scores but for what the physics prefers (preference.py); the first plausible
        one (Effect.implausible), and with it every other such candidate whose links are not related
        to those of one chosen or waiting before it (not the same links nor one joint away: disjoint
        residuals, none the echo of another): refit
        each on all the data, add them (correct the recording, or augment the URDF), re-track, and
        refine their parameters `refine` times (the fits are linearised and the tracker absorbs
        part of an effect: Gauss-Newton steps), with the earlier effects of their kind on related
        links (refinement.py)
        keep each if the error it acts on (over the links the others do not move) did not rise and
        it is still plausible and relevant; else take it back;
        then re-score every effect kept before it with the others in place and drop those that no
        longer pay for their parameters, as echoes of it (elimination.py)
    until no candidate is significant, or `max_effects` rounds are done; Diagnosis.stop says which
    (STOPS), and Diagnosis.noise how much of what remains the noise accounts for. Then every kept
    effect is re-scored with all the others in place once more, those seen only in the orientations
    that change nothing a report shows by a degree become negligible (contribution.py), those that
    share a residual are fitted jointly (jointfit.py), and those the joint fit puts below their floor
    become negligible too.

Candidates the data cannot identify (the joints follow them, or there is no gyro) come back
without a fit and are listed, from the first round, in Diagnosis.unobservable; so are the turns of
each sensor the joints follow (Diagnosis.unseen) and those the data tell from a neighbour's only
poorly (Diagnosis.confounded).

Subjects (recordings of the same length) run as one batch: every round tracks all of them at
once, those whose model has changed in a batch of their own.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from . import (
    axis_drift,
    contribution,
    crossing,
    elimination,
    frames,
    jointfit,
    joints,
    limit_turn,
    neighbour,
    placement,
    preference,
    refinement,
    shared_drift,
)
from .analysis import DEFAULT_GAIN, joint_summary, link_summary, noise_floor
from .candidates import KINDS
from .effect import SIGNIFICANT, Effect
from .result import WORSE, Diagnosis, Errors, Step, errors
from .subject import Subject, analyse_subjects

FAMILIES = ("gyro", "placement", "joints", "position")
NOISE_SHARE = 0.8  # the noise accounts for this share of what remains: the residual is consistent with it
def _choose(s: Subject, kinds, threshold: float, first: bool, gain: float) -> list[Effect]:
    """The significant candidates of subject s that explain disjoint residuals, refitted on all the
    data, best first (empty when none is): the best plausible one, then, in the order of their
    scores, each plausible one whose links are not related (elimination.neighbourhood: not the same
    links nor one joint away) to those of a candidate chosen before it. Candidates that far apart
    are not each other's echoes (elimination.related), so each was scored as it would be once the
    others are in; those related to a chosen one wait for the next round, fitted with it in place.
    A deferred candidate (taken back from a round with others) comes alone, when it is the best."""
    taken = s.rejected + [st.effect for st in s.steps]
    found = [c for c in s.candidates(kinds) if not any(c.overlaps(e) for e in taken) and (c.kind, c.target) not in s.shrunk]
    drifting = {st.effect.target for st in s.steps if st.effect.kind == "heading_drift"}
    for c in found:  # what a drift kept on the link left (its rate fitted short) is that drift's, not a bias
        if c.kind == "gyro_bias" and c.target in drifting and "vertical_turn_score" in c.params:
            c.params["drift_kept"] = True
    found = sorted(found + frames.candidates(s, kinds, taken, gain), key=lambda c: -c.score)  # half turns, swaps
    if first:
        s.unobservable = [c for c in found if c.fit is None]
        s.unseen = {c.target: c.unseen().tolist() for c in found if isinstance(c, placement.Misalignment)}
        s.confounded = _confounded(s)
    found = [c for c in found if c.fit is not None]
    noise = noise_floor(*s.current)
    passing = []
    for c in found:
        why = c.significant(threshold, noise.axis_rms) or elimination.hanger_on(
            c, [st.effect for st in s.steps], s.model, s.urdf, s.current[0].links, noise.axis_rms)
        if not why:
            passing.append(c)
        elif c.score > threshold:
            c.notes = "; ".join(filter(None, [c.notes, f"not significant: {why}"]))
    passing = preference.relevant(s, passing)
    passing = preference.biased_first(s, preference.simplest_first(s, passing))
    passing = preference.offset_first(s, preference.gyro_first(s, passing, threshold))
    passing = preference.scaled_first(s, passing)
    chosen: list[tuple[Effect, Effect]] = []  # (the candidate, its refit)
    areas: list[tuple[set[str], set[str]]] = []
    waiting: list[tuple[set[str], set[str]]] = []  # the areas of candidates that wait for the next round
    for c in passing:
        alone = (c.kind, c.target) in s.deferred
        if alone and chosen:
            continue
        area = preference.area(s, c)
        # a candidate related to one chosen waits, and so does any weaker one related to it: else a weaker
        # neighbour would take the residual that the stronger, waiting one explains better
        if any(area[0] & near or reach & area[1] for reach, near in areas + waiting):
            waiting.append(area)
            continue
        final, why = s.adopted(c)
        if why:
            final.notes = "; ".join(filter(None, [final.notes, f"implausible: {why}"]))
            c.notes = final.notes  # the report's best candidate left is c: it says why it was not kept
            s.rejected.append(final)
            continue
        chosen.append((c, final))
        areas.append(area)
        if alone:
            break
    if not chosen:
        s.done, s.best_rejected = True, found[0] if found else None
        s.stop = ("unidentifiable" if not found else "negligible" if s.negligible and not passing
                  else "noise" if noise.share >= NOISE_SHARE else "unexplained")
        return []
    picked = {id(c) for c, _ in chosen}
    for (best, final), area in zip(chosen, areas):  # what else explains the same residual about as well
        rivals = [c for c in passing if id(c) not in picked and c.kind == best.kind
                  and c.score >= preference.TIE * best.score and preference.area(s, c)[0] & area[1]]
        if rivals:
            final.notes = "; ".join(filter(None, [final.notes, "explained nearly as well by " + ", ".join(
                f"{c.kind} at {c.target} (score {c.score:.0f} against {best.score:.0f})" for c in rivals)
                + ": the data hardly tell them apart"]))
    return [f for _, f in chosen]


def _error_apart(errors_: Errors, key: str, others: set[str]) -> float:
    """Errors.overall[key] over the links but `others` (those the round's other effects move):
    what an effect added with others is judged on. The base's velocity is one figure for all."""
    if key == "base_velocity_rmse":
        return errors_.base_velocity
    values = getattr(errors_, key)
    keep = np.array([name not in others for name in errors_.links])
    return float(np.nanmean(values[keep])) if keep.any() else errors_.overall[key]


Added = tuple[Subject, list[Effect], Errors, tuple]  # a subject, the effects of the round, its errors and state before


def _variants(s: Subject, chosen: list[Effect]) -> list[elimination.Variant]:
    """The variants of subject s for backward elimination after a round that added `chosen`: s without
    each effect related to one of them, with all the others in place (each kept effect once)."""
    out: dict[int, elimination.Variant] = {}
    for effect in chosen:
        others = [e for e in chosen if e is not effect]
        for v in elimination.variants(s, s.effects + others + [effect]):
            out.setdefault(id(v[1]), v)
    return list(out.values())


def _refined_to_nothing(effect: Effect, dt: float) -> str:
    """Why a measurement effect, refined, is no effect any more ("" when it still is): every parameter
    within its standard error of zero, or its size below its family's floor. Fitted first on a residual
    that another effect of the round or the tracker's share of it explained, the Gauss-Newton steps took
    it back to nothing; kept, it would be a finding of size zero. Model effects are not tested on their
    standard errors, which are of other values."""
    if effect.below_floor(dt):
        return f"refined, it is negligible: {effect.below_floor(dt)}"
    if effect.model_effect or not effect.stderr or not effect.within_error():
        return ""
    return "refined, every parameter is within its standard error of zero: nothing is left for it to explain"


def _check(added: list[Added], links, gain: float, progress: bool, max_samples: int, round_: int,
           say: Callable[[str], None], refined: set[int]) -> set[int]:
    """Keep each effect of the round whose error (Effect.error, over the links the round's other
    effects do not move: all of them when it came alone) did not rise by more than WORSE once
    re-tracked and refined, and that is still plausible; take back the others (the subject rebuilt
    from its source without them and tracked again). One taken back from a round with others is
    tried again in a round of its own (Subject.deferred: what rose may be the others' doing), then
    rejected if it fails again. A subject in `refined` (its earlier effects refined beside the round's)
    is rebuilt even when the round leaves nothing, so that its recording holds them as refined.
    Returns the ids of the subjects that kept all of theirs (their elimination variants hold what
    they have)."""
    complete, rebuilt = set(), []
    for s, chosen, before, saved in added:
        after = errors(*s.current)
        dt = float(torch.diff(s.current[0].time).median())
        areas = [elimination.neighbourhood(e, s.model, s.urdf, links) for e in chosen]
        kept = []
        for n, effect in enumerate(chosen):
            others = set().union(*(area for m, area in enumerate(areas) if m != n))
            old, new = (_error_apart(e, effect.error, others) for e in (before, after))
            rose = new > old * (1 + WORSE)
            why = (f"re-tracked with it, the {effect.error} went from {old:.4g} to {new:.4g}" if rose
                   else effect.implausible() or _refined_to_nothing(effect, dt))  # refined, it may be where it cannot
            if not why:
                kept.append(effect)
                s.steps.append(Step(effect, before, after))
                continue
            if rose and len(chosen) > 1 and (effect.kind, effect.target) not in s.deferred:
                s.deferred.add((effect.kind, effect.target))  # the others' effect on the error may be what rose
                say(f"round {round_ + 1}: {effect.kind} at {effect.target} taken back, to be tried alone ({why})")
                continue
            if not rose and effect.below_floor(dt):  # real, and too small to matter: listed as such
                effect.notes = "; ".join(filter(None, [effect.notes, f"significant but negligible: {why}"]))
                s.negligible[(effect.kind, effect.target)] = effect
                s.shrunk.add((effect.kind, effect.target))
                say(f"round {round_ + 1}: {effect.kind} at {effect.target} taken back as negligible ({why})")
                continue
            effect.notes = "; ".join(filter(None, [effect.notes, f"reverted: {why}"]))
            s.rejected.append(effect)
            say(f"round {round_ + 1}: {effect.kind} at {effect.target} reverted ({why})")
        if len(kept) == len(chosen):
            complete.add(id(s))
        elif not kept and id(s) not in refined:
            s.recording, s.urdf, s.model, s.analysis = saved
        else:
            assert s.source is not None, "set by the loop"
            s.recording, s.urdf = elimination.without(*s.source, s.effects, None)
            s.model = KinematicModel.from_urdf(s.urdf, name=s.model.name, dtype=s.model.dtype)
            rebuilt.append(s)
    analyse_subjects(rebuilt, links, gain, progress, max_samples)
    return complete


def _drop_negligible(subjects: list[Subject], links, gain: float, progress: bool, max_samples: int) -> None:
    """Move the kept measurement effects that the joint fit put below their floor to the negligible ones:
    fitted alone a neighbour's residual made them look larger (a clavicle's turn beside its trunk's), and
    fitted with every other effect they are too small to matter. The subjects that lose one are rebuilt
    from their source without it and tracked again."""
    moved = []
    for s in subjects:
        dt = float(torch.diff(s.current[0].time).median())
        small = [st for st in s.steps if not st.effect.model_effect and st.effect.below_floor(dt)]
        for st in small:
            e = st.effect
            e.notes = "; ".join(filter(None, [e.notes, f"significant but negligible: fitted with the others, "
                                                      f"{e.below_floor(dt)}"]))
            s.negligible[(e.kind, e.target)] = e
        if small:
            assert s.source is not None, "set by the loop"
            s.steps = [st for st in s.steps if st not in small]
            s.recording, s.urdf = elimination.without(*s.source, s.effects, None)
            moved.append(s)
    analyse_subjects(moved, links, gain, progress, max_samples)


def _confounded(s: Subject) -> dict[str, list[dict]]:
    """Per tracked link, the turns of its sensor the data tell from a neighbour's only poorly
    (placement.confounds), on the first analysis: what no diagnosis of these data can attribute."""
    analysis, b = s.current
    links = analysis.links
    out = {}
    for name in links:
        found = placement.confounds(analysis, b, links.index(name), [links.index(n) for n in s.neighbours(name)])
        if found:
            out[name] = [dict(c, neighbour=links[c["neighbour"]]) for c in found]
    return out


def _note_confounds(s: Subject) -> None:
    """Each kept misalignment's turns that the data tell from a neighbour's only poorly
    (placement.confounds): params['confounds'] and a note, so that the report says the data see the
    two sensors' difference there and not which one turned."""
    analysis, b = s.current
    links = analysis.links
    for e in s.effects:
        if not isinstance(e, placement.Misalignment):
            continue
        found = placement.confounds(analysis, b, links.index(e.target), [links.index(n) for n in s.neighbours(e.target)])
        if not found:
            continue
        e.params["confounds"] = [dict(c, neighbour=links[c["neighbour"]]) for c in found]
        told = "; ".join(f"a turn of it about ({', '.join(f'{x:+.2f}' for x in c['direction'])}) from one of the "
                         f"{links[c['neighbour']]} sensor about ({', '.join(f'{x:+.2f}' for x in c['neighbour_direction'])})"
                         for c in found)
        e.notes = "; ".join(filter(None, [e.notes, f"the data tell {told} only poorly (they see the two sensors' "
                                                   f"difference there, not which one turned)"]))


def diagnose(model: KinematicModel, urdf: str, recordings: Sequence[Recording], links, gain: float = DEFAULT_GAIN,
             max_effects: int = 6, threshold: float = SIGNIFICANT, refine: int = 1, kinds: Sequence[str] = KINDS,
             progress: bool = False, log: Callable[[str], None] | None = None,
             max_samples: int = 300, eliminate: bool = True, joint: bool = True) -> list[Diagnosis]:
    """Run the loop on B recordings (the same length, links the model's) with `model` built from
    `urdf`. Returns one Diagnosis per recording. kinds: the candidate effects considered;
    max_samples: the sample times at which effects are fitted against the task Jacobian; eliminate:
    after each round, drop kept effects that no longer pay with the others in place (elimination.py);
    joint: at the end, fit the kept measurement effects jointly and give their standard errors from
    the joint fit (jointfit.py).

    An effect added is kept only if, re-tracked, it does not raise the error it acts on (Effect.error:
    the orientations' MNTE, the angular-velocity RMSE or the base's velocity RMSE; by more than
    WORSE: a gyro effect on one link moves the overall RMSE by little); otherwise the
    subject goes back to where it was and the effect is listed in Diagnosis.rejected, as are
    significant candidates whose fitted values are implausible (Effect.implausible)."""
    links = tuple(links)
    subjects = [Subject(rec, urdf, model, source=(rec, urdf)) for rec in recordings]
    analyse_subjects(subjects, links, gain, progress, max_samples)
    for s in subjects:
        s.first = s.analysis
        s.derived = s.current[0].derived[s.current[1]]
    say = log or (lambda _: None)
    for round_ in range(max_effects):
        added: list[Added] = []
        for s in (s for s in subjects if not s.done):
            chosen = _choose(s, kinds, threshold, round_ == 0, gain)
            if not chosen:
                continue
            s.rounds += 1
            for effect in chosen:
                say(f"round {round_ + 1}: {effect.summary()} (score {effect.score:.0f})")
            added.append((s, chosen, errors(*s.current), s.saved()))
            for effect in chosen:
                s.add(effect)
        if not added:
            break
        # the variants for backward elimination track in the batch of their subject
        found = [v for s, chosen, *_ in added for v in _variants(s, chosen)] if eliminate else []
        elimination.track([s for s, *_ in added], found, links, gain, progress, max_samples)
        refined: set[int] = set()  # subjects whose earlier effects were refined beside this round's
        for _ in range(refine):
            refined |= refinement.refine([(s, chosen) for s, chosen, *_ in added], links, gain, progress, max_samples)
        complete = _check(added, links, gain, progress, max_samples, round_, say, refined)
        elimination.eliminate([v for v in found if id(v[0]) in complete], links, gain, threshold, progress,
                              max_samples, say, lambda s, key: errors(*s.current).overall[key], WORSE)
        for s, chosen, *_ in added:  # an axis kept beside a misalignment may be that turn on the wrong side
            for axis in [e for e in chosen if isinstance(e, joints.MissingDof) and any(e is k for k in s.effects)]:
                if not crossing.other_side(s, axis, links, gain, threshold, progress, max_samples, say):
                    axis_drift.axis_as_drift(s, axis, links, gain, threshold, progress, max_samples, say)
            for limit in [e for e in chosen if isinstance(e, joints.JointLimit) and any(e is k for k in s.effects)]:
                limit_turn.limit_as_turn(s, limit, links, gain, threshold, progress, max_samples, say)
    if eliminate:  # the last check: each kept effect with every other in place, the last added too
        found = [v for s in subjects if len(s.effects) > 1 for v in elimination.variants(s, s.effects, every=True)]
        elimination.track([], found, links, gain, progress, max_samples)
        elimination.eliminate(found, links, gain, threshold, progress, max_samples, say,
                              lambda s, key: errors(*s.current).overall[key], WORSE)
        for s in subjects:  # a turn or a drift kept on the neighbour of the sensor that has it
            neighbour.moved_to_neighbours(s, links, gain, threshold, progress, max_samples, say)
    if eliminate:  # a drift its gyro shares named as two effects, then what changes nothing a report shows
        shared_drift.merge(subjects, links, gain, progress, max_samples, WORSE, say)
        contribution.drop_invisible(subjects, links, gain, progress, max_samples, say)
    fits = jointfit.refit(subjects, links, gain, progress, max_samples) if joint else [None] * len(subjects)
    _drop_negligible(subjects, links, gain, progress, max_samples)
    for s in subjects:
        _note_confounds(s)
    out = []
    for s, original, fit in zip(subjects, recordings, fits):
        analysis, b = s.current
        remaining = sorted((row for row in link_summary(analysis, b) if "rms_deg" in row), key=lambda r: -r["rms_deg"])
        out.append(Diagnosis(s.steps, s.recording, original, s.urdf, s.model, links, s.initial, s.current,
                             s.best_rejected, remaining, joint_summary(analysis, b), s.unobservable, s.rejected,
                             s.done, s.stop, noise_floor(analysis, b), fit, s.rounds, list(s.negligible.values()),
                             s.unseen, s.confounded))
    return out

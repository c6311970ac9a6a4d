"""The loop: track, analyse, fit every candidate effect, add the significant ones that explain disjoint
residuals, repeat.

    for each round:
        analyse the residuals of the current recording and model
        fit every candidate on the train half of the time, score it on the test half (effect.py)
        keep those significant (Effect.significant: the held-out score above SIGNIFICANT, also once
        calibrated on how its gains scatter across stretches of the test time (Score.calibrated), or
        for an angle fitted sample by sample, a size above the noise that analysis.noise_floor
        estimates) and relevant (Effect.below_floor: the others are listed as negligible), in the
        order of their scores but for what the physics prefers (_simplest_first, _biased_first,
        _gyro_first, _offset_first); the first plausible one (Effect.implausible), and with it every
        other such candidate whose links are not related to those of one chosen or waiting before it
        (not the same links nor one joint away: disjoint residuals, none the echo of another): refit
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
    effect is re-scored with all the others in place once more, those that share a residual are fitted
    jointly (jointfit.py), and those the joint fit puts below their floor become negligible.

Candidates the data cannot identify (the joints follow them, or there is no gyro) come back
without a fit and are listed, from the first round, in Diagnosis.unobservable; so are the turns of
each sensor the joints follow (Diagnosis.unseen) and those the data tell from a neighbour's only
poorly (Diagnosis.confounded).

Subjects (recordings of the same length) run as one batch: every round tracks all of them at
once, those whose model has changed in a batch of their own.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch

from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from ...method.metrics import orientation_error
from . import elimination, frames, jointfit, joints, placement, posture, refinement
from .analysis import DEFAULT_GAIN, Analysis, NoiseFloor, joint_summary, link_summary, noise_floor
from .calibration import FORMAT
from .candidates import KINDS
from .effect import SIGNIFICANT, Effect
from .subject import Subject, analyse_subjects

FAMILIES = ("gyro", "placement", "joints", "position")
TIE = 0.9  # a second candidate scoring this share of the best explains the data nearly as well
WORSE = 1e-3  # an effect that raises its error by more than this share once re-tracked is taken back
NOISE_SHARE = 0.8  # the noise accounts for this share of what remains: the residual is consistent with it
STOPS = {"noise": "consistent with noise: no candidate is significant, and the noise accounts for what remains",
         "unexplained": "no candidate is both significant and plausible, but more remains than the noise accounts "
                        "for: a cause none of the candidates describes",
         "unidentifiable": "nothing identifiable: no candidate can be fitted on these data",
         "negligible": "what the data still show significantly is below the size that matters (listed as negligible)",
         "cap": "cap reached: candidates were still significant after the last round allowed (--max-effects)"}


@dataclass
class Errors:
    """Per link: mnte (mean of 1 - cos of the orientation error) and rmse (rad/s, angular velocity),
    over the time after the transient; overall: their means over the links; base_velocity: the
    rms of the base's measured linear velocity against the estimate (m/s, per axis)."""

    links: tuple[str, ...]
    mnte: np.ndarray
    rmse: np.ndarray
    base_velocity: float = float("nan")

    @property
    def overall(self) -> dict:
        return dict(mnte=float(np.nanmean(self.mnte)), rmse=float(np.nanmean(self.rmse)),
                    base_velocity_rmse=self.base_velocity)

    def to_json(self) -> dict:
        return dict(overall=self.overall, per_link={n: dict(mnte=float(m), rmse=float(r))
                                                    for n, m, r in zip(self.links, self.mnte, self.rmse)})


def errors(analysis: Analysis, b: int, transient: float = 1.0) -> Errors:
    """The tracking errors of subject b against its (current, corrected) measurements."""
    time = analysis.time
    keep = time >= time[0] + (transient if float(time[-1] - time[0]) > 3 * transient else 0.0)
    ok = analysis.valid[:, b] & keep[:, None]  # [T,L]
    err = orientation_error(torch.where(ok[..., None, None], analysis.R_m[:, b], analysis.R_hat[:, b]), analysis.R_hat[:, b])
    dw = torch.where(ok[..., None], analysis.w_m[:, b] - analysis.w_hat[:, b], 0.0).square().sum(-1) / 3.0
    n = ok.sum(0).clamp(min=1)
    v_hat = analysis.trajectory.velocity[:, b, :3]
    if analysis.trajectory.velocity.shape[0] > 1:  # the midpoint scheme's nu_k is the mean over the step before t_k
        v_hat = torch.cat((0.5 * (v_hat[:-1] + v_hat[1:]), v_hat[-1:]))
    dv = (analysis.v_m[:, b] - v_hat)[keep]
    dv = dv[torch.isfinite(dv).all(-1)]
    return Errors(analysis.links, (err.sum(0) / n).numpy(), (dw.sum(0) / n).sqrt().numpy(),
                  float(dv.square().mean().sqrt()) if len(dv) else float("nan"))


@dataclass
class Step:
    """One added effect with the errors before and after it."""

    effect: Effect
    before: Errors
    after: Errors


@dataclass
class Diagnosis:
    """What the loop found for one recording: the effects (in the order added) with the errors
    before and after each, the corrected recording and the (augmented) URDF, the first and last
    analyses (subject `index` of their batches), the best candidate left (not significant), where
    the residual sits at the end (link_summary rows, largest first), the joints at a limit, and
    the candidates the data cannot identify (no fit, notes saying why), and the significant ones
    not kept (implausible values, or added and taken back because re-tracking with them did not
    lower the error; notes saying which). complete: the loop ended because no candidate was
    significant any more (not at max_effects)."""

    steps: list[Step]
    recording: Recording
    original: Recording
    urdf: str
    model: KinematicModel
    links: tuple[str, ...]
    first: tuple[Analysis, int]
    last: tuple[Analysis, int]
    best_rejected: Effect | None
    remaining: list[dict] = field(default_factory=list)
    limits: list[dict] = field(default_factory=list)
    unobservable: list[Effect] = field(default_factory=list)
    rejected: list[Effect] = field(default_factory=list)
    complete: bool = True
    stop: str = ""  # why the loop stopped: a key of STOPS
    noise: NoiseFloor | None = None  # what a correct model would leave, estimated on the last analysis
    joint: jointfit.Joint | None = None  # the kept measurement effects fitted jointly at the end (jointfit.py)
    rounds: int = 0  # the rounds that added effects
    negligible: list[Effect] = field(default_factory=list)  # significant, but below their family's floor: not added
    unseen: dict = field(default_factory=dict)  # link: [m,3] directions (link frame) of a sensor turn the joints follow
    confounded: dict = field(default_factory=dict)  # link: its sensor's turns told from a neighbour's only poorly

    @property
    def why_stopped(self) -> str:
        share = "" if self.noise is None else f" (the noise accounts for {100 * self.noise.share:.0f} % of the residual)"
        return STOPS.get(self.stop, self.stop) + share

    @property
    def effects(self) -> list[Effect]:
        return [s.effect for s in self.steps]

    @functools.cached_property  # the report reads them dozens of times; each is a pass over [T,L] rotations
    def before(self) -> Errors:
        return errors(*self.first)

    @functools.cached_property
    def after(self) -> Errors:
        return errors(*self.last)

    def calibration(self) -> dict:
        """The measurement effects, as `apply_calibration` reads them (JSON-ready)."""
        return dict(format=FORMAT, links=list(self.links),
                    effects=[e.to_json() for e in self.effects if not e.model_effect],
                    fit=None if self.joint is None else self.joint.note)


def _area(s: Subject, effect: Effect) -> tuple[set[str], set[str]]:
    """The tracked links a candidate of subject s moves and its neighbourhood (elimination.reach and
    neighbourhood), a missing axis's in the model that has it."""
    links, urdf, model = s.current[0].links, s.urdf, s.model
    if isinstance(effect, joints.MissingDof):
        urdf = effect.augment(urdf)
        model = KinematicModel.from_urdf(urdf, name=model.name, dtype=model.dtype)
    return elimination.reach(effect, model, links), elimination.neighbourhood(effect, model, urdf, links)


def _relevant(s: Subject, passing: list[Effect]) -> list[Effect]:
    """The candidates of `passing` at or above their family's floor (Effect.below_floor); the others are
    recorded in s.negligible (the latest fit of each kind and target), noted "significant but negligible",
    and never added: they are real to the data and matter to no one, and adding them would cost a round
    of tracking and, fitted on what the larger effects leave, risk echoes."""
    dt = float(torch.diff(s.current[0].time).median())
    out = []
    for c in passing:
        why = c.below_floor(dt)
        if not why:
            out.append(c)
            continue
        c.notes = "; ".join(filter(None, [c.notes, f"significant but negligible: {why}"]))
        s.negligible[(c.kind, c.target)] = c
    for c in out:  # relevant now: what an earlier round found negligible of it is no longer the word
        s.negligible.pop((c.kind, c.target), None)
    return out


def _simplest_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` (best first) with the best replaced by the simplest of its rivals: candidates of its
    kind on related links (elimination.related: they explain the same residual) that score within TIE
    of it with fewer parameters identified, the fewest first. Where the joints share a rotation
    between several links (a spine whose joints have no axis along it), one sensor's offset shows on
    its neighbours too, and a neighbour's fit that adds directions the joints nearly follow picks up
    the rest of the residual with them: it scores about as well, with values no strap allows."""
    if not passing:
        return passing
    best = passing[0]
    near = _area(s, best)[1]
    rivals = [c for c in passing[1:] if c.kind == best.kind and c.n_params < best.n_params
              and c.score >= TIE * best.score and _area(s, c)[0] & near]
    if not rivals:
        return passing
    simplest = min(rivals, key=lambda c: (c.n_params, -c.score))
    simplest.notes = "; ".join(filter(None, [simplest.notes, f"preferred to {best.kind} at {best.target} (score "
                                             f"{best.score:.0f} with {best.n_params} parameters against "
                                             f"{simplest.score:.0f} with {simplest.n_params})"]))
    return [simplest] + [c for c in passing if c is not simplest]


TIED = 0.99  # two candidates scoring within 1 % of each other explain the data equally: the data cannot choose


def _biased_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` with each drift its gyro shares put after a tied rival (a drift on a related link scoring
    within TIED of it: a heading tied to a neighbour's by joints without a vertical axis turns one way
    or the neighbour's the other, and the orientations cannot tell which) on a link whose own gyro shows
    a bias among the candidates: a heading-free filter integrates its gyro's bias about the vertical
    into the drift and leaves the rest in the gyro's stream (placement.HeadingDrift), so the biased
    gyro is the drifting one."""
    biased = {c.target for c in passing if c.kind == "gyro_bias"}
    out = list(passing)
    for c in passing:
        if c.kind != "heading_drift" or c.target in biased:
            continue
        near = _area(s, c)[1]
        rival = next((r for r in out if r.kind == c.kind and r.target in biased and r.score >= TIED * c.score
                      and c.score >= TIED * r.score and _area(s, r)[0] & near), None)
        if rival is not None and out.index(rival) > out.index(c):
            out.remove(rival)
            out.insert(out.index(c), rival)
            rival.notes = "; ".join(filter(None, [rival.notes, f"preferred to {c.kind} at {c.target} (the same score): "
                                                               f"this sensor's gyro shows a bias"]))
    return out


def _gyro_first(s: Subject, passing: list[Effect], threshold: float) -> list[Effect]:
    """`passing` with each drift whose own gyro shows it (a heading turned under an unbiased gyro: its
    integral's word, own_gyro_score, significant by itself) put before the model effects (a missing axis,
    a moved limit) on the links around it: the orientations alone may fit an axis moving sample by sample
    better than one rate, but only the drift explains what the gyro says of its own orientations, which
    no joint of the model changes."""
    out = list(passing)
    for d in passing:
        if d.kind != "heading_drift" or d.params.get("gyro_shares") or d.params.get("own_gyro_score", 0.0) <= threshold:
            continue
        near = _area(s, d)[1]
        model = next((m for m in out[:out.index(d)] if m.model_effect and _area(s, m)[0] & near), None)
        if model is not None:
            out.remove(d)
            out.insert(out.index(model), d)
            d.notes = "; ".join(filter(None, [d.notes, f"preferred to {model.kind} at {model.target}: its own gyro "
                                                       f"shows the turn (score {d.params['own_gyro_score']:.0f})"]))
    return out


def _offset_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` with a misalignment of the links on either side of a missing axis put before the axis
    where the axis' angle is mostly an offset (its mean beyond its rms about it): a constant angle is a
    sensor's frame turned on its segment, which one to three parameters explain, and a joint's angle
    comes and goes; fitted first, an axis takes the offset with the motion, and the frame's turn is
    never named (a shank's frame turned about the knee's missing axis came back as that axis)."""
    out = list(passing)
    for m in passing:
        if not isinstance(m, joints.MissingDof) or abs(m.params.get("angle_mean", 0.0)) <= m.params.get("angle_rms", 0.0):
            continue
        frame = next((c for c in out[out.index(m):] if c.kind == "misalignment"
                      and c.target in (m.params["child"], m.params["parent"])), None)
        if frame is not None:
            out.remove(frame)
            out.insert(out.index(m), frame)
            why = (f"preferred to the missing axis at {m.target}, whose angle is mostly an offset "
                   f"({math.degrees(m.params['angle_mean']):.1f} deg, about which it moves by "
                   f"{math.degrees(m.angle_rms()):.1f})")
            frame.notes = "; ".join(filter(None, [frame.notes, why]))
    return out


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
    passing = _relevant(s, passing)
    passing = _offset_first(s, _gyro_first(s, _biased_first(s, _simplest_first(s, passing)), threshold))
    chosen: list[tuple[Effect, Effect]] = []  # (the candidate, its refit)
    areas: list[tuple[set[str], set[str]]] = []
    waiting: list[tuple[set[str], set[str]]] = []  # the areas of candidates that wait for the next round
    for c in passing:
        alone = (c.kind, c.target) in s.deferred
        if alone and chosen:
            continue
        area = _area(s, c)
        # a candidate related to one chosen waits, and so does any weaker one related to it: else a weaker
        # neighbour would take the residual that the stronger, waiting one explains better
        if any(area[0] & near or reach & area[1] for reach, near in areas + waiting):
            waiting.append(area)
            continue
        final = s.refit(c) or c
        final.fit = c.fit  # the score is the held-out one, and so are the judgements made beside it
        final.params.update({name: c.params[name] for name in c.judged if name in c.params})
        why = final.implausible() or posture.held_by_reference(final, s.model, s.current[0].poses[s.current[1]])
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
        rivals = [c for c in passing if id(c) not in picked and c.kind == best.kind and c.score >= TIE * best.score
                  and _area(s, c)[0] & area[1]]
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


def _neighbours(s: Subject, link: str) -> list[str]:
    """The tracked links one joint from `link` (its nearest tracked ancestor and the links whose it is)."""
    groups = joints.joint_groups(s.urdf, s.current[0].links)
    return sorted({g.parent for g in groups if g.child == link} | {g.child for g in groups if g.parent == link})


def _confounded(s: Subject) -> dict[str, list[dict]]:
    """Per tracked link, the turns of its sensor the data tell from a neighbour's only poorly
    (placement.confounds), on the first analysis: what no diagnosis of these data can attribute."""
    analysis, b = s.current
    links = analysis.links
    out = {}
    for name in links:
        found = placement.confounds(analysis, b, links.index(name), [links.index(n) for n in _neighbours(s, name)])
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
        found = placement.confounds(analysis, b, links.index(e.target), [links.index(n) for n in _neighbours(s, e.target)])
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
    if eliminate:  # the last check: each kept effect with every other in place, the last added too
        found = [v for s in subjects if len(s.effects) > 1 for v in elimination.variants(s, s.effects, every=True)]
        elimination.track([], found, links, gain, progress, max_samples)
        elimination.eliminate(found, links, gain, threshold, progress, max_samples, say,
                              lambda s, key: errors(*s.current).overall[key], WORSE)
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

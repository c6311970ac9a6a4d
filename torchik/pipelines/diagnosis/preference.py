"""Which of the significant candidates a round of the loop takes first, where the data score them alike
and the physics does not: the relevant ones only (above their family's floor), the simplest of tied
rivals, the drifting sensor whose gyro shows a bias, a drift its own gyro shows before a model effect,
a sensor's turned frame before a missing axis whose angle is mostly an offset, a gyro's scale error before
the bias it makes of a steady turn. Each takes the candidates best first and returns them reordered,
noting on the one it moves why.
"""

from __future__ import annotations

import math

import torch

from ...method.kinematics import KinematicModel
from . import elimination, joints
from .effect import Effect
from .subject import Subject

TIE = 0.9  # a second candidate scoring this share of the best explains the data nearly as well


def area(s: Subject, effect: Effect) -> tuple[set[str], set[str]]:
    """The tracked links a candidate of subject s moves and its neighbourhood (elimination.reach and
    neighbourhood), a missing axis's in the model that has it."""
    links, urdf, model = s.current[0].links, s.urdf, s.model
    if isinstance(effect, joints.MissingDof):
        urdf = effect.augment(urdf)
        model = KinematicModel.from_urdf(urdf, name=model.name, dtype=model.dtype)
    return elimination.reach(effect, model, links), elimination.neighbourhood(effect, model, urdf, links)


def relevant(s: Subject, passing: list[Effect]) -> list[Effect]:
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


def simplest_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` (best first) with the best replaced by the simplest of its rivals: candidates of its
    kind on related links (elimination.related: they explain the same residual) that score within TIE
    of it with fewer parameters identified, the fewest first. Where the joints share a rotation
    between several links (a spine whose joints have no axis along it), one sensor's offset shows on
    its neighbours too, and a neighbour's fit that adds directions the joints nearly follow picks up
    the rest of the residual with them: it scores about as well, with values no strap allows."""
    if not passing:
        return passing
    best = passing[0]
    near = area(s, best)[1]
    rivals = [c for c in passing[1:] if c.kind == best.kind and c.n_params < best.n_params
              and c.score >= TIE * best.score and area(s, c)[0] & near]
    if not rivals:
        return passing
    simplest = min(rivals, key=lambda c: (c.n_params, -c.score))
    simplest.notes = "; ".join(filter(None, [simplest.notes, f"preferred to {best.kind} at {best.target} (score "
                                             f"{best.score:.0f} with {best.n_params} parameters against "
                                             f"{simplest.score:.0f} with {simplest.n_params})"]))
    return [simplest] + [c for c in passing if c is not simplest]


TIED = 0.99  # two candidates scoring within 1 % of each other explain the data equally: the data cannot choose


def biased_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` with each drift its gyro shares put after a tied rival (a drift on a related link scoring
    within TIED of it: a heading tied to a neighbour's by joints without a vertical axis turns one way
    or the neighbour's the other, and the orientations cannot tell which) on a link whose own gyro shows
    a bias among the candidates: a heading-free filter integrates its gyro's bias about the vertical
    into the drift and leaves the rest in the gyro's stream (drift.HeadingDrift), so the biased
    gyro is the drifting one."""
    biased = {c.target for c in passing if c.kind == "gyro_bias"}
    out = list(passing)
    for c in passing:
        if c.kind != "heading_drift" or c.target in biased:
            continue
        near = area(s, c)[1]
        rival = next((r for r in out if r.kind == c.kind and r.target in biased and r.score >= TIED * c.score
                      and c.score >= TIED * r.score and area(s, r)[0] & near), None)
        if rival is not None and out.index(rival) > out.index(c):
            out.remove(rival)
            out.insert(out.index(c), rival)
            rival.notes = "; ".join(filter(None, [rival.notes, f"preferred to {c.kind} at {c.target} (the same score): "
                                                               f"this sensor's gyro shows a bias"]))
    return out


def gyro_first(s: Subject, passing: list[Effect], threshold: float) -> list[Effect]:
    """`passing` with each drift whose own gyro shows it (a heading turned under an unbiased gyro: its
    integral's word, own_gyro_score, significant by itself) put before the model effects (a missing axis,
    a moved limit) on the links around it: the orientations alone may fit an axis moving sample by sample
    better than one rate, but only the drift explains what the gyro says of its own orientations, which
    no joint of the model changes.
    So does a drift of a sensor whose gyro bias is kept: a filter that corrects tilt and not heading
    integrates the bias' vertical part into the heading, and the bias, fitted first on the gyro
    against the orientations, takes the gyro's word of that turn with it (a constant in the sensor
    frame of a segment that keeps its attitude). The drift is then what the bias implies, where an
    axis or a limit would be a second cause (an upper arm's drift, which the shoulder follows, shows
    through the elbow only, as an axis moving with the arm's swing)."""
    biased = {e.target for e in s.effects if e.kind == "gyro_bias"}
    out = list(passing)
    for d in passing:
        shown = d.params.get("own_gyro_score", 0.0) > threshold
        if d.kind != "heading_drift" or d.params.get("gyro_shares") or not (shown or d.target in biased):
            continue
        near = area(s, d)[1]
        model = next((m for m in out[:out.index(d)] if m.model_effect and area(s, m)[0] & near), None)
        if model is not None:
            out.remove(d)
            out.insert(out.index(model), d)
            why = (f"its own gyro shows the turn (score {d.params['own_gyro_score']:.0f})" if shown else
                   "its gyro's bias is kept, whose vertical part a filter without heading reference integrates")
            d.notes = "; ".join(filter(None, [d.notes, f"preferred to {model.kind} at {model.target}: {why}"]))
    return out


def offset_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` with a misalignment of the links on either side of a missing axis put before the axis
    where the axis' angle is mostly an offset (its mean beyond its rms about it): a constant angle is a
    sensor's frame turned on its segment, which one to three parameters explain, and a joint's angle
    comes and goes; fitted first, an axis takes the offset with the motion, and the frame's turn is
    never named (a shank's frame turned about the knee's missing axis came back as that axis).
    Not where a heading drift of that sensor scores above its misalignment: a drift's mean is an offset
    too, and the drift, taken first, leaves the misalignment what is left (moved ahead alone, the
    misalignment takes the drift's mean and the drift comes back split over the neighbours)."""
    out = list(passing)
    for m in passing:
        if not isinstance(m, joints.MissingDof) or abs(m.params.get("angle_mean", 0.0)) <= m.params.get("angle_rms", 0.0):
            continue
        sides = (m.params["child"], m.params["parent"])
        sensors = [c for c in out[out.index(m):] if not c.model_effect and c.target in sides]
        frame = next((c for c in sensors if c.kind == "misalignment"), None)
        if frame is None or any(c.kind == "heading_drift" and c.target == frame.target
                                for c in sensors[:sensors.index(frame)]):
            continue
        why = (f"preferred to the missing axis at {m.target}, whose angle is mostly an offset "
               f"({math.degrees(m.params['angle_mean']):.1f} deg, about which it moves by "
               f"{math.degrees(m.angle_rms()):.1f})")
        out.remove(frame)
        out.insert(out.index(m), frame)
        frame.notes = "; ".join(filter(None, [frame.notes, why]))
    return out


AGREE = 0.3  # a bias within this share of its size of what a scale error makes of the sensor's mean rate


def scaled_first(s: Subject, passing: list[Effect]) -> list[Effect]:
    """`passing` with a gyro's scale error put before a bias of that gyro which the scale error makes:
    a scale error kappa reads kappa w_bar more than the mean rate w_bar of a segment that turns steadily
    (a turning walk), a constant in the sensor frame as a bias is. Fitted on its integral, the bias
    shows that constant alone and scores well above the scale error seen in the swings; taken first,
    it is kept beside the scale error, which then explains the swings. Moved where the bias is, within
    AGREE of its size, some kappa_b times the mean rate (sensor frame), with kappa_b within a factor of
    two of the scale candidate's own kappa: two readings of one scale error, one parameter for four."""
    out = list(passing)
    analysis, b = s.current
    for c in passing:
        if c.kind != "gyro_bias":
            continue
        scale = next((k for k in out[out.index(c):] if k.kind == "gyro_scale" and k.target == c.target), None)
        if scale is None:
            continue
        i = analysis.links.index(c.target)
        ok = analysis.valid[:, b, i]
        mean_rate = (analysis.R_m[ok, b, i].transpose(-1, -2) @ analysis.w_m[ok, b, i, :, None])[..., 0].mean(0)
        bias = torch.as_tensor(c.params["bias"], dtype=mean_rate.dtype)
        power = float(mean_rate.square().sum())
        if power == 0.0:
            continue
        kappa_b = float(bias @ mean_rate) / power
        kappa = scale.params["scale_error"]
        if kappa == 0.0 or float((bias - kappa_b * mean_rate).norm()) > AGREE * float(bias.norm()) \
                or not 0.5 <= kappa_b / kappa <= 2.0:
            continue
        out.remove(scale)
        out.insert(out.index(c), scale)
        scale.notes = "; ".join(filter(None, [scale.notes, (
            f"preferred to the gyro bias of this sensor (score {c.score:.0f}): that bias is what a scale error of "
            f"{100 * kappa_b:+.1f} % makes of the sensor's mean rate ({math.degrees(float(mean_rate.norm())):.1f} deg/s)")]))
    return out

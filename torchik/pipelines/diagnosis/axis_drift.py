"""A missing axis that is a biased sensor's heading drift.

A filter without a heading reference (a 6-axis fusion, or a 9-axis one indoors where the field is
not trusted) integrates its gyro's bias about the vertical into its heading (drift.py): the sensor's
heading turns at a constant rate against its neighbours'. Where the joint between them cannot turn
about the vertical (a wrist, an elbow whose forearm hangs), the tracker leaves the turn in the
residual, and a missing axis at that joint explains it as an angle that grows through the recording
(fitted sample by sample, it takes any shape). The loop keeps the axis when it scores above the drift:
the drift's rate is fitted once the gyro's bias is corrected, and the first rounds' residual mixes
both.

So once an axis is kept, the heading drift of each of the joint's two tracked segments without a kept
drift is tried in its place, a segment whose gyro bias is kept first (its filter's drift is then
expected): the recording without the axis, the drift fitted and added, re-tracked. Where the axis is
then no longer significant, the drift replaces it: the commonest fault of an inertial sensor against
a joint no body has. A joint's real motion (an axis moving back and forth with the gait) is no drift,
and stays.
"""

from __future__ import annotations

import copy
from typing import Callable

import torch

from .crossing import add_tracked, fitted, moving_over, rebuilt, take
from .drift import HeadingDrift
from .effect import Effect
from .gyro import GyroBias
from .joints import MissingDof
from .subject import Subject, analyse_subjects


def axis_as_drift(s: Subject, axis: MissingDof, links, gain: float, threshold: float, progress: bool,
                  max_samples: int, say: Callable[[str], None]) -> bool:
    """Try the kept `axis` as the heading drift of its child's, then its parent's, sensor, one whose gyro
    bias is kept first (module docstring); adopt the first that leaves the axis standing no longer.
    Returns whether one was adopted."""
    biased = {e.target for e in s.effects if isinstance(e, GyroBias)}
    drifting = {e.target for e in s.effects if e.kind == "heading_drift"}
    sides = sorted((axis.params["child"], axis.params["parent"]), key=lambda x: x not in biased)
    without = rebuilt(s, (axis,))
    analyse_subjects([without], links, gain, progress, max_samples)

    def unturned() -> Subject:  # s without the axis, tracked once: each try adds its drift to a copy
        v = rebuilt(s, (axis,))
        v.analysis = without.analysis
        return v

    for side in (x for x in sides if x not in drifting and x in links):
        v = unturned()
        # not calibrated on how its gains scatter: a drift carried into an arm's chain shows at the elbow
        # more in some postures than in others; whether the axis is still needed with it decides
        drift, why = fitted(v, "heading_drift", side, threshold, links, calibrated=False)
        if drift is None:
            say(f"a heading drift of {side} in place of the axis at {axis.target} does not fit ({why})")
        else:
            add_tracked(v, drift, links, gain, progress, max_samples)
            still, why_not = fitted(v, "missing_dof", axis.target, threshold, links)
            if still is None:
                _adopt(s, v, axis, drift, side, biased, why_not, say)
                return True
            say(f"the axis at {axis.target} stays: with {drift.summary()}, it is still significant "
                f"(score {still.score:.0f})")
        v = unturned()
        moved = _other_projection(v, side, None if drift is None else bool(drift.params.get("gyro_shares")), links,
                                  gain, progress, max_samples)
        if moved is None:
            continue
        still, why_not = fitted(v, "missing_dof", axis.target, threshold, links)
        if still is not None:
            say(f"the axis at {axis.target} stays: with {moved.summary()} (the rate the other kind's "
                f"projection fits), it is still significant (score {still.score:.0f})")
            continue
        _adopt(s, v, axis, moved, side, biased, why_not, say)
        return True
    return False


def _adopt(s: Subject, v: Subject, axis: MissingDof, drift: Effect, side: str, biased: set[str], why_not: str,
           say: Callable[[str], None]) -> None:
    """v, the subject without `axis` and with `side`'s `drift`, taken as s."""
    axis.notes = "; ".join(filter(None, [axis.notes, f"replaced by a heading drift of {side}: with it, the axis "
                                                     f"is no longer needed ({why_not})"]))
    s.rejected.append(axis)
    drift.notes = "; ".join(filter(None, [drift.notes, (
        f"in place of {moving_over(axis)}"
        + (": this sensor's gyro is biased, and a filter without a heading reference integrates the bias into "
           "its heading" if side in biased else ""))]))
    take(s, v)
    say(f"the axis at {axis.target} replaced by {drift.summary()}")


def _other_projection(v: Subject, side: str, shared: bool | None, links, gain: float, progress: bool,
                      max_samples: int) -> Effect | None:
    """`side`'s drift added to v (the subject without the axis, analysed) at the rate the other kind's
    fit gives it (`shared`: the kind fitted first; None where none could be, and the drift its gyro
    does not share is fitted), of the kind its own gyro says, and v tracked; None, and v as it was,
    where that kind cannot be fitted, its rate is under the drift's floor or beyond a sensor's. Given
    the kind the gyro says, the drift keeps that kind's tilt weighting (drift.tilt_weight), though its
    rate was fitted at a constant weight: on a hanging upper arm the weight stays within 0.87-1.

    The two kinds differ in whether the tracker's velocity target carries the drift (drift.fit_drifts),
    but at the tracker's gain a drift of a degree a second lags its orientation target by rate / K, a
    few hundredths of a degree: either way the tracker follows the orientations. Where an arm's chain
    spreads the turn over the shoulder and the elbow, the carried projection can fit the rate far off:
    tilt_filter_bias 4006, an upper arm's gyro biased by 2.6 deg/s through a 6-axis filter, its heading
    drifting at 0.86-0.90 deg/s (simulated): fitted 2.25 as carried, 0.83 on the orientations alone,
    with which the elbow's axis is no longer needed. The kind stays the gyro's word: its disagreement
    with its orientations about the vertical (own_gyro_score above 0: e = -rate z, the gyro does not
    share it)."""
    other = HeadingDrift("heading_drift", side, dict(gyro_shares=shared is not None and not shared))
    found = [c for c in v.candidates(("heading_drift",), target=side, like=other) if c.fit is not None]
    if not found or found[0].below_floor(float(torch.diff(v.current[0].time).median())):
        return None
    moved, implausible = v.adopted(found[0])
    if implausible:
        return None
    moved = copy.deepcopy(moved)
    derived = bool(moved.params.get("derived"))
    shares = derived or float(moved.params.get("own_gyro_score", 0.0)) <= 0.0
    moved.params.update(gyro_shares=shares, tilt=shares and not derived)
    add_tracked(v, moved, links, gain, progress, max_samples)
    return moved

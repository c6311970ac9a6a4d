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

import math
from typing import Callable

from .crossing import add_tracked, fitted, rebuilt
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
    for side in (x for x in sides if x not in drifting and x in links):
        v = rebuilt(s, (axis,))
        analyse_subjects([v], links, gain, progress, max_samples)
        # not calibrated on how its gains scatter: a drift carried into an arm's chain shows at the elbow
        # more in some postures than in others; whether the axis is still needed with it decides
        drift, why = fitted(v, "heading_drift", side, threshold, links, calibrated=False)
        if drift is None:
            say(f"the axis at {axis.target} stays: a heading drift of {side} in its place does not fit ({why})")
            continue
        add_tracked(v, drift, links, gain, progress, max_samples)
        still, why_not = fitted(v, "missing_dof", axis.target, threshold, links)
        if still is not None:
            say(f"the axis at {axis.target} stays: with {side}'s heading drifting, it is still significant")
            continue
        axis.notes = "; ".join(filter(None, [axis.notes, f"replaced by a heading drift of {side}: with it, the axis "
                                                         f"is no longer needed ({why_not})"]))
        s.rejected.append(axis)
        drift.notes = "; ".join(filter(None, [drift.notes, (
            f"in place of a missing axis at {axis.target} (moving over "
            f"{', '.join(f'{math.degrees(x):.1f}' for x in axis.params['angle_range'])} deg)"
            + (": this sensor's gyro is biased, and a filter without a heading reference integrates the bias into "
               "its heading" if side in biased else ""))]))
        s.recording, s.urdf, s.model, s.analysis, s.steps = v.recording, v.urdf, v.model, v.analysis, v.steps
        say(f"the axis at {axis.target} replaced by {drift.summary()}")
        return True
    return False


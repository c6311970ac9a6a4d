"""A joint limit that is a sensor's turn about the joint's axis.

A strap or a marker cluster turned on its segment about one of the joint's own axes is, to the
tracker, the joint's angle moved by the turn: the joint follows it, and nothing shows until the
moved angle reaches the joint's limit. There the joint holds, the residual is the angle beyond the
limit, and the loop's best explanation of it is the limit set wider (JointLimit): a misalignment's
linear fit, held at the limit (placement.py), takes only the mean of that excess over the samples at
the limit, and leaves the rest to the limit. A narrow limit (Human48's shoulder girdle moves by 5
deg either way) is crossed by a strap's turn of a few degrees.

Both explain the residual with one number, but where the sensor of one of the joint's segments is
already known to be turned (its misalignment kept) the rest of that turn is one cause against two: a
strap turned, and the model's range too narrow besides. Where neither segment's sensor is known to be
turned, the limit is as likely, and stays. The data tell them apart by the joint's other side too: the
least turn that brings the motion back within the limit (its largest excess, about the joint's axis)
moves the whole motion, and where the joint then runs into its other limit, the motion is wider than
the model's range and the limit stays. So once a limit is kept, each of the joint's two tracked
segments whose misalignment is kept (the child first) is tried: the recording without the limit, that
misalignment completed by the least turn, re-tracked; where the joint's limit is then no longer
significant and the tracking is no worse, the turn replaces the limit.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from ...method import so3
from .crossing import add_tracked, fitted, rebuilt, take
from .joints import JointLimit, joint_groups
from .placement import Misalignment
from .result import WORSE, errors
from .subject import Subject, analyse_subjects


def limit_as_turn(s: Subject, limit: JointLimit, links, gain: float, threshold: float, progress: bool,
                  max_samples: int, say: Callable[[str], None]) -> bool:
    """Try the kept `limit` as the least turn of the joint's child's, then its parent's, sensor about the
    joint's axis, where that sensor's misalignment is kept (module docstring); adopt the first that
    leaves the limit standing no longer. Returns whether one was adopted."""
    group = next((g for g in joint_groups(s.urdf, s.current[0].links) if limit.target in g.joints), None)
    if group is None:
        return False
    turned = {e.target: e for e in s.effects if isinstance(e, Misalignment)}
    for link, side in ((group.child, 1.0), (group.parent, -1.0)):
        if link in turned and _turned(s, limit, turned[link], side, links, gain, threshold, progress, max_samples,
                                      say):
            return True
    return False


def _axis_in(s: Subject, joint: str, link: str) -> torch.Tensor | None:
    """[3] the joint's axis in `link`'s frame, the mean over the samples where the joint is at its limit
    (the tracked link's frame turns with the joints between them); None where it never is."""
    analysis, b = s.current
    j = analysis.model.joint_names.index(joint)
    k = analysis.sample
    at = analysis.active[k, b][:, j]
    if not bool(at.any()):
        return None
    R = analysis.R_hat[k, b, analysis.links.index(link)][at]  # [P,3,3]
    a = (R.transpose(-1, -2) @ analysis.joint_axes[:, b, j][at][..., None])[..., 0].mean(0)
    return a / a.norm().clamp(min=1e-12)


def _turned(s: Subject, limit: JointLimit, kept: Misalignment, side: float, links, gain: float, threshold: float,
            progress: bool, max_samples: int, say: Callable[[str], None]) -> bool:
    """limit_as_turn's try of the `kept` misalignment's sensor (side +1 below the joint, -1 above it):
    adopted into s where the limit no longer stands. Returns whether it was."""
    link = kept.target
    axis = _axis_in(s, limit.target, link)
    if axis is None:
        return False
    # the child's sensor turned by delta about the axis reads the joint delta further; the parent's, delta less
    delta = side * (limit.params["needed"] - limit.params["limit"])
    C = so3.exp(delta * axis) @ torch.as_tensor(kept.rotation(), dtype=axis.dtype)
    turn = Misalignment("misalignment", link, dict(kept.params, rotation_vector=so3.log(C).tolist()),
                        dict(kept.stderr), kept.n_params, kept.fit)
    v = rebuilt(s, (limit, kept))
    analyse_subjects([v], links, gain, progress, max_samples)
    add_tracked(v, turn, links, gain, progress, max_samples)
    still, why_not = fitted(v, "joint_limit", limit.target, threshold, links)
    before, after = errors(*s.current).overall["mnte"], errors(*v.current).overall["mnte"]
    if still is not None or after > before * (1.0 + WORSE):
        say(f"the limit of {limit.target} stays: with {link}'s sensor turned by {math.degrees(delta):+.1f} deg about its "
            f"axis, " + ("the limit is still needed" if still is not None
                         else f"the tracking is worse (its mean orientation error {after:.4g} against {before:.4g})"))
        return False
    turn.notes = "; ".join(filter(None, [kept.notes, (
        f"in place of {limit.summary()}: its turn completed about the joint's axis by the "
        f"{abs(math.degrees(delta)):.1f} deg that bring the motion back within the limit, which the joint then no "
        f"longer needs ({why_not})")]))
    limit.notes = "; ".join(filter(None, [limit.notes, f"replaced by a misalignment of {link}: a turn of its sensor "
                                                       f"about the joint's axis explains it, within the joint's range"]))
    kept.notes = "; ".join(filter(None, [kept.notes, f"completed about {limit.target}'s axis, in place of its limit"]))
    s.rejected += [limit, kept]
    take(s, v)
    say(f"{limit.summary()} replaced by a turn of the {link} sensor about the joint's axis "
        f"({math.degrees(delta):+.1f} deg)")
    return True

"""A position target measured at a point offset from its link's origin.

With the base free, the tracker moves the whole body to the measured point and leaves no position
residual: the offset shows only where the position stream disagrees with the velocity stream of
the link origin (an optical cluster's position against an inertial velocity, say):

    e_p = S(v_m) - dp_m/dt = -w x (R o) = -hat(w) R o,   o constant in the link frame,

fitted by least squares (both sides low-passed as for the gyro effects). When the velocity is
itself the derivative of the same positions, the streams agree and no offset can be seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...method import so3
from .analysis import Analysis
from .effect import Effect, lowpass_blocks, replace, score
from .series import simpson

MAX_OFFSET = 0.3  # m: a point on the pelvis is within this of its origin
OFFSET_FLOOR = 1.0  # cm: a marker's or a suit's pelvis origin is placed to within this; less changes no reported position


@dataclass
class PositionOffset(Effect):
    """The base link's position target is at params['offset'] [3] (m, link frame) from its origin."""

    additive = ("offset",)
    error = "base_velocity_rmse"
    floor, unit = OFFSET_FLOOR, "cm"

    def size(self, dt):
        return 100.0 * float(np.linalg.norm(self.params["offset"]))

    def apply(self, recording, sign):
        R = recording.orientation[:, recording.links.index(recording.base_link)]
        p = recording.base_position + sign * (R @ np.asarray(self.params["offset"]))
        return replace(recording, base_position=p)

    def implausible(self):
        size = float(np.linalg.norm(self.params["offset"]))
        return (f"a position {100 * size:.0f} cm from the link's origin, beyond the {100 * MAX_OFFSET:.0f} cm of a "
                f"segment: a sign of a position of another segment, or in other units" if size > MAX_OFFSET else "")

    def summary(self):
        o = np.asarray(self.params["offset"])
        components = ", ".join(f"{x:+.3f}" for x in o)
        return (f"the {self.target} position is measured {100 * np.linalg.norm(o):.1f} cm from its origin "
                f"({components} m, link frame)")


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, cutoff: float = 5.0) -> list[Effect]:
    base = analysis.model.base_link
    if base not in analysis.links:
        return []
    i = analysis.links.index(base)
    if bool(analysis.velocity_derived[b]):
        return [PositionOffset("position_offset", base,
                               notes="not identifiable: the base velocity is the positions' "
                                     "derivative, which agrees with them wherever they are measured")]
    time = analysis.time
    ok = analysis.valid[:, b, i] & torch.isfinite(analysis.p_m[:, b]).all(-1)
    tr, te = ok & train, ok & test
    if int(tr.sum()) < 8 or int(te.sum()) < 8:
        return []
    cutoff = min(cutoff, 0.25 / float(torch.diff(time).median()))
    low = lambda x: lowpass_blocks(x, time, cutoff, train, test)  # noqa: E731
    R = torch.where(ok[:, None, None], analysis.R_m[:, b, i], torch.eye(3, dtype=time.dtype))
    w = simpson(torch.where(ok[:, None], analysis.w_m[:, b, i], 0.0))
    X = low(-so3.hat(w) @ R)
    y = low(torch.where(ok[:, None], analysis.e_p[:, b], 0.0))
    N = (X[tr].transpose(-1, -2) @ X[tr]).sum(0)
    if float(torch.linalg.eigvalsh(N)[0]) <= 1e-9 * float(N.diagonal().sum()):
        return []
    o = torch.linalg.solve(N, (X[tr].transpose(-1, -2) @ y[tr, :, None]).sum(0)).squeeze(-1)
    fit_o = score(y[te], y[te] - X[te] @ o, 3)
    cov = fit_o.sigma2 * fit_o.tau * torch.linalg.inv(N)
    return [PositionOffset("position_offset", base, dict(offset=o.tolist()), dict(offset=cov.diagonal().sqrt().tolist()),
                           3, fit_o)]

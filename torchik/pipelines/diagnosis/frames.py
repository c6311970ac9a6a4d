"""The flipped segment frame: a sensor's frame turned by half a turn about one of its own axes.

A segment frame built the wrong way round (a cross product taken in the other order, an axis
pointing to a marker of the other side) or a sensor strapped upside down gives R_m = R F, with
F = diag(+-1) reversing two of the three axes: a half turn about the third. The angular velocity
is in the world frame (io/recording.py) and does not change (F is constant).

A half turn cannot be linearised: sk(R_m R^T)^vee, the residual the other families fit, vanishes
at 180 deg, and their fits take what is left of it for a misalignment or a static pose beyond any
strap's or posture's bounds. Each candidate is scored by re-tracking instead: on every link whose
residual is large (rms angle above LARGE), the recording with the flip about each axis undone, all
of them tracked in one batch, and what the tracker leaves on the test half of the time compared with
what it leaves now (effect.score, one parameter). The residual compared is the chordal one,
R_m - R_hat of every link, whose square is 4 (1 - cos) of the angle: the MNTE the loop judges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .analysis import Analysis
from .effect import Effect, halves, replace, score
from .joints import joint_groups
from .subject import Subject, analyse_subjects

KIND = "flipped_frame"
LARGE = 30.0  # deg: the rms angle of a link's residual above which its frame may be flipped
AXES = "xyz"
VARIANT_SAMPLES = 2  # the sample times of the flipped recordings' task Jacobian, which their score does not use


def flip(axis: str) -> np.ndarray:
    """F [3,3]: the half turn about `axis` ('x', 'y' or 'z'), diag(+-1); its own inverse."""
    return np.diag([1.0 if a == axis else -1.0 for a in AXES])


@dataclass
class FlippedFrame(Effect):
    """The frames of the sensors params['links'] (`target` and, for a whole limb, the tracked links
    below it) turned by 180 deg about their own axis params['axis'] ('x', 'y' or 'z'): R_m = R F
    (flip). A choice among a few, with no continuous parameter to refine."""

    def apply(self, recording, sign):
        R = recording.orientation.copy()
        F = flip(self.params["axis"])
        for name in self.params["links"]:
            i = recording.links.index(name)
            R[:, i] = R[:, i] @ F  # F^-1 = F: adding and removing it are the same
        return replace(recording, orientation=R)

    def overlaps(self, other):
        return other.kind == self.kind and list(other.params.get("links", [])) == list(self.params["links"])

    def summary(self):
        links = self.params["links"]
        if len(links) == 1:
            return f"the {self.target} sensor frame flipped 180 deg about its {self.params['axis']} axis"
        return f"the {', '.join(links)} sensor frames flipped 180 deg about their {self.params['axis']} axes"


def chordal_residual(analysis: Analysis, b: int) -> torch.Tensor:
    """[T,L,9] R_m - R_hat of subject b, zero where the measurement is missing."""
    ok = analysis.valid[:, b, :, None]
    return torch.where(ok, (analysis.R_m[:, b] - analysis.R_hat[:, b]).flatten(-2), 0.0)


def large_residual(analysis: Analysis, b: int, transient: float = 1.0) -> list[str]:
    """The links of subject b whose orientation residual has an rms angle above LARGE (after the
    transient); the angle from the trace, which does not saturate at 90 deg as |r| = sin does."""
    time = analysis.time
    keep = time >= time[0] + (transient if float(time[-1] - time[0]) > 3 * transient else 0.0)
    ok = analysis.valid[:, b] & keep[:, None]  # [T,L]
    trace = (analysis.R_m[:, b] * analysis.R_hat[:, b]).sum((-1, -2))  # tr(R_m R_hat^T)
    angle = torch.arccos(((trace - 1.0) / 2.0).clamp(-1.0, 1.0))
    rms = (torch.where(ok, angle.square(), 0.0).sum(0) / ok.sum(0).clamp(min=1)).sqrt()
    return [name for name, value, n in zip(analysis.links, rms.tolist(), ok.sum(0).tolist())
            if n >= 8 and value > math.radians(LARGE)]


def flip_sets(s: Subject) -> list[list[str]]:
    """The sets of links whose frames subject s's candidates flip: each link with a large residual
    (large_residual) and each tracked link one joint from it (the tracker shares a flip's residual
    with the links the joints between them connect, and may leave most of it on a neighbour), alone
    and with the tracked links below it (a whole limb's frames built the wrong way round, which a
    static pose would need half a turn to explain); but those scored since the last flip was kept
    (s.tried)."""
    analysis, b = s.current
    groups = joint_groups(s.urdf, analysis.links)
    large = set(large_residual(analysis, b))
    near = large | {g.parent for g in groups if g.child in large} | {g.child for g in groups if g.parent in large}
    below = {g.child: tuple(n for n in analysis.links if n in g.subtree) for g in groups}
    flips = sum(e.kind == KIND for e in s.effects)
    sets = {(name,) for name in near} | {below[name] for name in near if len(below.get(name, ())) > 1}
    return [list(links) for links in sorted(sets) if (links, flips) not in s.tried]


def candidates(s: Subject, kinds, taken: list[Effect], gain: float) -> list[Effect]:
    """FlippedFrame candidates of subject s, scored by re-tracking, best first: three (one per axis)
    on each of flip_sets(s) that has no flip taken (kept or rejected); none when KIND is not among
    `kinds`. The recordings with each flip undone track as one batch."""
    if KIND not in kinds:
        return []
    analysis, b = s.current
    flips = sum(e.kind == KIND for e in s.effects)
    found = [FlippedFrame(KIND, links[0], dict(axis=axis, links=links), n_params=1) for links in flip_sets(s)
             for axis in AXES]
    found = [c for c in found if not any(c.overlaps(e) for e in taken)]
    if not found:
        return []
    s.tried |= {(tuple(c.params["links"]), flips) for c in found}
    variants = [Subject(c.correct(s.recording), s.urdf, s.model) for c in found]
    analyse_subjects(variants, analysis.links, gain, False, VARIANT_SAMPLES)
    test = halves(analysis.time)[1]
    y = chordal_residual(analysis, b)[test].flatten(1)
    for c, v in zip(found, variants):
        left = chordal_residual(*v.current)[test].flatten(1)
        c.fit = score(y, left, c.n_params)
    return sorted(found, key=lambda c: -c.score)

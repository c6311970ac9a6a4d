"""The flipped segment frame (a sensor's frame turned by half a turn about one of its own axes) and the
swapped segments (a link's streams exchanged with its counterpart's on the other side).

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
A half turn has no size to fit: where it is the cause, undoing it leaves only noise on its links, so
one that removes less than MIN_REMOVED of the residual there (and one joint away) is refused as
implausible: it brought a cause of another size closer (a static pose of 110 deg, which a half turn leaves at 70).

Markers of the two sides mislabelled give a link the streams of its counterpart (the left forearm's
on the right one); scored the same way, by re-tracking with the streams exchanged back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .analysis import Analysis
from .chunks import Chunking
from .effect import Effect, halves, replace, score
from .joints import joint_groups
from .subject import Subject, analyse_subjects

KIND = "flipped_frame"
SWAP = "swapped_segments"
KINDS = (KIND, SWAP)
LARGE = 30.0  # deg: the rms angle of a link's residual above which its frame may be flipped
AXES = "xyz"
MIN_REMOVED = 0.5  # a flip or a swap that is the cause leaves only noise on its links once undone: most of it goes
VARIANT_SAMPLES = 2  # the sample times of the flipped recordings' task Jacobian, which their score does not use


def flip(axis: str) -> np.ndarray:
    """F [3,3]: the half turn about `axis` ('x', 'y' or 'z'), diag(+-1); its own inverse."""
    return np.diag([1.0 if a == axis else -1.0 for a in AXES])


@dataclass
class Retracked(Effect):
    """An effect scored by re-tracking with it undone; params['removed']: the share of the residual on
    its links and those one joint from them that undoing it removed (test half)."""

    def implausible(self):
        removed = self.params.get("removed", 1.0)
        return "" if removed >= MIN_REMOVED else (
            f"undone, it removes {100 * removed:.0f} % of the residual on its links and those one joint away, "
            f"not the {100 * MIN_REMOVED:.0f} % that would be gone were it the cause: it has no size to fit, so "
            f"what it removes is a cause of another size brought closer (a static pose, a misalignment)")


@dataclass
class FlippedFrame(Retracked):
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


@dataclass
class SwappedSegments(Retracked):
    """The streams (orientation and angular velocity) of the links params['links'] exchanged with
    those of their counterparts on the other side: its first half, Left, with its second, Right.
    Exchanging them again undoes it."""

    def apply(self, recording, sign):
        links = self.params["links"]
        half = len(links) // 2
        i = [recording.links.index(n) for n in links]
        j = i[half:] + i[:half]  # each link's counterpart
        R, w = recording.orientation.copy(), recording.angular_velocity.copy()
        R[:, i], w[:, i] = recording.orientation[:, j], recording.angular_velocity[:, j]
        return replace(recording, orientation=R, angular_velocity=w)

    def overlaps(self, other):
        return other.kind == self.kind and sorted(other.params.get("links", [])) == sorted(self.params["links"])

    def summary(self):
        links = self.params["links"]
        half = len(links) // 2
        return f"the streams of {', '.join(links[:half])} swapped with those of {', '.join(links[half:])}"


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


def flip_sets(s: Subject) -> list[tuple[str, ...]]:
    """The sets of links whose frames subject s's candidates flip: each link with a large residual
    (large_residual) and each tracked link one joint from it (the tracker shares a flip's residual
    with the links the joints between them connect, and may leave most of it on a neighbour), alone
    and with the tracked links below it (a whole limb's frames built the wrong way round, which a
    static pose would need half a turn to explain)."""
    analysis, b = s.current
    groups = joint_groups(s.urdf, analysis.links)
    large = set(large_residual(analysis, b))
    near = large | {g.parent for g in groups if g.child in large} | {g.child for g in groups if g.parent in large}
    below = {g.child: tuple(n for n in analysis.links if n in g.subtree) for g in groups}
    return sorted({(name,) for name in near} | {below[name] for name in near if len(below.get(name, ())) > 1})


def swap_sets(s: Subject) -> list[tuple[str, ...]]:
    """The sets of links whose streams subject s's candidates swap with their counterparts': each link
    with a large residual and a tracked counterpart (Left for Right), alone and with the tracked links
    below it, every one of them with a counterpart; the side named Left first."""
    analysis, b = s.current
    below = {g.child: tuple(n for n in analysis.links if n in g.subtree) for g in joint_groups(s.urdf, analysis.links)}
    sets = set()
    for name in large_residual(analysis, b):
        left = counterpart(name) if name.startswith("Right") else name
        for links in ((left,), below.get(left, ())):
            if links and all(counterpart(n) in analysis.links for n in links):
                sets.add(links)
    return sorted(sets)


def counterpart(name: str) -> str:
    """The name of the link on the other side (Left for Right and the reverse; itself when neither)."""
    for a, b in (("Left", "Right"), ("Right", "Left")):
        if name.startswith(a):
            return b + name[len(a):]
    return name


def candidates(s: Subject, kinds, taken: list[Effect], gain: float) -> list[Effect]:
    """FlippedFrame (three, one per axis, on each of flip_sets) and SwappedSegments (on each of
    swap_sets) candidates of subject s, scored by re-tracking, best first; of the kinds among `kinds`,
    but those that overlap one taken (kept or rejected) and those scored since the last of either kind
    was kept (s.tried). The recordings with each undone track as one batch."""
    analysis, b = s.current
    kept = sum(e.kind in KINDS for e in s.effects)
    found: list[Effect] = []
    if KIND in kinds:
        found += [FlippedFrame(KIND, links[0], dict(axis=axis, links=list(links)), n_params=1)
                  for links in flip_sets(s) for axis in AXES]
    if SWAP in kinds:
        found += [SwappedSegments(SWAP, links[0], dict(links=list(links) + [counterpart(n) for n in links]),
                                  n_params=1) for links in swap_sets(s)]
    found = [c for c in found if (c.kind, c.summary(), kept) not in s.tried and not any(c.overlaps(e) for e in taken)]
    if not found:
        return []
    s.tried |= {(c.kind, c.summary(), kept) for c in found}
    # a flipped or swapped frame guessed wrong leaves residuals whose chunks disagree: not the subject's
    variants = [Subject(c.correct(s.recording), s.urdf, s.model, chunking=Chunking(s.chunking.on)) for c in found]
    analyse_subjects(variants, analysis.links, gain, False, VARIANT_SAMPLES)
    test = halves(analysis.time)[1]
    y = chordal_residual(analysis, b)[test]
    groups = joint_groups(s.urdf, analysis.links)
    for c, v in zip(found, variants):
        left = chordal_residual(*v.current)[test]
        c.fit = score(y.flatten(1), left.flatten(1), c.n_params)
        moved = set(c.params["links"])
        near = moved | {n for g in groups if g.child in moved or g.parent in moved for n in (g.child, g.parent)}
        area = torch.tensor([n in near for n in analysis.links])
        before = float(y[:, area].square().sum())
        c.params["removed"] = 1.0 - float(left[:, area].square().sum()) / max(before, 1e-30)
    return sorted(found, key=lambda c: -c.score)

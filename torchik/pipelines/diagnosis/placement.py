"""Effects of where and when a sensor measures: misalignment, delay against the others (heading drift,
fitted with this module's linear fits: drift.py).

A sensor's orientations R_m differ from the link's R by a small rotation delta (world frame,
R_m = exp(delta) R); the tracker leaves r = M delta (analysis.py), so that delta = G theta with
theta the effect's parameters is fitted by least squares against M:

    theta = (sum_t G^T M G)^+ sum_t G^T M r

- misalignment C = exp(c), c constant in the link frame (R_m = R C):    G = R_hat
- the sensor's streams late by d on the others' (R_m(t) = R(t - d)):     G = -w_hat
- heading drift eps about the world vertical (R_m = Rz(eps (t - t0)) R): G = (t - t0) z, and the
  gyro, rotated with it, disagrees with the orientations by e = -eps z: both channels are fitted.

Directions the joints can follow leave no residual (G^T M G is singular there): a misalignment
about a link's own joint axes is a joint offset to the data, and is reported as not identified.
Unless it carries the joint to its limit: there the joint cannot follow it further, and the residual
it leaves is the part beyond the limit, which a joint limit would otherwise take (explaining the
residual only while the joint is there). A misalignment is fitted both ways, M with the joints free
and M without the joints next to its link where they are at a limit (project_held), and keeps the better
calibrated score: the joint holds at its limit against the sensor's turn, or moves off it with the
turn the other way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection

import numpy as np
import torch

from ...method import so3
from .analysis import Analysis
from .effect import SIGNIFICANT, Effect, Score, combine, replace, score, shift

KINDS = ("misalignment", "sensor_delay")  # the candidates fit() makes
MAX_DELAY = 0.25  # s: a sensor later than this on the others is no delay but a different recording
MAX_DRIFT = 5.0  # deg/s: heading drift of inertial sensors is a fraction of this
MAX_MISALIGNMENT = 45.0  # deg: the most a strap or a marker cluster turns a sensor on its segment
# Relevance floors (Effect.below_floor). A strap or a marker cluster is placed to within a degree or
# two; a constant offset under 1 deg changes no joint angle beyond what a gait lab reports to.
MISALIGNMENT_FLOOR = 1.0  # deg
# One sample: a delay below it is the sampling's own (an integrate-and-dump or anti-alias filter delays a
# gyro's rate by half a sample on its orientation) and nothing a recording's clocks can fix.
DELAY_FLOOR = 1.0  # samples
# 0.05 deg/s turns a heading by 3 deg a minute; over a shorter recording, a drift whose whole turn stays
# under the misalignment's floor (1 deg) is below it too (HeadingDrift.relevance_floor).
DRIFT_FLOOR = 0.05  # deg/s
IDENTIFIABLE = 1e-2  # eigenvalues of G^T M G below this share of the largest: a direction not identified
LEVERAGE = 1e-3  # a direction that leaves less of itself in the residual (G^T M G against G^T G): followed by the joints


def project_blocks(analysis: Analysis, b: int, links: list[int], blocks: torch.Tensor) -> torch.Tensor:
    """M G for N candidates whose G is `blocks` [N,S,3,k] on the orientation rows of links[n] and
    zero elsewhere -> [N,S,R,k]."""
    M = analysis.projector(b)  # [S,R,R]
    columns = M[:, :, 3:].unflatten(-1, (-1, 3)).permute(0, 2, 1, 3)  # [S,L,R,3]: M's columns of each link's rows
    if list(links) != list(range(columns.shape[1])):
        columns = columns[:, links]
    return (columns @ blocks.transpose(0, 1)).transpose(0, 1)  # [S,N,R,3] @ [S,N,3,k] -> [N,S,R,k]


def adjacent_joints(analysis: Analysis) -> torch.Tensor:
    """[L,n] the joints next to each tracked link: those between it and its nearest tracked ancestor
    (all above it for the root) and those between it and the tracked links whose nearest it is."""
    above = analysis.model.select(analysis.links).ancestor_mask.bool()  # [L,n]
    count = above.sum(-1)  # [L]
    inside = (above[None, :, :] <= above[:, None, :]).all(-1) & (count[None, :] < count[:, None])  # [L,L]: p above l
    has = inside.any(-1)
    parent = torch.where(inside, count[None, :], -1).argmax(-1)  # the deepest link above each
    own = above & ~(above[parent] & has[:, None])
    child = torch.nn.functional.one_hot(parent, len(count)).T.bool() & has[None, :]  # [L,L]: c's parent is l
    return own | (child.to(torch.float64) @ own.to(torch.float64) > 0)


def project_held(analysis: Analysis, b: int, links: list[int], blocks: torch.Tensor) -> torch.Tensor:
    """project_blocks with M, for candidate n, built without the joints next to links[n]
    (adjacent_joints) at the samples where they are at a limit (analysis.active): the tracker cannot
    move them further, so a sensor turned until the joints that follow it (its own, or those of the
    links below that keep them where their sensors say) reach a limit leaves its residual there,
    which the free joint would seem to follow -> [N,S,R,k]."""
    k = analysis.sample
    out = project_blocks(analysis, b, links, blocks).clone()
    held = analysis.active[k, b][None] & adjacent_joints(analysis)[links][:, None]  # [N,S,n]
    # M changes only at the (candidate, sample) pairs with a joint held: a few of the N S, mostly
    cand, at = torch.nonzero(held.any(-1), as_tuple=True)  # [P] each
    if not len(cand):
        return out
    J, A = analysis.without(b, held[cand, at], at)
    X = blocks.new_zeros(len(cand), J.shape[1], blocks.shape[-1])  # [P,R,k]: each candidate's G at that sample
    rows = 3 + 3 * torch.as_tensor(links)[cand, None] + torch.arange(3)  # [P,3]: its link's orientation rows
    X.scatter_(1, rows[..., None].expand(-1, -1, X.shape[-1]), blocks[cand, at])
    out[cand, at] = analysis.project(b, X[None], J, A, at)[0]
    return out


@dataclass
class LinearFit:
    """theta [k], its covariance [k,k], the identified directions [k,m], and the Score."""

    theta: torch.Tensor
    cov: torch.Tensor
    identified: torch.Tensor
    fit: Score


def fit_linear(analysis: Analysis, b: int, links: list[int], blocks: torch.Tensor, train: torch.Tensor,
               test: torch.Tensor, extra: list | None = None) -> list[LinearFit]:
    """Fit r = M G theta for N candidates at once, G being `blocks` [N,S,3,k] on the orientation
    rows of links[n] (project_blocks), on train, score on test (train, test [N,T] masks). `extra`:
    per candidate a second channel (N_e [k,k], g_e [k], sigma2_e, y_test [n,d], predict(theta) ->
    [n,d]) fitted jointly. A direction is identified when it leaves at least LEVERAGE of itself in
    the residual (the joints do not follow it) and carries IDENTIFIABLE of the largest eigenvalue."""
    return fit_projected(analysis, b, project_blocks(analysis, b, links, blocks),
                         blocks.transpose(-1, -2) @ blocks, train, test, extra)


def fit_projected(analysis: Analysis, b: int, MG: torch.Tensor, GG: torch.Tensor, train: torch.Tensor,
                  test: torch.Tensor, extra: list | None = None) -> list[LinearFit]:
    """fit_linear with M G [N,S,R,k] given, and G^T G [N,S,k,k] (before the joints absorb their part):
    for candidates whose G spans the rows of several links (posture.py)."""
    tr, te = train[:, analysis.sample], test[:, analysis.sample]  # [N,S]
    r = analysis.stacked_residual(b)  # [S,R]
    w = tr.to(MG.dtype)[..., None, None]
    N = (w * (MG.transpose(-1, -2) @ MG)).sum(1)  # [N,k,k]
    N0 = (w * GG).sum(1)  # the same before the joints absorb their part
    g = (w[..., 0] * (MG.transpose(-1, -2) @ r[..., None])[..., 0]).sum(1)  # [N,k]
    sigma2_o = max(float(torch.diff(r[:, 3:], dim=0).square().mean()) / 2.0, 1e-12)  # white noise: var(dr) = 2 sigma^2
    if extra is not None:
        N_e, g_e = torch.stack([x[0] for x in extra]), torch.stack([x[1] for x in extra])
        sigma2_e = torch.tensor([x[2] for x in extra], dtype=N.dtype)
        N, N0, g = (N / sigma2_o + N_e / sigma2_e[:, None, None], N0 / sigma2_o + N_e / sigma2_e[:, None, None],
                    g / sigma2_o + g_e / sigma2_e[:, None])
    # every candidate at once; the directions not kept have a zero weight in the inverse
    eigval, eigvec = torch.linalg.eigh(N)  # [N,k], [N,k,k]
    leverage = eigval / torch.einsum("nik,nij,njk->nk", eigvec, N0, eigvec).clamp(min=1e-300)
    keep = (eigval > IDENTIFIABLE * eigval.amax(-1, keepdim=True).clamp(min=1e-300)) & (leverage > LEVERAGE)
    inverse = eigvec @ (torch.where(keep, 1.0 / eigval, 0.0)[..., None] * eigvec.transpose(-1, -2))  # [N,k,k]
    theta = (inverse @ g[..., None])[..., 0]  # [N,k]
    pred = (MG @ theta[:, None, :, None])[..., 0]  # [N,S,R]
    energy = pred.square().sum(1)  # [N,R]
    support = energy > 1e-6 * energy.amax(-1, keepdim=True).clamp(min=1e-300)
    support[:, :3] = False  # the base position (metres) is not part of an orientation effect's support
    out = []
    for n in range(MG.shape[0]):
        k = int(keep[n].sum())
        y = r[te[n]][:, support[n]]
        fit = score(y, y - pred[n, te[n]][:, support[n]], 0 if extra is not None else k)
        if extra is not None:
            y_e, predict = extra[n][3], extra[n][4]
            fit = combine((fit, 0), (score(y_e, y_e - predict(theta[n]), 0), k))
        scale = fit.sigma2 * fit.tau if extra is None else fit.tau  # extra: N already weighted by 1/sigma^2
        out.append(LinearFit(theta[n], inverse[n] * scale, eigvec[n][:, keep[n]], fit))
    return out


def _held_or_free(free: LinearFit, held: LinearFit) -> LinearFit:
    """The misalignment fit of the better calibrated score, with M's joints free or held at their limits
    (module docstring). Held, the part about a joint's axis is the least turn that keeps the joint
    within its limit, not the sensor's whole turn about it (the residual beyond the limit is what
    shows): the directions the data determine stay those of the free fit, where it has any. Only a
    turn the free fit already finds significant is completed so: one that shows only while a joint is
    at its limit is, to the data, just as well that limit set narrower than the motion."""
    if held.fit.calibrated <= free.fit.calibrated or free.fit.calibrated <= SIGNIFICANT:
        return free  # seen only at the limits, a turn is as much a limit narrower than the motion
    return held if not free.identified.shape[1] else LinearFit(held.theta, held.cov, free.identified, held.fit)


UNOBSERVABLE = "not identifiable: the joints follow every direction of it, so it leaves no residual"
ONE_CLOCK = ("not fitted: one clock samples every segment (optical markers; the file declares no separate streams, "
             "meta['clock'])")


def _unidentified(lf: LinearFit, k: int) -> str:
    """The directions (link frame) a misalignment fit could not identify, in words."""
    m = lf.identified.shape[1]
    if m == k:
        return ""
    free = torch.linalg.svd(torch.eye(k, dtype=lf.identified.dtype) - lf.identified @ lf.identified.T)[0][:, :k - m]
    about = " and ".join("(" + ", ".join(f"{x:+.2f}" for x in v) + ")" for v in free.T.tolist())
    return (f"not identified about {about} in the link frame (the joints follow it; that part is set to zero, or "
            f"where a joint is held at its limit to the least turn that keeps it within, and its standard error "
            f"means nothing)")


@dataclass
class Misalignment(Effect):
    """A constant sensor-to-segment rotation: R_m = R C, C = exp(params['rotation_vector']) (link
    frame); params['identified']: the unit directions (link frame) the data determine."""

    floor, unit = MISALIGNMENT_FLOOR, "deg"

    def size(self, dt):
        return float(np.degrees(np.linalg.norm(self.params["rotation_vector"])))

    def apply(self, recording, sign):
        i = recording.links.index(self.target)
        C = self.rotation()
        R = recording.orientation.copy()
        R[:, i] = R[:, i] @ (C if sign > 0 else C.T)
        return replace(recording, orientation=R)

    def directions(self, name):
        if name != "rotation_vector" or "identified" not in self.params:
            return super().directions(name)
        return np.asarray(self.params["identified"], dtype=np.float64).reshape(-1, 3).T  # the joints follow the rest

    def rotation(self) -> np.ndarray:
        return so3.exp(torch.tensor(self.params["rotation_vector"], dtype=torch.float64)).numpy()

    def unseen(self) -> np.ndarray:
        """[m,3] the unit directions (link frame) of a turn of this sensor that the data cannot see: the
        joints follow them (all three where the fit identified none)."""
        V = np.asarray(self.params.get("identified", []), dtype=np.float64).reshape(-1, 3)
        if not len(V):
            return np.eye(3)
        U, S, _ = np.linalg.svd(np.eye(3) - V.T @ np.linalg.pinv(V.T), full_matrices=True)
        return U[:, S > 0.5].T

    def implausible(self):
        c = np.asarray(self.params["rotation_vector"], dtype=np.float64)
        angle = float(np.degrees(np.linalg.norm(c)))
        if angle <= MAX_MISALIGNMENT:
            return ""
        axis = c / np.linalg.norm(c)
        near = int(np.argmax(np.abs(axis)))
        flipped = abs(axis[near]) > 0.9 and min(abs(angle - 90.0), abs(angle - 180.0)) < 20.0
        cause = (f"a segment frame flipped or swapped (about {angle:.0f} deg about its {'xyz'[near]} axis)" if flipped
                 else "a static pose that is not the assumed one (the arms', the pelvis' posture) or a mislabelled marker")
        return f"a misalignment of {angle:.0f} deg, beyond the {MAX_MISALIGNMENT:g} deg a strap allows: a sign of {cause}"

    def refine(self, update):
        C = update.rotation() @ self.rotation()  # R_m C^T = R Delta: C_true = Delta C
        self.params["rotation_vector"] = so3.log(torch.from_numpy(C)).tolist()
        self.stderr, self.notes = update.stderr, update.notes
        return self

    def summary(self):
        c = np.asarray(self.params["rotation_vector"])
        return (f"misalignment of the {self.target} sensor: {np.degrees(np.linalg.norm(c)):.2f} deg about "
                f"({', '.join(f'{x:+.2f}' for x in c / max(np.linalg.norm(c), 1e-12))}) in the link frame")


@dataclass
class SensorDelay(Effect):
    """A sensor whose streams (orientation and gyro) are late on the others by params['delay'] s."""

    additive = ("delay",)
    unit = "ms"

    def size(self, dt):
        return 1e3 * abs(self.params["delay"])

    def relevance_floor(self, dt):
        return 1e3 * dt * DELAY_FLOOR

    def apply(self, recording, sign):
        i, d = recording.links.index(self.target), -sign * self.params["delay"]
        R, w = recording.orientation.copy(), recording.angular_velocity.copy()
        R[:, i] = shift(R[:, i], recording.time, d, rotations=True)
        w[:, i] = shift(w[:, i], recording.time, d)
        return replace(recording, orientation=R, angular_velocity=w)

    def implausible(self):
        delay = self.params["delay"]
        if delay < 0:  # a sensor's samples cannot come before it measured them
            return (f"the sensor {-1e3 * delay:.3g} ms early on the others, which no sensor is: what the residual "
                    f"carries is the delay between it and a neighbour, a neighbour late")
        return (f"a delay of {delay:.3g} s, beyond the {MAX_DELAY} s a sensor lags: a sign of a sensor of "
                f"another take, or of a clock error" if delay > MAX_DELAY else "")

    def summary(self):
        return f"the {self.target} sensor is late on the others by {1e3 * self.params['delay']:.1f} ms"


def usable_links(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor,
                 target: str | None = None) -> tuple[list[int], torch.Tensor, torch.Tensor]:
    """The links of subject b with 8 valid sample times or more in train and in test (only `target`'s if
    given), and where each is valid in them: (usable, tr [N,T], te [N,T])."""
    k, ok = analysis.sample, analysis.valid[:, b]  # [T,L]
    usable = [i for i, name in enumerate(analysis.links) if target in (None, name)
              and int((ok[:, i] & train)[k].sum()) >= 8 and int((ok[:, i] & test)[k].sum()) >= 8]
    return usable, (ok[:, usable] & train[:, None]).T, (ok[:, usable] & test[:, None]).T


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, target: str | None = None,
        kinds: Collection[str] = KINDS) -> list[Effect]:
    """Misalignment and sensor-delay candidates (those of `kinds`) for every link of subject b; those
    the data cannot identify without a fit (their notes say why). target: only that link's
    candidates. Each kind is fitted on its own: one asked alone (a refit) is the same as among all.
    (A heading drift, the third effect of where a sensor measures: drift.py.)"""
    k = analysis.sample
    usable, tr, te = usable_links(analysis, b, train, test, target)
    if not usable:
        return []
    R_hat = analysis.R_hat[k, b][:, usable].transpose(0, 1)  # [N,S,3,3]
    w_hat = analysis.w_hat[k, b][:, usable].transpose(0, 1)  # [N,S,3]
    none = [None] * len(usable)
    misalignments = [_held_or_free(*fits) for fits in zip(fit_linear(analysis, b, usable, R_hat, tr, te), fit_projected(
        analysis, b, project_held(analysis, b, usable, R_hat), R_hat.transpose(-1, -2) @ R_hat, tr, te))] \
        if "misalignment" in kinds else none
    one_clock = bool(analysis.clocks[b]) if analysis.clocks else False
    delays = fit_linear(analysis, b, usable, -w_hat[..., None], tr, te) if "sensor_delay" in kinds and not one_clock \
        else none
    out: list[Effect] = []
    for i, mis, delay in zip(usable, misalignments, delays):  # per link: its kinds asked for
        name = analysis.links[i]
        if mis is not None:
            out.append(_misalignment(name, mis))
        if delay is not None:
            out.append(_sensor_delay(name, delay))
        elif one_clock and "sensor_delay" in kinds:
            out.append(SensorDelay("sensor_delay", name, notes=ONE_CLOCK))
    return out


def confounds(analysis: Analysis, b: int, link: int, others: list[int]) -> list[dict]:
    """The turns of link `link`'s sensor that the data tell from a turn of a neighbour's (`others`, links
    one joint away) only poorly: for each neighbour, the misalignments of both fitted together (G = R_hat
    on each one's rows, projected by M, over every sample time), and each direction of the pair's normal
    matrix that carries less than IDENTIFIABLE of its largest eigenvalue while each sensor alone is
    identified along its part: there the two sensors' turns leave nearly the same residual (about a
    hinge's missing axis, a thigh's and a shank's frames turned the same way, since the knee cannot turn
    the shank against the thigh about it: the data see their difference). Returns dicts of neighbour
    (its index), direction and neighbour_direction (unit, each sensor's frame) and share (the pair
    direction's eigenvalue against the largest)."""
    k = analysis.sample
    out = []
    for n in others:
        R_hat = analysis.R_hat[k, b][:, [link, n]].transpose(0, 1)  # [2,S,3,3]
        MG = project_blocks(analysis, b, [link, n], R_hat)  # [2,S,R,3]
        X = torch.cat((MG[0], MG[1]), dim=-1)  # [S,R,6]
        N = torch.einsum("srk,srl->kl", X, X)
        alone = [torch.linalg.eigvalsh(N[s_, s_]) for s_ in (slice(0, 3), slice(3, 6))]
        eigval, eigvec = torch.linalg.eigh(N)
        top = float(eigval[-1])
        for value, v in zip(eigval.tolist(), eigvec.T):
            a, c = v[:3], v[3:]
            if not (0.0 < value < IDENTIFIABLE * top) or min(float(a.norm()), float(c.norm())) < 0.3:
                continue
            # each part alone is seen (the sensor alone identified along it): the pair is what hides it
            seen = all(float(p @ (N[s_, s_] @ p)) / float(p @ p) > IDENTIFIABLE * float(e[-1])
                       for p, s_, e in ((a, slice(0, 3), alone[0]), (c, slice(3, 6), alone[1])))
            if seen:
                out.append(dict(neighbour=n, direction=(a / a.norm()).tolist(), neighbour_direction=(c / c.norm()).tolist(),
                                share=value / top))
    return out


def _misalignment(name: str, mis: LinearFit) -> Effect:
    if not mis.identified.shape[1]:
        return Misalignment("misalignment", name, notes=UNOBSERVABLE)
    return Misalignment("misalignment", name, dict(rotation_vector=mis.theta.tolist(), identified=mis.identified.T.tolist()),
                        dict(rotation_vector=mis.cov.diagonal().clamp(min=0).sqrt().tolist()),
                        mis.identified.shape[1], mis.fit, _unidentified(mis, 3))


def _sensor_delay(name: str, delay: LinearFit) -> Effect:
    if not delay.identified.shape[1]:
        return SensorDelay("sensor_delay", name, notes=UNOBSERVABLE)
    return SensorDelay("sensor_delay", name, dict(delay=float(delay.theta[0])),
                       dict(delay=float(delay.cov[0, 0].clamp(min=0).sqrt())), 1, delay.fit)

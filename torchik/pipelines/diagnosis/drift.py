"""Heading drift: a sensor's heading turning about the world vertical, with or without its gyro.

Two kinds, from the sensor's physics (HeadingDrift says which filters make which): the heading
reference moved under an unbiased gyro (the gyro disagrees with its own orientations by
e = -rate z), or a bias about the vertical that a filter without heading reference integrates (the
gyro stream carries it too, e = 0, and only the orientations' drift against the other sensors, as
the tracker follows the velocity targets that carry it, shows it: project_carried). Fitted with
placement.py's linear fits; `fit_drifts` gives both kinds per link and `heading_drift` the candidate.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from .analysis import Analysis
from .effect import ABOVE_NOISE, Effect, lowpass_blocks, replace, rotation_about
from .integral import agreement, vertical_turn
from .placement import (
    DRIFT_FLOOR,
    MAX_DRIFT,
    MISALIGNMENT_FLOOR,
    UNOBSERVABLE,
    LinearFit,
    fit_linear,
    fit_projected,
    usable_links,
)


def project_carried(analysis: Analysis, b: int, links: list[int], rate: torch.Tensor,
                    weight: torch.Tensor | None = None) -> torch.Tensor:
    """The residual [N,S,R,1] that a turn at a unit rate about `rate` [3] (world) on links[n] leaves when
    the link's velocity target carries it too (a drift its gyro shares, or any drift of a derived
    angular velocity): the tracker then follows the turn where the joints can, and the residual is
    not the projection of the turn, M(t) (t - t0) rate (that is when only the orientation target turns,
    and the tracker corrects the part the joints follow), but the part of its rate the joints could not
    follow at each time, accumulated, e(t) = integral of M(s) rate ds, kept in M(t)'s range:

        d e / d t = M rate - K P e,   P = I - M   ->   e(t) = M(t) sum_{s <= t} M(s) rate ds

    (the residual's part the joints follow decays at the tracker's gain K, fast against the walk). The
    two are equal where M is constant; over a walk, whose trunk turns, they are not. weight [S,N]: the
    turn's rate at each sample time, per candidate (default 1)."""
    M = analysis.projector(b)  # [S,R,R]
    time = analysis.time[analysis.sample]
    columns = M[:, :, 3:].unflatten(-1, (-1, 3)) @ rate.to(M.dtype)  # [S,R,L]: M of each link's turn
    columns = columns[..., links]
    if weight is not None:
        columns = columns * weight[:, None, :].to(columns.dtype)
    step = torch.diff(time, prepend=time[:1])[:, None, None]
    mean = 0.5 * (columns + torch.cat((columns[:1], columns[:-1])))  # trapezoid between sample times
    carried = torch.cumsum(mean * step, dim=0)  # [S,R,N]
    return (M @ carried).permute(2, 0, 1)[..., None]


@dataclass
class HeadingDrift(Effect):
    """A sensor's heading drifting about the world vertical at params['rate'] rad/s from the start
    params['t0']: its orientations turned by Rz(rate (t - t0)), and its world-frame gyro with them.

    What the sensor physics gives, in two kinds (params['gyro_shares']):

    - the gyro does not share it (False): the heading reference moved, not the gyro. A filter that
      corrects heading with a magnetometer follows a disturbed field: Xsens' MTi manual says that under
      a magnetic disturbance lasting more than 10 to 30 s the heading "slowly converges to a new solution
      using the 'new' local magnetic north", with no effect on inclination. The gyro, unbiased, is put
      in the world frame by the drifting orientation: w_m = Rz w, and it disagrees with the rate of its
      own orientations by e = -rate z.
    - the gyro shares it (True): a bias about the vertical that the filter cannot see. Accelerometers
      give a filter the gyro's bias about the two horizontal axes (gravity), and only a magnetometer in a
      homogeneous field gives it the vertical one (the MTi manual, "Internal Sensor Bias Estimation");
      without it (a VRU profile, an IMU-only fusion, OpenSense's input when the vendor's heading is
      free) the heading integrates the bias, and the gyro stream, which carries it, turns with the
      orientations: w_m = Rz w + rate z, e = 0. Only the orientations' drift against the other sensors
      shows it, and the velocity the tracker cannot follow.

    A bias about the sensor's vertical at rest (the part its filter could not see before the recording)
    turns the heading at rate cos(tilt) as the sensor tilts away from it: params['tilt'] (True, the
    shared kind) weighs the rate by z^T R_m(t) R_m(t0)^T z, the sensor's vertical at the start against its
    vertical now (the_turn); on an upright trunk it is 1, on a swinging shank it varies with the swing.
    Where the angular velocity is the orientations' derivative (no gyro), it shares whatever the
    orientations do (True), at a constant rate: so do the quaternion tables OpenSense reads, whose IMU
    inverse kinematics fits the model to the vendor filter's orientations frame by frame (a weighted least
    squares of their errors, OpenSim's "How IMU Inverse Kinematics Works") with no gyro and no model of
    drift: its IMU Placer aligns the base sensor's heading once, on the calibration frame, and a sensor's
    heading drifting after it goes into the joint angles."""

    additive = ("rate",)
    floor, unit = DRIFT_FLOOR, "deg/s"

    def size(self, dt):
        return float(np.degrees(abs(self.params["rate"])))

    def relevance_floor(self, dt):
        span = self.params.get("t1", math.inf) - self.params.get("t0", 0.0)
        return max(self.floor, MISALIGNMENT_FLOOR / span if span > 0 else math.inf)

    def apply(self, recording, sign):
        i = recording.links.index(self.target)
        rate = self.params["rate"]
        weight = tilt_weight(recording.orientation[:, i], recording.time, self.params["t0"]) \
            if self.params.get("tilt") else np.ones(len(recording.time))
        Rz = rotation_about([0.0, 0.0, 1.0], sign * rate * the_turn(weight, recording.time, self.params["t0"]))
        R, w = recording.orientation.copy(), recording.angular_velocity.copy()
        R[:, i] = Rz @ R[:, i]
        w[:, i] = (Rz @ w[:, i, :, None])[..., 0]
        if self.params.get("gyro_shares", False):
            w[:, i, 2] += sign * rate * weight
        return replace(recording, orientation=R, angular_velocity=w)

    def implausible(self):
        rate = np.degrees(abs(self.params["rate"]))
        return (f"a drift of {rate:.3g} deg/s, beyond the {MAX_DRIFT:g} deg/s of an inertial sensor: a sign of a "
                f"segment's offset changing (skin, a slipping strap) or of a mislabelled marker" if rate > MAX_DRIFT else "")

    def angle_rms(self) -> float:
        """The rms (rad) of the turn it makes over the recording, rate (t - t0) from t0 to t1."""
        return abs(self.params["rate"]) * (self.params.get("t1", math.inf) - self.params["t0"]) / math.sqrt(3.0)

    def significant(self, threshold: float, noise_rms: float) -> str:
        """Effect.significant, and a turn larger than the noise (ABOVE_NOISE times its rms) or shown by
        the sensor's own gyro: a drift of a tenth of a degree a second beside a true drift of its
        neighbour (the common part of a chain's headings, which only the gyros see) turns its sensor
        by about a degree over a recording, which the orientations cannot tell from their noise."""
        why = super().significant(threshold, noise_rms)
        own = self.params.get("own_gyro_score", 0.0)
        if why or self.angle_rms() > ABOVE_NOISE * noise_rms or own > threshold:
            return why
        return (f"the turn it makes, {math.degrees(self.angle_rms()):.2f} deg rms over the recording, is within "
                f"{ABOVE_NOISE:g} times the noise's {math.degrees(noise_rms):.2f} deg, and its own gyro does not "
                f"show it (score {own:.1f})")

    def summary(self):
        how = (", its gyro drifting with it (a bias about the vertical the filter integrates)"
               if self.params.get("gyro_shares") and not self.params.get("derived")
               else ", its gyro not (the heading reference moved: a magnetic disturbance)"
               if not self.params.get("gyro_shares") else "")
        return f"heading of the {self.target} sensor drifting by {np.degrees(self.params['rate']):+.3f} deg/s{how}"


def tilt_weight(R: np.ndarray, time: np.ndarray, t0: float) -> np.ndarray:
    """[T] z^T R(t) R(t0)^T z: how much of a bias along a sensor's vertical at t0 (R [T,3,3], sensor to
    world) lies along the vertical at t, the share of it a heading-free filter integrates into the
    heading then (HeadingDrift). At the first valid sample at or after t0; NaN rotations weigh 0."""
    ok = np.isfinite(R).all((-1, -2))
    start = int(np.argmax(ok & (time >= t0))) if (ok & (time >= t0)).any() else 0
    up = R[start, 2, :]  # the world's vertical in the sensor's axes then
    return np.where(ok, np.nan_to_num(R[:, 2, :]) @ up, 0.0)


def the_turn(weight: np.ndarray, time: np.ndarray, t0: float) -> np.ndarray:
    """[T] the integral of weight [T] from t0 (trapezoid; 0 before t0): a drift's turn at unit rate."""
    mean = 0.5 * (weight[1:] + weight[:-1]) * np.diff(time) * (time[1:] > t0)
    return np.concatenate(([0.0], np.cumsum(mean)))


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, derived: torch.Tensor | None = None,
        target: str | None = None, like: Effect | None = None) -> list[Effect]:
    """Heading-drift candidates for every link of subject b (only `target`'s if given); those the data
    cannot identify come without a fit. derived [L]: links whose angular velocity is computed from the
    orientations (default: analysis.derived), whose drift is fitted on the orientations alone. like: a
    drift whose kind a refit keeps (its gyro sharing it or not)."""
    derived = analysis.derived[b] if derived is None else derived
    usable, tr, te = usable_links(analysis, b, train, test, target)
    if not usable:
        return []
    ok, t0 = analysis.valid[:, b], float(analysis.time[0])
    shares = like.params.get("gyro_shares") if like is not None and like.kind == "heading_drift" else None
    return [heading_drift(analysis, b, i, head, bool(derived[i]), ok[:, i], t0, shares)
            for i, head in zip(usable, fit_drifts(analysis, b, usable, tr, te, derived, train, test))]


def heading_drift(analysis: Analysis, b: int, i: int, head: tuple[LinearFit | None, LinearFit], derived: bool,
                   ok: torch.Tensor, t0: float, shares: bool | None = None) -> Effect:
    """Link i's drift from its fits (with its gyro's e_z, None without a gyro; on the orientations alone);
    ok [T]: where its targets are valid. The two kinds of HeadingDrift differ in what the gyro shows
    (turned with an unbiased gyro, e = -rate z; shared, e = 0) and so in how the tracker follows them
    (project_carried): each is fitted with its own rate, the first on the orientations and e_z with
    what the integral of e says of it (integral.agreement: 2 log of the likelihood ratio of e = -rate z
    against nothing in e), the second on the orientations alone (e predicts nothing), and the one of
    the larger score is the candidate (or the kind `shares` says: a refit keeps the kind the held-out
    score chose). Both have one parameter."""
    name, time = analysis.links[i], analysis.time
    joint, alone = head
    seen = bool(alone.identified.shape[1])  # the orientations show it (the joints do not follow it all)
    if not seen and (joint is None or not joint.identified.shape[1]):
        return HeadingDrift("heading_drift", name, notes=UNOBSERVABLE)
    params: dict = dict(rate=float(alone.theta[0]), t0=t0, t1=float(time[-1]), gyro_shares=True, tilt=not derived)
    fit_d, sd = alone.fit, float(alone.cov[0, 0].clamp(min=0).sqrt())
    if derived or joint is None:
        params["derived"] = True
        return HeadingDrift("heading_drift", name, params, dict(rate=sd), 1, fit_d)
    # (each gyro's own noise model, not the suit's shared walk a bias is judged with: with that, 15007's
    # thigh drift lost its own gyro's word to the shank's, 66 of 70 named)
    # the gyro does not share it: its e_z joins the fit and its integral's word the score. The low-passed
    # e_z of the fit barely tells a drift of a link's own sensor from its neighbour's where a ball joint
    # takes up the turn between them and only the other side's joint shows it
    own = agreement(analysis.e[:, b, i], analysis.R_m[:, b, i], vertical_turn(time), ok, time, joint.theta[:1])
    params["own_gyro_score"] = own
    unaware = not seen or joint.fit.score + own > alone.fit.score  # the likelier of the two, each its rate's best
    if (not shares if shares is not None and seen else unaware):
        params.update(rate=float(joint.theta[0]), gyro_shares=False, tilt=False)
        fit_d = dataclasses.replace(joint.fit, score=joint.fit.score + own)
        sd = float(joint.cov[0, 0].clamp(min=0).sqrt())
    return HeadingDrift("heading_drift", name, params, dict(rate=sd), 1, fit_d)


def fit_drifts(analysis: Analysis, b: int, usable: list[int], tr: torch.Tensor, te: torch.Tensor,
           derived: torch.Tensor, train: torch.Tensor, test: torch.Tensor) -> list[tuple[LinearFit | None, LinearFit]]:
    """Heading-drift fits of the links `usable`, per link (joint, alone): the drift its gyro shares, on
    the orientation channel alone (project_carried: the tracker follows the velocity targets that
    carry it, and the residual is what their rate leaves, integrated), and, where the link has a gyro,
    the drift its gyro does not share, G = (t - t0) z, with its disagreement with the orientations
    e_z = -rate fitted together (e_z low-passed within the blocks of train and test; None without a
    gyro)."""
    k, time = analysis.sample, analysis.time
    z = torch.tensor([0.0, 0.0, 1.0], dtype=time.dtype)
    drift = ((time[k] - time[0])[:, None] * z)[..., None]  # [S,3,1]
    e_z = lowpass_blocks(analysis.e[:, b, :, 2], time, min(5.0, 0.25 / float(torch.diff(time).median())), train, test)
    gyro = [n for n, i in enumerate(usable) if not bool(derived[i])]
    extra = []
    for n in gyro:
        y_tr, y_te = e_z[tr[n], usable[n]], e_z[te[n], usable[n]]
        extra.append((torch.tensor([[float(tr[n].sum())]], dtype=time.dtype), -y_tr.sum()[None],
                      max(float(y_tr.var(unbiased=False)), 1e-12), y_te[:, None],  # noise about the constant fitted
                      lambda theta, m=len(y_te): -theta[0].expand(m)[:, None]))  # noqa: B008  (m bound per gyro)
    R = analysis.R_m[:, b][:, usable].numpy()  # [T,N,3,3]
    t = time.numpy()
    weight = torch.from_numpy(np.stack([tilt_weight(R[:, n], t, t[0]) if not bool(derived[i]) else np.ones(len(t))
                                        for n, i in enumerate(usable)], axis=-1))  # [T,N]
    turn = torch.from_numpy(np.stack([the_turn(weight[:, n].numpy(), t, t[0]) for n in range(len(usable))], -1))
    G = (turn[k].T[..., None] * z)[..., None]  # [N,S,3,1]
    alone = fit_projected(analysis, b, project_carried(analysis, b, usable, z, weight[k]), G.transpose(-1, -2) @ G,
                          tr, te)
    joint: dict[int, LinearFit] = {}
    if gyro:
        found = fit_linear(analysis, b, [usable[n] for n in gyro], drift.expand(len(gyro), -1, -1, -1), tr[gyro],
                           te[gyro], extra)
        joint.update(zip(gyro, found))
    return [(joint.get(n), alone[n]) for n in range(len(usable))]

"""Residual analysis of tracked recordings: what the model did not explain, where and when.

For a batch of B recordings of the same length tracked with one model (links L, joints n):

- r [T,B,L,3]: orientation residual sk(R_m R_hat^T)^vee, world frame (the tracker's r_o; |r| is
  sin of the angle), and r_link = R_hat^T r, the same in the estimated link frame;
- u [T,B,L,3]: velocity residual w_m - w_hat (world), w_hat = J nu of the estimate;
- e [T,B,L,3]: the disagreement of a sensor's two streams, its gyro against the rate of its own
  orientations: S(w_m) - w_fd(R_m), S the rate that a central difference of orientations computes
  (central_rate: the Simpson average (1,4,1)/6 and a coning term), so that e is O(dt^4) on
  consistent streams. It does not depend on the
  model (it is u - dr/dt to first order) and carries the gyro's own effects;
- position: r_p = p_m - p_hat [T,B,3] of the base link, and e_p = S(v_m) - dp_m/dt [T,B,3];
- joint positions s [T,B,n] and active-limit flags [T,B,n];
- at up to `max_samples` sample times: the task Jacobian J [S,B,R,6+n] (R = 3 position rows of
  the base, then 3 orientation rows per link; the rows of a target missing at that time zero, as
  the tracker drops it) and A = (J^T J + lambda I)^-1. With them M = I - J A J^T projects a target
  inconsistency delta onto the residual it leaves, r = M delta (the steady state of the tracker's
  least squares): directions of delta that the joints can follow leave none and cannot be seen.
  Effects are fitted against M (placement.py, joints.py), on the rows whose targets are present.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ...io.recording import Recording, angular_velocity_from_orientations
from ...method import so3
from ...method.kinematics import KinematicModel
from ...method.sequence import nominal_steps
from ...method.settings import TrackerSettings
from ...method.state import TargetSequence, Trajectory
from ...method.tracker import DynamicalIK
from ..evaluation import link_motion
from . import chunks, streams
from .series import central_difference, central_rate, simpson

DEFAULT_GAIN = TrackerSettings.orientation_gain  # the tracker's K (1/s), from its one source
NO_LIMIT = 19.9  # rad: a range this wide is no limit (the URDFs write +-10 rad for none)
LIMIT_TOLERANCE = 0.01  # rad: a joint this close to a finite limit is at it


@dataclass
class Analysis:
    """Residuals of B tracked recordings (module docstring). Measured: R_m [T,B,L,3,3], w_m
    [T,B,L,3], p_m, v_m [T,B,3]; estimated: R_hat, w_hat, p_hat; residuals r, r_link, u, e, r_p,
    e_p; valid [T,B,L] (both streams finite); derived [B,L] (the angular velocity is a derivative
    of the orientations, not a gyro: streams.py); velocity_derived [B] (the base velocity is the
    central difference of its positions); s, active [T,B,n]; sample [S] time indices of J
    [S,B,R,6+n] and A [S,B,6+n,6+n]; rows [S,B,R] (the row's target is present); joint_axes
    [S,B,n,3] (world)."""

    model: KinematicModel
    links: tuple[str, ...]
    time: torch.Tensor
    R_m: torch.Tensor
    w_m: torch.Tensor
    p_m: torch.Tensor
    v_m: torch.Tensor
    R_hat: torch.Tensor
    w_hat: torch.Tensor
    p_hat: torch.Tensor
    r: torch.Tensor
    r_link: torch.Tensor
    u: torch.Tensor
    e: torch.Tensor
    r_p: torch.Tensor
    e_p: torch.Tensor
    valid: torch.Tensor
    derived: torch.Tensor
    velocity_derived: torch.Tensor
    s: torch.Tensor
    active: torch.Tensor
    sample: torch.Tensor
    J: torch.Tensor
    A: torch.Tensor
    rows: torch.Tensor
    joint_axes: torch.Tensor
    trajectory: Trajectory = field(repr=False)
    poses: tuple[str | None, ...] = ()  # per subject: the reference pose a map calibrated it on (reference_pose)
    clocks: tuple[bool, ...] = ()  # per subject: one clock samples every segment (streams.shared_clock)
    _projector: tuple | None = field(default=None, init=False, repr=False, compare=False)  # (b, {at_limits: M})

    @property
    def batch(self) -> int:
        return self.R_m.shape[1]

    def orientation_rows(self, link: int) -> slice:
        """The rows of link `link`'s orientation in J (after the base's 3 position rows)."""
        return slice(3 + 3 * link, 6 + 3 * link)

    def stacked_residual(self, b: int | None = None) -> torch.Tensor:
        """[S,B,R] the residual at the sample times, rows as J's (position, then orientations);
        [S,R] that of subject b."""
        k = self.sample
        if b is None:
            r = torch.cat((self.r_p[k], self.r[k].flatten(-2)), dim=-1)
            return torch.where(self.rows, r, 0.0)
        r = torch.cat((self.r_p[k, b], self.r[k, b].flatten(-2)), dim=-1)
        return torch.where(self.rows[:, b], r, 0.0)

    def projector(self, b: int, at_limits: bool = False) -> torch.Tensor:
        """M = I - J A J^T of subject b [S,R,R], zero on the rows of missing targets (M X is
        project(b, X)): the candidates' G are a few columns each, and M G a few of M's columns.
        at_limits: J without the columns of the joints at a limit at each sample (active): the tracker
        cannot move such a joint further, so an inconsistency that pushes it there (a sensor turned
        about the joint's axis until the joint reaches its limit) leaves its residual, which a free
        joint would seem to follow. Kept for the last subject asked, whose candidates are fitted one
        after the other."""
        if self._projector is None or self._projector[0] != b:
            self._projector = (b, {})
        cache = self._projector[1]
        if at_limits not in cache:
            J, A = self.J[:, b], self.A[:, b]
            if at_limits:
                active = self.active[self.sample, b]  # [S,n]
                held = active.any(-1)  # J and A change only at the samples with a joint at a limit: a few, mostly
                J, A = J.clone(), A.clone()
                J[held], A[held] = self.without(b, active[held], held)
            M = torch.eye(J.shape[-2], dtype=J.dtype) - J @ (A @ J.transpose(-1, -2))
            cache[at_limits] = M * self.rows[:, b, :, None].to(J.dtype)
        return cache[at_limits]

    def without(self, b: int, held: torch.Tensor, samples: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Subject b's J at `samples` (a mask or index of the S sample times, P of them) without the
        columns of the joints `held` [P,n] (those the tracker cannot move: at a limit), and its A:
        ([P,R,6+n], [P,6+n,6+n]), for project(b, X, J, A, samples). Computed only where asked: a joint
        is held at a few of the samples, mostly, and elsewhere the analysis' own J and A hold."""
        free = torch.cat((torch.ones(len(held), 6, dtype=torch.bool), ~held), -1)  # [P,6+n]
        J = self.J[samples, b] * free[:, None, :].to(self.J.dtype)
        return J, inverse_normal(J)

    def project(self, b: int, X: torch.Tensor, J: torch.Tensor | None = None, A: torch.Tensor | None = None,
                samples: torch.Tensor | None = None) -> torch.Tensor:
        """M X = X - J A J^T X for subject b, X [...,S,R,k] (rows as J's) -> the same, zero on the
        rows of missing targets. J [S,R,C], A [S,C,C]: others than the analysis' (joints.py);
        samples: a mask or index of the sample times that X, J and A hold (default all S)."""
        J = self.J[:, b] if J is None else J
        A = self.A[:, b] if A is None else A
        rows = self.rows[:, b] if samples is None else self.rows[samples, b]
        # the candidates' columns side by side, [S,R,N k]: one product per sample time, not per candidate
        (S, R, k), lead = X.shape[-3:], X.shape[:-3]
        Y = X.reshape(-1, S, R, k).permute(1, 2, 0, 3).reshape(S, R, -1)
        Y = (Y - J @ (A @ (J.transpose(-1, -2) @ Y))) * rows[..., None].to(X.dtype)
        return Y.reshape(S, R, -1, k).permute(2, 0, 1, 3).reshape(*lead, S, R, k)


def sequence_of(recordings: Sequence[Recording], links, dtype=torch.float64) -> TargetSequence:
    """The tracker's targets for B recordings of the same length [T,B,...]: orientations and gyros of
    `links`, the base link's position and velocity."""
    T = len(recordings[0].time)
    for rec in recordings:
        if len(rec.time) != T:
            raise ValueError("recordings tracked as one batch must have the same length")
    idx = [[rec.links.index(name) for name in links] for rec in recordings]
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    R = torch.stack([t(rec.orientation[:, i]) for rec, i in zip(recordings, idx)], dim=1)
    w = torch.stack([t(rec.angular_velocity[:, i]) for rec, i in zip(recordings, idx)], dim=1)
    p = torch.stack([t(rec.base_position) for rec in recordings], dim=1)[:, :, None]
    v = torch.stack([t(rec.base_linear_velocity) for rec in recordings], dim=1)[:, :, None]
    return TargetSequence(t(recordings[0].time), p, v, R, w)


def track(model: KinematicModel, recordings: Sequence[Recording], links, gain: float = DEFAULT_GAIN,
          progress: bool = False, settle: float = 0.5, chunking: chunks.Chunking | None = None) -> Trajectory:
    """Track B recordings as one batch, each from a state at rest in its first frame's posture: the
    tracker run for `settle` seconds on the first targets held still. Started from the zero posture
    instead, a short recording would be mostly the transient. A uniformly sampled recording is
    tracked in overlapping chunks as one batch (chunks.py) whose hand-overs agree within
    chunks.HANDOVER, and in one piece where they do not (which turns `chunking` off) or `chunking`
    is off. The batched backend solves every run of more than one subject or chunk (the chunks give
    the batched run in one piece's states to about HANDOVER); one subject in one piece uses PIQP
    ("auto"), whose solutions differ from it by the solvers' tolerance (1e-7 on the joints)."""
    sequence = sequence_of(recordings, links, model.dtype)
    dt = float(np.median(np.diff(recordings[0].time))) if len(recordings[0].time) > 1 else 0.01
    split = chunks.plan(len(sequence), len(recordings), dt, gain, bool(nominal_steps(sequence.time, dt).all()))
    if split is not None and (chunking is None or chunking.on):
        stitched = split.stitch(settled_run(model, links, split.batch(sequence), dt, gain, progress, settle),
                                sequence.time, gain)
        if stitched is not None:
            return stitched
        if chunking is not None:
            chunking.on = False
    return settled_run(model, links, sequence, dt, gain, progress, settle)


def settled_run(model: KinematicModel, links, sequence: TargetSequence, dt: float, gain: float, progress: bool,
                 settle: float) -> Trajectory:
    """`track`'s run of `sequence` [T,B,...] in one piece, after settling on its first targets."""
    tracker = DynamicalIK(model, links, position_gain=gain, orientation_gain=gain, dt=dt,
                          backend="batched" if sequence.rotation.shape[1] > 1 else "auto")
    return tracker.run(sequence, progress=progress, settle=settle)


def reference_pose(recording: Recording) -> str | None:
    """The pose ('tpose', 'npose') a map calibrated the recording's offsets on; None if none did."""
    calibration = (recording.meta.get("link_map") or {}).get("calibration") or {}
    return calibration.get("reference_pose")


def analyse(model: KinematicModel, recordings: Sequence[Recording], links, trajectory: Trajectory | None = None,
            gain: float = DEFAULT_GAIN, max_samples: int = 300, progress: bool = False,
            chunking: chunks.Chunking | None = None) -> Analysis:
    """Track (unless `trajectory` is given; `chunking` as `track`) and compute the residuals of
    module docstring."""
    links = tuple(links)
    if trajectory is None:
        trajectory = track(model, recordings, links, gain, progress, chunking=chunking)
    seq = sequence_of(recordings, links, model.dtype)
    time = seq.time
    R_hat, w_hat = link_motion(model, trajectory, links)
    R_m, w_m = seq.rotation, seq.angular_velocity
    valid, r = orientation_residual(R_m, w_m, R_hat)
    R_safe = torch.where(valid[..., None, None], R_m, R_hat)
    w_safe = torch.where(valid[..., None], w_m, w_hat)
    r_link = (R_hat.transpose(-1, -2) @ r[..., None]).squeeze(-1)
    T, B, L = R_safe.shape[:3]  # every subject's links at once: [T,B*L,3,3]
    w_fd = torch.from_numpy(angular_velocity_from_orientations(R_safe.reshape(T, B * L, 3, 3).numpy(),
                                                               time.numpy())).reshape(T, B, L, 3)
    e = central_rate(w_safe, time) - w_fd
    # a sample next to a missing one has no central difference
    near = valid & torch.cat((valid[:1], valid[:-1])) & torch.cat((valid[1:], valid[-1:]))
    valid = near & torch.isfinite(e).all(-1)
    e = torch.where(valid[..., None], e, 0.0)
    # an angular velocity computed from the orientations (C3D, BVH, a converted file) is no gyro: nothing
    # to find in it (streams.py tells it from the data, whatever the scheme that computed it)
    derived = streams.derived_rates(torch.where(valid[..., None, None], R_m, torch.nan), w_m, time) | torch.tensor(
        [[streams.declared_derived(r)] for r in recordings])
    p_m, v_m = seq.position[:, :, 0], seq.linear_velocity[:, :, 0]
    p_hat = trajectory.base_position
    dp = central_difference(p_m, time)
    e_p = simpson(v_m) - dp
    velocity_derived = streams.derived_velocity(p_m, v_m, time)
    s = trajectory.joint_positions
    lower, upper = model.lower.to(s), model.upper.to(s)
    finite = (upper - lower) < NO_LIMIT
    active = finite & ((s <= lower + LIMIT_TOLERANCE) | (s >= upper - LIMIT_TOLERANCE))

    T = len(time)
    sample = torch.arange(0, T, max(1, -(-T // max_samples)))
    J, axes = _task_jacobian(model, trajectory, links, sample)
    rows = torch.cat((torch.isfinite(p_m[sample]).all(-1, keepdim=True).expand(-1, -1, 3),
                      valid[sample].repeat_interleave(3, dim=-1)), dim=-1)  # [S,B,R]
    J = J * rows[..., None].to(J.dtype)
    A = inverse_normal(J)
    return Analysis(model, links, time, R_m, w_m, p_m, v_m, R_hat, w_hat, p_hat, r, r_link, w_m - w_hat, e,
                    p_m - p_hat, torch.nan_to_num(e_p), valid, derived, velocity_derived, s, active, sample, J, A, rows,
                    axes, trajectory, tuple(reference_pose(r) for r in recordings),
                    tuple(streams.shared_clock(r) for r in recordings))


def orientation_residual(R_m: torch.Tensor, w_m: torch.Tensor, R_hat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """valid [T,B,L] (both measured streams finite) and the residual r = sk(R_m R_hat^T)^vee [T,B,L,3]
    (world; |r| the sine of the angle; zero where not valid) of measured rotations R_m and angular
    velocities w_m against estimated rotations R_hat."""
    valid = torch.isfinite(R_m).flatten(-2).all(-1) & torch.isfinite(w_m).all(-1)
    return valid, so3.skew_vee(torch.where(valid[..., None, None], R_m, R_hat) @ R_hat.transpose(-1, -2))


def inverse_normal(J: torch.Tensor, damping: float = 1e-9) -> torch.Tensor:
    """(J^T J + damping I)^-1 for J [...,R,C] -> [...,C,C]."""
    return torch.linalg.inv(J.transpose(-1, -2) @ J + damping * torch.eye(J.shape[-1], dtype=J.dtype))


def _task_jacobian(model: KinematicModel, trajectory: Trajectory, links, sample: torch.Tensor):
    """J [S,B,3+3L,6+n] (base position rows, then each link's angular rows) and world joint axes
    [S,B,n,3] at the sample times."""
    B = trajectory.joint_positions.shape[1]
    pick = lambda x: x[sample].reshape(-1, *x.shape[2:])  # noqa: E731
    names = (model.base_link,) + tuple(links)
    with torch.inference_mode():
        kin = model(pick(trajectory.base_position), pick(trajectory.base_rotation), pick(trajectory.joint_positions),
                    names, jacobian=True, joint_axes=True)
        assert kin.jacobian is not None  # asked for
        J = torch.cat((kin.jacobian[:, 0, :3], kin.jacobian[:, 1:, 3:].flatten(1, 2)), dim=1)
    S, axes = len(sample), kin.joint_axes
    assert axes is not None  # asked for
    return J.reshape(S, B, *J.shape[1:]).clone(), axes.reshape(S, B, *axes.shape[1:]).clone()


# ------------------------------------------------------------------------------ structure
@dataclass
class NoiseFloor:
    """What a correct model leaves, estimated from the residual of subject b (after the transient):
    axis_rms (rad), the noise's rms along one axis, the median over the links of the rms along each
    link's dominant axis (the direction the joints do not follow, where the sensor's noise stays
    whole); link_power [L], each link's mean |r|^2; noise_power, their median: the power a link
    carries when nothing but noise is left (effects sit on a minority of the links); share, the
    fraction of the residual's power that the noise accounts for, sum_l min(P_l, noise_power) /
    sum_l P_l."""

    axis_rms: float
    link_power: np.ndarray
    noise_power: float
    share: float


def noise_floor(analysis: Analysis, b: int = 0, transient: float = 1.0) -> NoiseFloor:
    time = analysis.time
    keep = time >= time[0] + (transient if float(time[-1] - time[0]) > 3 * transient else 0.0)
    ok = analysis.valid[:, b] & keep[:, None]  # [T,L]
    r = torch.where(ok[..., None], analysis.r_link[:, b], 0.0)  # [T,L,3]
    n = ok.sum(0).clamp(min=1).to(r.dtype)  # [L]
    mean = r.sum(0) / n[:, None]
    centred = torch.where(ok[..., None], r - mean, 0.0)
    cov = torch.einsum("tli,tlj->lij", centred, centred) / n[:, None, None]
    dominant = torch.linalg.eigvalsh(cov)[:, -1].clamp(min=0.0)  # [L]
    power = r.square().sum((0, -1)) / n
    has = ok.any(0)
    if not bool(has.any()):
        return NoiseFloor(0.0, power.numpy(), 0.0, 1.0)
    axis_rms = float(dominant[has].median().sqrt())
    noise_power = float(power[has].median())
    share = float(power[has].clamp(max=noise_power).sum() / power[has].sum().clamp(min=1e-30))
    return NoiseFloor(axis_rms, power.numpy(), noise_power, share)


BANDS = ((0.0, 0.2), (0.2, 1.0), (1.0, 3.0), (3.0, 10.0), (10.0, float("inf")))  # Hz


def link_summary(analysis: Analysis, b: int = 0, transient: float = 1.0) -> list[dict]:
    """Per link of subject b: where the residual sits and what it follows. Keys: link, rms_deg (of
    the orientation residual's angle), mean_link_deg [3] (its mean in the link frame), trend_deg_s
    [3] (world-frame slope), dominant_axis (unit, link frame: the principal axis of r_link),
    dominant_share (of the variance), corr_omega, corr_alpha (|correlation| of r with the angular
    velocity and acceleration, world), corr_joint and joint (the largest |correlation| of a component
    of r with the angle of a joint above the link, and that joint), band_hz (the band holding most
    of r's power), gyro_rms (|e| rms, rad/s: the gyro against the orientations), velocity_rms (|u|
    rms, rad/s)."""
    time = analysis.time
    long_enough = float(time[-1] - time[0]) > 2 * transient
    keep = (time >= time[0] + transient) if long_enough else torch.ones_like(time, dtype=torch.bool)
    rows = []
    rate = 1.0 / float(torch.diff(time).median()) if len(time) > 1 else 1.0
    above = analysis.model.select(analysis.links).ancestor_mask.bool()  # [L,n]
    for i, name in enumerate(analysis.links):
        ok = keep & analysis.valid[:, b, i]
        if int(ok.sum()) < 4:
            rows.append(dict(link=name, samples=int(ok.sum())))
            continue
        r, rl, t = analysis.r[ok, b, i], analysis.r_link[ok, b, i], time[ok]
        w = analysis.w_hat[ok, b, i]
        alpha = central_difference(w, t)
        angle = torch.asin(r.norm(dim=-1).clamp(max=1.0))
        centred = rl - rl.mean(0)
        eigval, eigvec = torch.linalg.eigh(centred.T @ centred)
        tc = t - t.mean()
        trend = (tc[:, None] * r).sum(0) / tc.square().sum().clamp(min=1e-12)
        corr = lambda x, y: float(((x - x.mean(0)) * (y - y.mean(0))).sum() / (  # noqa: E731
            (x - x.mean(0)).norm() * (y - y.mean(0)).norm()).clamp(min=1e-12))
        s = analysis.s[ok, b][:, above[i]]  # [t,m] the angles of the joints above
        s, r0 = s - s.mean(0), r - r.mean(0)
        joint_corr = (s.T @ r0).abs() / (s.norm(dim=0)[:, None] * r0.norm(dim=0)).clamp(min=1e-12)  # [m,3]
        best = int(joint_corr.amax(-1).argmax()) if joint_corr.numel() else -1
        power = torch.fft.rfft(r - r.mean(0), dim=0).abs().square().sum(-1)
        freq = torch.fft.rfftfreq(r.shape[0], d=1.0 / rate)
        band_power = [float(power[(freq >= lo) & (freq < hi)].sum()) for lo, hi in BANDS]
        lo, hi = BANDS[int(np.argmax(band_power))]
        rows.append(dict(
            link=name, samples=int(ok.sum()), rms_deg=float(angle.square().mean().sqrt()) * 180 / np.pi,
            mean_link_deg=(rl.mean(0) * 180 / np.pi).tolist(), trend_deg_s=(trend * 180 / np.pi).tolist(),
            dominant_axis=eigvec[:, -1].tolist(), dominant_share=float(eigval[-1] / eigval.sum().clamp(min=1e-30)),
            corr_omega=abs(corr(r, w)), corr_alpha=abs(corr(r, alpha)), band_hz=[lo, hi],
            corr_joint=float(joint_corr.amax()) if best >= 0 else 0.0,
            joint=analysis.model.joint_names[int(torch.nonzero(above[i])[best])] if best >= 0 else "",
            gyro_rms=float(analysis.e[ok, b, i].square().sum(-1).mean().sqrt()),
            velocity_rms=float(analysis.u[ok, b, i].square().sum(-1).mean().sqrt())))
    return rows


def joint_summary(analysis: Analysis, b: int = 0) -> list[dict]:
    """Joints that sat at a finite limit: name, fraction of the time, and the side."""
    model, s, active = analysis.model, analysis.s[:, b], analysis.active[:, b]
    out = []
    for j in torch.nonzero(active.any(0)).flatten().tolist():
        at_upper = bool((s[active[:, j], j] > 0.5 * (model.lower[j] + model.upper[j])).float().mean() > 0.5)
        out.append(dict(joint=model.joint_names[j], fraction=float(active[:, j].double().mean()),
                        side="upper" if at_upper else "lower"))
    return out

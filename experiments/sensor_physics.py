"""Recordings made by simulating the sensors, to check the diagnosis (torchik/pipelines/diagnosis/).

The check is only worth something if the recordings do not share the diagnosis's equations, so
nothing here writes an effect's residual signature. The body moves (a walk, through pinocchio's
kinematics of the Human48 or Human66 URDF, not torchik's), and each effect comes from a sensor
doing what a real one does:

- an inertial sensor strapped on its segment at a true rotation C (a strap turned: C differs from
  the mounting the software assumes); its gyro measures the sensor-frame rate with a scale error,
  a bias and noise, integrated and dumped at the output rate; its accelerometer the specific force
  R_s^T (a - g) of its mounting point; its magnetometer the direction of a horizontal field (which
  a magnetic disturbance turns); a strapdown filter (Mahony's explicit complementary filter)
  estimates its orientation from them at 4x the output rate, correcting tilt with the
  accelerometer and, when it is a 9-axis filter, heading with the magnetometer;
- timing: a sensor whose clock is late is simulated at t - d; a rate stream late on its own
  orientations is the internal stream sampled at t - d;
- optical mode: a cluster of markers on each segment, the orientation fitted to their measured
  positions (Kabsch) against the cluster's nominal geometry, the angular velocity differentiated
  from the orientations as a user would; a cluster sitting turned on its segment gives the offset.

Two things a real suit does that a diagnosis should find negligible: its rate is integrated and
dumped over each output interval, so it is the rate of the interval's middle, half an output
sample (5 ms at 100 Hz) behind the orientation it is reported with; and its filter's orientation
is off by what the accelerometer's uncompensated share of the walking accelerations tilts it
(about 0.1 deg on the trunk, 1 deg on the feet). Filters start at the true orientation with no
bias estimate: they converged during a still period before the recording, and a bias is one that
appeared since (one the still period had estimated would be a smaller effect).

`generate(seed, family)` draws one recording of a family (FAMILIES) with its ground truth
(`Injected`). The motion depends on the seed only, the same for every family: recordings of one
seed differ only by their sensors (and, for missing_axis, by the one axis Human48 lacks).

Only `torchik.io.recording.Recording` (the container) and `torchik.method.models` (the Human48/66
URDF text when the published files are absent, TRACKED_LINKS) come from torchik; nothing from
torchik.pipelines. Run `python experiments/sensor_physics.py --family strap --seed 3` to time one.
"""

from __future__ import annotations

import math
import time as clock
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

REFERENCE_DIR = Path(__file__).resolve().parents[2] / "shared" / "reference-models"
GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2, world (z up)
DEG = math.pi / 180
FAMILIES = ("clean", "strap", "gyro_bias", "tilt_filter_bias", "vertical_bias", "magnetic_drift", "gyro_scale",
            "stream_delay", "sensor_delay", "missing_axis", "optical_clean", "cluster_offset")
# the diagnosis's effect kinds that name each family's effect
KINDS = {"strap": ("misalignment",), "gyro_bias": ("gyro_bias",), "tilt_filter_bias": ("heading_drift", "gyro_bias"),
         "vertical_bias": ("heading_drift", "gyro_bias"), "magnetic_drift": ("heading_drift",),
         "gyro_scale": ("gyro_scale",), "stream_delay": ("stream_delay",), "sensor_delay": ("sensor_delay",),
         "missing_axis": ("missing_dof",), "cluster_offset": ("misalignment",)}
# axes Human66 has and Human48 lacks that a body makes: knee ab/adduction, elbow carrying angle, head and lumbar twist
MISSING_AXES = ("jRightKnee_rotx", "jLeftKnee_rotx", "jRightElbow_rotx", "jLeftElbow_rotx", "jC1Head_rotz",
                "jL5S1_rotz")
# deg: the amplitude (half the range) each of them moves by in a walk: a knee's ab/adduction and an
# elbow's carrying angle by a few degrees (a range of 5-10 deg in gait), the head's and the lumbar
# spine's axial rotation by more
AXIS_AMPLITUDE = {"Knee": (2.5, 6.0), "Elbow": (2.5, 6.0), "Head": (5.0, 15.0), "L5S1": (3.0, 8.0)}
# segments that stay roughly upright in a walk (a bias along their vertical axis is a heading drift),
# in the groups Human48's joints tie together about the vertical (the lumbar joints and the head's have
# no vertical axis; T9T8 and T1C7 have one; the thighs turn freely at the hip and the knee): a drift
# that each sensor's gyro shares shows only against its group, so two in one group are seen as their
# difference and no data tell which of them turns. A recording draws at most one sensor of a group.
UPRIGHT_GROUPS = (("Pelvis", "L5", "L3", "T12"), ("T8",), ("Neck", "Head"))
UPRIGHT = tuple(x for group in UPRIGHT_GROUPS for x in group)
# frames of the centred moving average a user puts on the markers before differentiating orientations:
# 0.5-1 mm of noise on clusters of 4-10 cm makes 1 deg of orientation noise, 1.2 rad/s of angular
# velocity noise unsmoothed at 100 Hz and 0.35 rad/s with it (it takes 1.6 % off a 2 Hz motion)
OPTICAL_WINDOW = 5


# ------------------------------------------------------------------------------ rotations (numpy, batched)
def hat(v: np.ndarray) -> np.ndarray:
    """[...,3] -> [...,3,3] with hat(v) @ x = v x x."""
    K = np.zeros(v.shape + (3,))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for [...,3] (np.cross costs several times more on small arrays, inside the filter's loop)."""
    return np.stack((a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]), -1)


def expm(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors [...,3] -> rotations [...,3,3], cos(t) I + sinc(t) hat(v) + (1 - cos t)/t^2 v v^T
    (np.sinc is exact at 0, where the closed forms divide by zero)."""
    theta = np.sqrt((v * v).sum(-1))[..., None, None]
    a = np.sinc(theta / np.pi)
    b = 0.5 * np.sinc(theta / (2 * np.pi)) ** 2  # (1 - cos t) / t^2 = sinc(t/2)^2 / 2
    return np.cos(theta) * np.eye(3) + a * hat(v) + b * (v[..., :, None] * v[..., None, :])


def logm(R: np.ndarray) -> np.ndarray:
    """Rotations [...,3,3] -> rotation vectors [...,3] (angle in [0, pi])."""
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(cos)[..., None]
    axis2 = np.stack((R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]), -1)
    sin = np.sin(theta)
    small = theta < 1e-6
    v = axis2 / 2 * np.where(small, 1 + theta ** 2 / 6, theta / np.where(small, 1.0, sin))
    near_pi = theta[..., 0] > math.pi - 1e-3  # (R - R^T) vanishes there: the axis from the symmetric part
    if near_pi.any():
        c = cos[near_pi][:, None, None]
        nn = ((R[near_pi] + np.swapaxes(R[near_pi], -1, -2)) / 2 - c * np.eye(3)) / (1 - c)  # n n^T
        k = np.argmax(np.diagonal(nn, axis1=-2, axis2=-1), -1)
        axis = nn[np.arange(len(k)), :, k]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        axis *= np.where((axis * axis2[near_pi]).sum(-1, keepdims=True) < 0, -1.0, 1.0)  # the sign sin(t) n has
        v[near_pi] = axis * theta[near_pi]
    return v


def quaternion(R: np.ndarray) -> np.ndarray:
    """Rotations [...,3,3] -> unit quaternions [...,4] as (w, x, y, z), the branch with the largest
    component (Shepperd's method, accurate at every angle)."""
    m = R
    tr = np.trace(m, axis1=-2, axis2=-1)
    cands = np.stack((tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]), -1)
    k = np.argmax(cands, -1)
    q = np.empty(R.shape[:-2] + (4,))
    for branch in range(4):
        sel = k == branch
        if not sel.any():
            continue
        M = m[sel]
        if branch == 0:
            s = 2 * np.sqrt(1 + tr[sel])
            q[sel] = np.stack((s / 4, (M[:, 2, 1] - M[:, 1, 2]) / s, (M[:, 0, 2] - M[:, 2, 0]) / s,
                               (M[:, 1, 0] - M[:, 0, 1]) / s), -1)
        else:
            i = branch - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 2 * np.sqrt(1 + M[:, i, i] - M[:, j, j] - M[:, l, l])
            out = np.empty((len(M), 4))
            out[:, 0] = (M[:, l, j] - M[:, j, l]) / s
            out[:, 1 + i] = s / 4
            out[:, 1 + j] = (M[:, j, i] + M[:, i, j]) / s
            out[:, 1 + l] = (M[:, l, i] + M[:, i, l]) / s
            q[sel] = out
    return q


def yaw(R: np.ndarray) -> np.ndarray:
    """Heading (rad) of rotations [...,3,3] about the world vertical: the angle of their x axis' horizontal part."""
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def rate_from_orientations(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World angular velocity [T,...,3] from orientations [T,...,3,3] at times t [T], as a user would
    write it: quaternions made continuous in sign, np.gradient, omega = 2 vec(q_dot q*)."""
    q = quaternion(R)
    flip = np.cumprod(np.where((q[1:] * q[:-1]).sum(-1) < 0, -1.0, 1.0), axis=0)
    q[1:] *= flip[..., None]
    dq = np.gradient(q, t, axis=0, edge_order=2)
    w, v, dw, dv = q[..., :1], q[..., 1:], dq[..., :1], dq[..., 1:]
    return 2 * (w * dv - dw * v + np.cross(v, dv))


# ------------------------------------------------------------------------------ the model
def human_model(dof: int = 48, reference: Path | None = REFERENCE_DIR):
    """A pinocchio model (free-flyer base) of Human{dof}: the published URDF in `reference` when it is
    there, else the text of torchik.method.models.human_urdf(dof). Returns (model, where it came from)."""
    import pinocchio

    path = None if reference is None else Path(reference) / f"humanSubject01_{dof}dof.urdf"
    if path is not None and path.is_file():
        return pinocchio.buildModelFromUrdf(str(path), pinocchio.JointModelFreeFlyer()), str(path)
    from torchik.method.models import human_urdf

    return pinocchio.buildModelFromXML(human_urdf(dof), pinocchio.JointModelFreeFlyer()), f"human_urdf({dof})"


def joint_table(model) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The model's 1-dof joints (all but the free flyer): names, lower and upper limits [n] (rad)."""
    names = [model.names[j] for j in range(2, model.njoints)]
    idx = [model.joints[j].idx_q for j in range(2, model.njoints)]
    return names, model.lowerPositionLimit[idx].copy(), model.upperPositionLimit[idx].copy()


# ------------------------------------------------------------------------------ motion
@dataclass
class Sines:
    """Channels x_j(t) = centre_j + sum over the terms m of channel j of amplitude_m sin(omega_m t + phase_m).

    centre [n]; channel, amplitude, omega (rad/s), phase [m]."""

    centre: np.ndarray
    channel: np.ndarray
    amplitude: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x, dx/dt, d2x/dt2 at times t [N], each [N,n]: exact derivatives."""
        arg = np.asarray(t, dtype=float)[:, None] * self.omega + self.phase  # [N,m]
        onehot = np.zeros((len(self.channel), len(self.centre)))
        onehot[np.arange(len(self.channel)), self.channel] = 1.0
        s, c = self.amplitude * np.sin(arg), self.amplitude * np.cos(arg)
        return (self.centre + s @ onehot, (c * self.omega) @ onehot, -(s * self.omega ** 2) @ onehot)

    def add(self, channel: int, amplitude, omega, phase) -> "Sines":
        """Self with more terms on one channel."""
        amplitude, omega, phase = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (amplitude, omega, phase))
        return replace(self, channel=np.concatenate((self.channel, np.full(len(amplitude), channel))),
                       amplitude=np.concatenate((self.amplitude, amplitude)),
                       omega=np.concatenate((self.omega, omega)), phase=np.concatenate((self.phase, phase)))

    def within(self, lower: np.ndarray, upper: np.ndarray, span: tuple[float, float], margin: float = 0.03) -> "Sines":
        """Self scaled (about each channel's mean) and shifted so that every channel stays within
        [lower + margin, upper - margin] over the time span (checked on a 200 Hz grid)."""
        x = self(np.arange(span[0], span[1], 0.005))[0]
        lo, hi, mean = x.min(0), x.max(0), x.mean(0)
        room = (upper - lower) - 2 * margin
        scale = np.minimum(1.0, room / np.maximum(hi - lo, 1e-12))
        lo, hi = mean + scale * (lo - mean), mean + scale * (hi - mean)
        shift = np.maximum(lower + margin - lo, 0.0) - np.maximum(hi - (upper - margin), 0.0)
        return replace(self, centre=mean + scale * (self.centre - mean) + shift,
                       amplitude=self.amplitude * scale[self.channel])


def _bumps(base: float, *bumps: tuple[float, float, float]):
    """A periodic curve of the stride phase p (cycles): base + sum h exp(-((p - c) / w)^2 / 2), for (h, c, w)."""
    h, c, w = np.array(bumps).T

    def curve(p):
        d = (p[:, None] - c + 0.5) % 1.0 - 0.5  # the periodic distance to each bump's centre
        return base + (h * np.exp(-0.5 * (d / w) ** 2)).sum(1)
    return curve


# Normal gait, degrees over one stride from the right heel strike (flexion positive; ankle: dorsiflexion)
GAIT_CURVES = {
    "hip": lambda p: 8 + 20 * np.cos(2 * np.pi * (p - 0.9)) + 2 * np.cos(4 * np.pi * (p - 0.25)),
    "knee": _bumps(3.0, (15.0, 0.13, 0.06), (57.0, 0.71, 0.09)),  # loading response hump, then the swing's
    "ankle": _bumps(0.0, (-6.0, 0.06, 0.05), (10.0, 0.42, 0.10), (-18.0, 0.63, 0.06), (3.0, 0.85, 0.08)),
    "arm": lambda p: 5 + 20 * np.cos(2 * np.pi * (p - 0.4)),  # forward when the same side's leg is back
    "elbow": lambda p: 35 + 12 * np.cos(2 * np.pi * (p - 0.4)),  # more flexed when the arm is forward
}
# (joint of Human48, curve, sign of the joint against the curve, phase shift in strides)
GAIT_JOINTS = (("jRightHip_roty", "hip", -1, 0.0), ("jLeftHip_roty", "hip", -1, 0.5),
               ("jRightKnee_roty", "knee", 1, 0.0), ("jLeftKnee_roty", "knee", 1, 0.5),
               ("jRightAnkle_roty", "ankle", -1, 0.0), ("jLeftAnkle_roty", "ankle", -1, 0.5),
               ("jRightShoulder_rotz", "arm", 1, 0.0), ("jLeftShoulder_rotz", "arm", -1, 0.5),
               ("jRightElbow_rotz", "elbow", 1, 0.0), ("jLeftElbow_rotz", "elbow", -1, 0.5))
GAIT_NAMES = {name for name, *_ in GAIT_JOINTS}
ARMS_DOWN = {"jRightShoulder_rotx": 1.4, "jLeftShoulder_rotx": -1.4}  # rad from the T-pose: arms by the sides
HARMONICS = 5


def fourier(curve, harmonics: int = HARMONICS) -> tuple[float, np.ndarray, np.ndarray]:
    """A periodic curve of the phase (cycles) as mean + sum_k A_k sin(2 pi k p + phi_k), k = 1..harmonics:
    (mean, A [K], phi [K])."""
    p = np.arange(256) / 256
    c = np.fft.rfft(curve(p)) / 256
    k = np.arange(1, harmonics + 1)
    return float(c[0].real), 2 * np.abs(c[k]), np.angle(c[k]) + np.pi / 2


@dataclass
class Motion:
    """A walk: joint angles (joint_names, Sines in rad) and the base (pelvis) path.

    The base walks at `speed` (m/s) along a heading turning at `turn` (rad/s) from `heading0`, at
    `height` (m), with offsets in the walking frame: base channels forward, left, up (m), yaw,
    pitch, roll (rad; R = Rz(heading + yaw) Ry(pitch) Rx(roll))."""

    joint_names: tuple[str, ...]
    joints: Sines
    base: Sines
    speed: float
    turn: float
    heading0: float
    height: float
    stride_hz: float

    def with_axis(self, name: str, amplitude: float, frequency_hz: float, phase: float) -> "Motion":
        """Self with one more joint moving: amplitude (rad) sin(2 pi f t + phase)."""
        n = len(self.joint_names)
        joints = replace(self.joints, centre=np.append(self.joints.centre, 0.0))
        return replace(self, joint_names=self.joint_names + (name,),
                       joints=joints.add(n, amplitude, 2 * math.pi * frequency_hz, phase))

    def base_state(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """At times t [N]: position p [N,3], rotation R [N,3,3], velocity dp, angular velocity w,
        acceleration ddp, angular acceleration dw [N,3], all in the world frame, exact."""
        (f, l, u, y, th, ph), (df, dl, du, dy, dth, dph), (ddf, ddl, ddu, ddy, ddth, ddph) = (
            x.T for x in self.base(t))
        v, r, h0 = self.speed, self.turn, self.heading0
        h = h0 + r * t
        F = np.stack((np.cos(h), np.sin(h), 0 * h), -1)  # forward; its derivative is r L
        L = np.stack((-np.sin(h), np.cos(h), 0 * h), -1)  # left; its derivative is -r F
        ez = np.array([0.0, 0.0, 1.0])
        if abs(r) > 1e-9:  # the path of a constant turn: an arc
            path = v / r * np.stack((np.sin(h) - math.sin(h0), -(np.cos(h) - math.cos(h0)), 0 * h), -1)
        else:
            path = v * t[:, None] * F
        c = lambda x: x[:, None]  # noqa: E731
        p = path + c(f) * F + c(l) * L + c(self.height + u) * ez
        dp = c(v + df - l * r) * F + c(f * r + dl) * L + c(du) * ez
        ddp = c(ddf - 2 * dl * r - f * r * r) * F + c(v * r + 2 * df * r + ddl - l * r * r) * L + c(ddu) * ez
        R, w, dw = _zyx(h + y, th, ph, r + dy, dth, dph, ddy, ddth, ddph)
        return dict(p=p, R=R, dp=dp, w=w, ddp=ddp, dw=dw)


def _zyx(psi, theta, phi, dpsi, dtheta, dphi, ddpsi, ddtheta, ddphi):
    """R = Rz(psi) Ry(theta) Rx(phi) [N,3,3], its world angular velocity and acceleration [N,3]."""
    def axis_rot(a, i):
        c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
        m = {2: (c, -s, z, s, c, z, z, z, o), 1: (c, z, s, z, o, z, -s, z, c), 0: (o, z, z, z, c, -s, z, s, c)}[i]
        return np.stack(m, -1).reshape(*a.shape, 3, 3)

    Rz, Ry, Rx = axis_rot(psi, 2), axis_rot(theta, 1), axis_rot(phi, 0)
    ez = np.array([0.0, 0.0, 1.0])
    ey, ex = Rz[..., :, 1], (Rz @ Ry)[..., :, 0]  # the pitch and roll axes in the world
    c = lambda x: x[:, None]  # noqa: E731
    w_zy = c(dpsi) * ez + c(dtheta) * ey  # the angular velocity of Rz Ry
    w = w_zy + c(dphi) * ex
    dw = (c(ddpsi) * ez + c(ddtheta) * ey + c(dtheta) * np.cross(c(dpsi) * ez, ey)
          + c(ddphi) * ex + c(dphi) * np.cross(w_zy, ex))
    return Rz @ Ry @ Rx, w, dw


def walking_motion(rng: np.random.Generator, joint_names: list[str], lower: np.ndarray, upper: np.ndarray,
                   span: tuple[float, float]) -> Motion:
    """A random walk-like motion of a Human48-like body, within the joint limits over the time span (s).

    Stride 0.8-1.1 Hz; gait joints (hips, knees, ankles, arm swing, elbows) follow GAIT_CURVES as
    5-harmonic series, scaled 0.8-1.2 and shifted per seed; pelvis rotation, obliquity and tilt,
    trunk counter-rotation; every other joint two sinusoids of 0.1-1.2 Hz, 1-4 deg in all."""
    stride = rng.uniform(0.8, 1.1)
    omega, start = 2 * math.pi * stride, rng.uniform(0, 1)  # rad/s; stride phase at t = 0 (cycles)
    index = {name: j for j, name in enumerate(joint_names)}
    joints = Sines(np.zeros(len(joint_names)), np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros(0))
    joints.centre[[index[n] for n in ARMS_DOWN]] = list(ARMS_DOWN.values())
    joints = _gait_joints(joints, rng, index, omega, start)
    joints, base = _trunk_and_base(joints, rng, index, omega, start)
    for name, j in index.items():  # small independent motion on the rest: no axis degenerate
        if name in GAIT_NAMES:
            continue
        total, split = rng.uniform(1, 4) * DEG, rng.dirichlet((2.0, 2.0))
        joints.centre[j] += rng.uniform(-2, 2) * DEG
        joints = joints.add(j, total * split, 2 * math.pi * rng.uniform(0.1, 1.2, 2), rng.uniform(0, 2 * math.pi, 2))
    speed = float(np.clip(stride * rng.uniform(1.1, 1.4), 0.9, 1.5))  # stride length 1.1-1.4 m
    return Motion(tuple(joint_names), joints.within(lower, upper, span), base, speed,
                  turn=float(rng.choice([-1, 1]) * rng.uniform(2, 8) * DEG), heading0=float(rng.uniform(-math.pi, math.pi)),
                  height=0.93, stride_hz=float(stride))


def _gait_joints(joints: Sines, rng: np.random.Generator, index: dict, omega: float, start: float) -> Sines:
    """GAIT_CURVES on GAIT_JOINTS, randomised per seed (the two sides share a draw, half a stride apart)."""
    k = np.arange(1, HARMONICS + 1)
    for curve_name, curve in GAIT_CURVES.items():
        mean, A, phi = fourier(curve)
        mean += rng.uniform(-3, 3)
        A = A * rng.uniform(0.8, 1.2) * rng.uniform(0.9, 1.1, HARMONICS)
        phi = phi + rng.uniform(-0.1, 0.1, HARMONICS) + 2 * math.pi * k * rng.uniform(-0.02, 0.02)
        for name, which, sign, shift in GAIT_JOINTS:
            if which != curve_name:
                continue
            side = rng.uniform(0.95, 1.05)  # a little asymmetry
            joints.centre[index[name]] += sign * mean * DEG
            joints = joints.add(index[name], sign * side * A * DEG, k * omega, phi + 2 * math.pi * k * (start + shift))
    return joints


def _trunk_and_base(joints: Sines, rng: np.random.Generator, index: dict, omega: float, start: float):
    """Pelvis rotation, obliquity, tilt, sway, bob and surge (base channels), the thorax turning
    against the pelvis and the head against the thorax; a slow random wobble on each base channel."""
    def phase(cycles, k=1):  # of a sinusoid at k times the stride frequency, sin(2 pi k (p + cycles)), p the stride's phase
        return 2 * math.pi * k * (start + cycles)

    yaw_amp = rng.uniform(3, 6) * DEG  # the pelvis turns the leading leg's side forward
    base = Sines(np.array([0, 0, 0, 0, rng.uniform(2, 8) * DEG, 0]), np.zeros(0, int), np.zeros(0), np.zeros(0),
                 np.zeros(0))
    base = base.add(3, yaw_amp, omega, phase(0.25))  # yaw: peak at the right heel strike
    base = base.add(5, -rng.uniform(2, 5) * DEG, omega, phase(0.0))  # roll: the swing side drops
    base = base.add(4, rng.uniform(1, 2) * DEG, 2 * omega, phase(rng.uniform(0, 1), 2))  # pitch: tilt at 2f
    base = base.add(1, -rng.uniform(0.015, 0.03), omega, phase(0.0))  # lateral sway over the stance leg
    base = base.add(2, rng.uniform(0.015, 0.025), 2 * omega, phase(-0.125, 2))  # bob: highest at mid stance
    base = base.add(0, rng.uniform(0.005, 0.015), 2 * omega, phase(rng.uniform(0, 1), 2))  # surge
    for ch, size in enumerate((0.01, 0.01, 0.005, 2 * DEG, 1 * DEG, 1 * DEG)):  # slow wobble
        base = base.add(ch, size * rng.uniform(0.3, 1.0), 2 * math.pi * rng.uniform(0.1, 0.5), rng.uniform(0, 2 * math.pi))
    counter = rng.uniform(1.2, 1.7)  # the thorax turns against the pelvis; the head keeps looking ahead
    joints = joints.add(index["jT9T8_rotz"], -counter * yaw_amp, omega, phase(0.25))
    joints = joints.add(index["jT1C7_rotz"], (counter - 1) * rng.uniform(0.6, 1.0) * yaw_amp, omega, phase(0.25))
    return joints, base


# ------------------------------------------------------------------------------ kinematics (pinocchio)
@dataclass
class Kinematics:
    """Frames at N times: rotation [N,F,3,3] (frame to world), body_rate [N,F,3] (the frame's angular
    velocity in its own axes, rad/s) and its derivative body_rate_dot [N,F,3] (rad/s^2), position
    [N,F,3] and acceleration [N,F,3] (classical, of the frame's origin: m, m/s^2, world)."""

    rotation: np.ndarray
    body_rate: np.ndarray
    body_rate_dot: np.ndarray
    position: np.ndarray
    acceleration: np.ndarray

    @property
    def world_rate(self) -> np.ndarray:
        return (self.rotation @ self.body_rate[..., None])[..., 0]


class Body:
    """A pinocchio model (free-flyer base) moved by a Motion; joints the motion lacks stay at zero."""

    def __init__(self, model, motion: Motion):
        import pinocchio

        self.pin, self.model, self.motion = pinocchio, pinocchio.Model(model), motion  # a copy: points are added
        self.data = self.model.createData()
        present = [n for n in motion.joint_names if self.model.existJointName(n)]
        self._channels = [motion.joint_names.index(n) for n in present]
        self._iq = [self.model.joints[self.model.getJointId(n)].idx_q for n in present]
        self._iv = [self.model.joints[self.model.getJointId(n)].idx_v for n in present]

    def frames(self, links) -> list[int]:
        """The frame ids of links (names)."""
        return [self.model.getFrameId(name) for name in links]

    def points(self, links, offsets: np.ndarray) -> list[int]:
        """New frames at offsets [F,3] (m, link axes) from the links' origins, axes the links'; their ids."""
        pin, ids = self.pin, []
        for name, offset in zip(links, offsets):
            parent = self.model.frames[self.model.getFrameId(name)]
            placement = parent.placement * pin.SE3(np.eye(3), np.asarray(offset, dtype=float))
            ids.append(self.model.addFrame(pin.Frame(f"{name}_point{len(self.model.frames)}", parent.parentJoint,
                                                     self.model.getFrameId(name), placement, pin.FrameType.OP_FRAME)))
        self.data = self.model.createData()
        return ids

    def configuration(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q [N,nq], v [N,nv], a [N,nv] at times t [N] in pinocchio's convention: the free flyer's v
        is its spatial velocity in its own frame (R^T dp, R^T w) and a the derivative of that v,
        R^T (ddp - w x dp) and R^T dw (not R^T ddp, which is the classical acceleration)."""
        b = self.motion.base_state(t)
        Rt = np.swapaxes(b["R"], -1, -2)
        local = lambda x: (Rt @ x[..., None])[..., 0]  # noqa: E731
        q = np.zeros((len(t), self.model.nq))
        v, a = np.zeros((len(t), self.model.nv)), np.zeros((len(t), self.model.nv))
        q[:, :3], q[:, 3:7] = b["p"], quaternion(b["R"])[:, [1, 2, 3, 0]]  # pinocchio: (x, y, z, w)
        v[:, :3], v[:, 3:6] = local(b["dp"]), local(b["w"])
        a[:, :3], a[:, 3:6] = local(b["ddp"] - np.cross(b["w"], b["dp"])), local(b["dw"])
        s, ds, dds = self.motion.joints(t)
        c = self._channels
        q[:, self._iq], v[:, self._iv], a[:, self._iv] = s[:, c], ds[:, c], dds[:, c]
        return q, v, a

    def kinematics(self, t: np.ndarray, frames: list[int]) -> Kinematics:
        """The frames' rotation, body rate, position and classical acceleration at times t [N].

        pinocchio's forward kinematics gives each parent joint's placement, spatial velocity and
        acceleration (joint axes); a frame rigidly at (R_f, t_f) on its joint then has rotation
        R_j R_f, body rate R_f^T w_j, and the classical acceleration of its origin
        R_j (a_j + alpha_j x t_f + w_j x (v_j + w_j x t_f)): what getFrameClassicalAcceleration
        (LOCAL_WORLD_ALIGNED) returns, done here in numpy for all frames and times at once (the
        per-frame calls cost twice the time). The body rate's derivative is R_f^T alpha_j (the
        angular part of a joint's spatial acceleration is the derivative of its body rate)."""
        pin, model, data = self.pin, self.model, self.data
        q, v, a = self.configuration(t)
        parents = [model.frames[f].parentJoint for f in frames]
        joints = sorted(set(parents))
        shape = (len(t), len(joints))
        M, V, A = np.empty(shape + (4, 4)), np.empty(shape + (6,)), np.empty(shape + (6,))
        for n in range(len(t)):  # pinocchio is one configuration at a time
            pin.forwardKinematics(model, data, q[n], v[n], a[n])
            for k, j in enumerate(joints):
                M[n, k], V[n, k], A[n, k] = data.oMi[j].np, data.v[j].np, data.a[j].np  # motions: (linear, angular)
        col = [joints.index(j) for j in parents]
        M, V, A = M[:, col], V[:, col], A[:, col]
        Rf = np.stack([model.frames[f].placement.rotation for f in frames])  # [F,3,3]
        tf = np.stack([model.frames[f].placement.translation for f in frames])  # [F,3]
        Rj, w, alpha = M[..., :3, :3], V[..., 3:], A[..., 3:]
        vp = V[..., :3] + cross(w, tf)  # the frame origin's velocity, joint axes
        acc = A[..., :3] + cross(alpha, tf) + cross(w, vp)
        world = lambda x: (Rj @ x[..., None])[..., 0]  # noqa: E731
        in_frame = lambda x: (np.swapaxes(Rf, -1, -2) @ x[..., None])[..., 0]  # noqa: E731
        return Kinematics(Rj @ Rf, in_frame(w), in_frame(alpha), M[..., :3, 3] + world(tf), world(acc))


# ------------------------------------------------------------------------------ inertial sensors
@dataclass(frozen=True)
class FilterGains:
    """Mahony's explicit complementary filter: R <- R exp((gyro - b + k_p w) dt), b' = -k_i w, with
    w = k_a (v_a x v_a_hat) + k_m (v_m x v_m_hat).

    k_p = 1 /s: the orientation follows the gravity (and field) direction with a time constant of 1 s,
    which passes the residual of the compensated walking accelerations (1-2 Hz) only in part. k_i =
    0.02 /s^2: the bias estimate moves with a time constant of about 50 s (k_p / k_i), as the slow
    bias estimators of suit filters do; it starts at what a still period before the recording gave it
    (settled_bias), so over a 12 s recording it barely moves. A fast estimator (k_i near k_p^2 / 4)
    would take up the walk's tilt errors as a bias that wanders by a fraction of a degree per second,
    which its raw rates then disagree with: a real effect of such a filter, and not one the study
    means to inject into every recording."""

    k_p: float = 1.0
    k_i: float = 0.02
    k_a: float = 1.0
    k_m: float = 1.0


@dataclass
class ImuSetup:
    """The inertial sensors, one per link, arrays over the S sensors (in `links` order).

    mount [S,3,3]: the sensor frame in its segment's frame (true); assumed [S,3,3]: what the
    software takes it to be (the recording reports R_sensor @ assumed^T); offset [S,3]: the sensor's
    point on the segment (m, segment axes). gyro_bias [S,3] (rad/s, sensor axes), gyro_scale [S]
    (fraction), bias_walk [S] (rad/s/sqrt(s)), gyro_noise [S] (rad/s rms at the output rate),
    accel_noise [S] (m/s^2 rms per internal sample), mag_noise [S] (per internal sample, of a unit
    vector). magnetometer [S]: a 9-axis filter (else 6-axis: tilt only); compensated [S]: the rate
    output is the gyro minus the filter's bias estimate (else raw). field_turn [S] (rad/s) from
    field_start [S] (s): the field's direction turning about the vertical. clock_delay [S] (s): the
    sensor's whole output late; rate_delay [S] (s): its rate stream late on its orientations (the
    world rate it reports at t is the one it had at t - d, between internal samples linearly).
    residual_share: the share of the segment's acceleration the filter's body model leaves in the
    accelerometer it corrects tilt with. rate_scale [S] (fraction, default none): the rate stream's
    conversion error, the raw gyro register read with the datasheet's nominal sensitivity (MEMS gyros
    are specified to +-3 %) while the filter integrates the factory-calibrated gyro: the stream reads
    (1 + rate_scale) times the rate and the orientations do not carry it (gyro_scale, the sensor's own,
    the filter integrates)."""

    links: tuple[str, ...]
    mount: np.ndarray
    assumed: np.ndarray
    offset: np.ndarray
    gyro_bias: np.ndarray
    gyro_scale: np.ndarray
    bias_walk: np.ndarray
    gyro_noise: np.ndarray
    accel_noise: np.ndarray
    mag_noise: np.ndarray
    magnetometer: np.ndarray
    compensated: np.ndarray
    field_turn: np.ndarray
    field_start: np.ndarray
    clock_delay: np.ndarray
    rate_delay: np.ndarray
    residual_share: float = 0.05
    gains: FilterGains = field(default_factory=FilterGains)
    rate_scale: np.ndarray | None = None

    @classmethod
    def ideal(cls, links, offset: np.ndarray | None = None, **changes) -> "ImuSetup":
        """Perfect sensors (no noise, no errors, 9-axis filters, raw rates, a perfect body model),
        offset 5 cm along each segment's x unless given; `changes` replace fields."""
        S, z, eye = len(links), np.zeros(len(links)), np.tile(np.eye(3), (len(links), 1, 1))
        base = cls(tuple(links), eye, eye.copy(), np.tile([0.05, 0.0, 0.0], (S, 1)) if offset is None else offset,
                   np.zeros((S, 3)), z.copy(), z.copy(), z.copy(), z.copy(), z.copy(), np.ones(S, bool),
                   np.zeros(S, bool), z.copy(), z.copy(), z.copy(), z.copy(), residual_share=0.0)
        return replace(base, **changes)


@dataclass
class ImuOutput:
    """What the sensors report and the truth beside it, at the output times t [K].

    orientation [K,S,3,3] (segment to world, as reported), angular_velocity [K,S,3] (world, as
    reported), true_orientation [K,S,3,3] and true_rate [K,S,3] (the segment's, world, at the
    sensor's own clock time t - clock_delay), bias_estimate [K,S,3] (the filter's, sensor axes)."""

    time: np.ndarray
    orientation: np.ndarray
    angular_velocity: np.ndarray
    true_orientation: np.ndarray
    true_rate: np.ndarray
    bias_estimate: np.ndarray


def settled_bias(setup: "ImuSetup", R0: np.ndarray) -> np.ndarray:
    """[S,3] the bias estimate a filter holds when the recording starts (sensor axes): what a still period
    before it let the filter see of the gyro's bias. A 9-axis filter sees all of it (gravity gives the
    two horizontal axes, a homogeneous field the vertical one: Xsens' MTi manual, "Internal Sensor Bias
    Estimation"); a 6-axis filter only the part about the horizontal axes at rest (R0 [S,3,3] the
    sensors' orientations then), and integrates the rest into its heading."""
    b = setup.gyro_bias
    up = R0[:, 2, :]  # the vertical in each sensor's axes
    unseen = np.where(setup.magnetometer[:, None], 0.0, (b * up).sum(-1, keepdims=True) * up)
    return b - unseen


def mahony(gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray, R0: np.ndarray, dt: float, gains: FilterGains,
           magnetometer: np.ndarray, b0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mahony, Hamel, Pflimlin (2008), explicit complementary filter, for S sensors at once.

    gyro [N,S,3]: the rate over each step (sensor axes, rad/s); accel [N,S,3], mag [N,S,3]: the
    specific force and the field direction at each step's start; R0 [S,3,3]; magnetometer [S] bool
    (9-axis); b0 [S,3]: the bias estimate at the start (default none). The field's reference is the
    world x axis; only the horizontal part of the measured
    field is used, so the magnetometer corrects heading and never tilt. Returns the estimates at
    the N+1 step boundaries: R [N+1,S,3,3] (sensor to world) and b [N+1,S,3] (bias, sensor axes)."""
    N, S = gyro.shape[:2]
    va = accel / np.linalg.norm(accel, axis=-1, keepdims=True)
    k_m = gains.k_m * magnetometer.astype(float)
    R, b = R0.copy(), np.zeros((S, 3)) if b0 is None else b0.copy()
    Rs, bs = np.empty((N + 1, S, 3, 3)), np.empty((N + 1, S, 3))
    Rs[0], bs[0] = R, b
    for i in range(N):
        up_hat = R[:, 2, :]  # R^T e_z: the vertical in the sensor's axes, by the estimate
        w = gains.k_a * cross(va[i], up_hat)
        h = (R @ mag[i][..., None])[..., 0]  # the measured field in the world, by the estimate
        sin_heading = -h[:, 1] / np.maximum(np.hypot(h[:, 0], h[:, 1]), 1e-9)  # (h_xy/|h_xy| x e_x) . e_z
        w += (k_m * sin_heading)[:, None] * up_hat  # R^T of a vertical correction: heading only
        R = R @ expm((gyro[i] - b + gains.k_p * w) * dt)
        b = b - gains.k_i * dt * w
        Rs[i + 1], bs[i + 1] = R, b
    return Rs, bs


def simulate_imus(body: Body, setup: ImuSetup, time: np.ndarray, oversample: int = 4,
                  rng: np.random.Generator | None = None) -> ImuOutput:
    """The sensors of `setup` on `body`, reporting at the (uniform) times [K], simulated at
    `oversample` times the output rate.

    The internal steps run from before the first output (so that a late rate stream and the first
    integrate-and-dump window have data); each filter starts at its sensor's true orientation with
    the bias estimate a still period before gave it (settled_bias): it converged then."""
    rng = rng or np.random.default_rng(0)
    dt_out = float(np.median(np.diff(time)))
    dt, K = dt_out / oversample, len(time)
    pre = int(math.ceil((float(setup.rate_delay.max()) + dt_out) / dt)) + 1  # steps before the first output
    n = pre + (K - 1) * oversample + 1  # step boundaries (nodes)
    nodes = time[0] + (np.arange(n) - pre) * dt
    kin = _sensor_kinematics(body, setup, nodes)
    Rs = kin.rotation @ setup.mount  # the sensors' frames
    in_sensor = lambda x: (np.swapaxes(setup.mount, -1, -2) @ x[..., None])[..., 0]  # noqa: E731
    gyro = _gyro(setup, step_mean(in_sensor(kin.body_rate), in_sensor(kin.body_rate_dot), dt), dt, oversample, rng)
    accel, mag = _accel_and_field(setup, Rs, kin.acceleration, nodes, rng)
    R_hat, b_hat = mahony(gyro, accel[:-1], mag[:-1], Rs[0], dt, setup.gains, setup.magnetometer,
                          settled_bias(setup, Rs[0]))
    converted = 1.0 + (np.zeros(len(setup.links)) if setup.rate_scale is None else setup.rate_scale)
    stream = _rate_stream(converted[:, None] * (gyro - np.where(setup.compensated[:, None], b_hat[:-1], 0.0)), R_hat,
                          oversample)
    out = pre + oversample * np.arange(K)  # the nodes of the output times
    late = out[:, None] - setup.rate_delay / dt  # [K,S]: where each sensor's rate sample comes from
    return ImuOutput(time, R_hat[out] @ np.swapaxes(setup.assumed, -1, -2), _sample(stream, late),
                     kin.rotation[out], kin.world_rate[out], b_hat[out])


def _sensor_kinematics(body: Body, setup: ImuSetup, t: np.ndarray) -> Kinematics:
    """The sensors' points on their segments [N,S] at times t [N], each at its own clock (t - clock_delay):
    one pass of pinocchio per distinct delay."""
    frames = np.array(body.points(setup.links, setup.offset))
    parts = {}
    for d in np.unique(setup.clock_delay):
        which = np.flatnonzero(setup.clock_delay == d)
        parts[float(d)] = (which, body.kinematics(t - d, [int(f) for f in frames[which]]))
    S = len(setup.links)
    out = Kinematics(np.empty((len(t), S, 3, 3)), *(np.empty((len(t), S, 3)) for _ in range(4)))
    for which, k in parts.values():
        for name in ("rotation", "body_rate", "body_rate_dot", "position", "acceleration"):
            getattr(out, name)[:, which] = getattr(k, name)
    return out


def step_mean(x: np.ndarray, dx: np.ndarray, dt: float) -> np.ndarray:
    """The mean over each step of a smooth signal known with its derivative at the step boundaries,
    [n,...] -> [n-1,...]: the integral of the cubic Hermite interpolant, (x0 + x1)/2 + dt (dx0 - dx1)/12
    (error dt^4 max|x(4)|/720): what an integrating gyro accumulates over a step."""
    return (x[:-1] + x[1:]) / 2 + dt * (dx[:-1] - dx[1:]) / 12


def _gyro(setup: ImuSetup, rate: np.ndarray, dt: float, oversample: int, rng: np.random.Generator) -> np.ndarray:
    """Gyro samples [N,S,3] of the true sensor-frame rates [N,S,3] over each step:
    (1 + scale) w + bias (+ random walk) + white noise, its rms per internal sample sqrt(oversample)
    times the output's (the output averages oversample of them)."""
    walk = np.cumsum(rng.standard_normal(rate.shape), axis=0) * (setup.bias_walk * math.sqrt(dt))[:, None]
    noise = rng.standard_normal(rate.shape) * (setup.gyro_noise * math.sqrt(oversample))[:, None]
    return (1 + setup.gyro_scale)[:, None] * rate + setup.gyro_bias + walk + noise


def _accel_and_field(setup: ImuSetup, Rs: np.ndarray, acc: np.ndarray, t: np.ndarray,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What the filter corrects with, at the nodes t [N] ([N,S,3] each): the measured specific force
    R_s^T (a - g) + noise less the body model's estimate (1 - residual_share) R_s^T a of the
    acceleration, and the measured field direction R_s^T m(t) + noise, m turning about the vertical
    at field_turn from field_start (at the sensor's clock time)."""
    Rt = np.swapaxes(Rs, -1, -2)
    force = (Rt @ (acc - GRAVITY)[..., None])[..., 0] + rng.standard_normal(acc.shape) * setup.accel_noise[:, None]
    accel = force - (1 - setup.residual_share) * (Rt @ acc[..., None])[..., 0]
    own = t[:, None] - setup.clock_delay  # [N,S]
    angle = setup.field_turn * np.maximum(own - setup.field_start, 0.0)
    m = np.stack((np.cos(angle), np.sin(angle), np.zeros_like(angle)), -1)
    mag = (Rt @ m[..., None])[..., 0] + rng.standard_normal(acc.shape) * setup.mag_noise[:, None]
    return accel, mag


def _rate_stream(gyro: np.ndarray, R_hat: np.ndarray, oversample: int) -> np.ndarray:
    """The world rate the sensor would report at each node [n,S,3]: the filter's orientation at the
    node times the mean gyro over the last `oversample` steps (integrate-and-dump, as strapdown-
    integrating IMUs such as Xsens' do: the rate is that of the interval's middle, half an output
    sample before the orientation it is reported with). NaN where the window lacks steps."""
    cs = np.concatenate((np.zeros((1,) + gyro.shape[1:]), np.cumsum(gyro, axis=0)))  # [n,S,3]
    mean = np.full_like(cs, np.nan)
    mean[oversample:] = (cs[oversample:] - cs[:-oversample]) / oversample
    return (R_hat @ mean[..., None])[..., 0]


def _sample(stream: np.ndarray, at: np.ndarray) -> np.ndarray:
    """stream [n,S,3] at fractional node indices at [K,S] (linear between nodes) -> [K,S,3]."""
    lo = np.floor(at).astype(int)
    frac = (at - lo)[..., None]
    s = np.arange(stream.shape[1])
    return (1 - frac) * stream[lo, s] + frac * stream[np.minimum(lo + 1, len(stream) - 1), s]


# ------------------------------------------------------------------------------ optical (marker clusters)
@dataclass
class ClusterSetup:
    """A rigid marker cluster per link: nominal [S,M,3] (m, segment axes; the rows with mask [S,M]
    False are absent: 3 or 4 markers), turn [S,3,3] and shift [S,3] (how the cluster actually sits
    on the segment against its nominal placement, about its nominal centroid), noise (m rms)."""

    links: tuple[str, ...]
    nominal: np.ndarray
    mask: np.ndarray
    turn: np.ndarray
    shift: np.ndarray
    noise: float = 0.0

    @classmethod
    def draw(cls, links, rng: np.random.Generator, noise: float = 0.0) -> "ClusterSetup":
        """Clusters of 3 or 4 markers (half each) 4-10 cm from the segments' origins, placed as nominal."""
        S = len(links)
        nominal, mask = np.zeros((S, 4, 3)), np.ones((S, 4), bool)
        for s in range(S):
            nominal[s] = _cluster(rng)
            if rng.uniform() < 0.5:
                mask[s, 3] = False
        return cls(tuple(links), nominal, mask, np.tile(np.eye(3), (S, 1, 1)), np.zeros((S, 3)), noise)


def _cluster(rng: np.random.Generator) -> np.ndarray:
    """Four marker positions [4,3] (m), 4-10 cm from the origin in random directions, at least 4 cm
    apart, the first three far from a line (their plane spread over 3 cm both ways)."""
    while True:
        P = unit_vectors(rng, 4) * rng.uniform(0.04, 0.10, (4, 1))
        apart = np.linalg.norm(P[:, None] - P[None], axis=-1)[np.triu_indices(4, 1)].min()
        spread = np.linalg.svd(P[:3] - P[:3].mean(0), compute_uv=False)
        if apart > 0.04 and spread[1] > 0.03:
            return P


def kabsch(nominal: np.ndarray, measured: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares rigid fit measured ~ R nominal + p: nominal [S,M,3], measured [...,S,M,3],
    mask [S,M] -> R [...,S,3,3], p [...,S,3]."""
    w = mask[..., None].astype(float)
    cn = (w * nominal).sum(-2) / w.sum(-2)
    cm = (w * measured).sum(-2) / w.sum(-2)
    H = np.swapaxes(w * (nominal - cn[..., None, :]), -1, -2) @ (measured - cm[..., None, :])  # [...,S,3,3]
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    D = np.tile(np.eye(3), d.shape + (1, 1))
    D[..., 2, 2] = d  # no reflection
    R = V @ D @ np.swapaxes(U, -1, -2)
    return R, cm - (R @ cn[..., None])[..., 0]


def simulate_clusters(body: Body, setup: ClusterSetup, time: np.ndarray, rng: np.random.Generator | None = None,
                      window: int = 1) -> dict[str, np.ndarray]:
    """Marker clusters on `body` at times [K]: orientation [K,S,3,3] fitted to the measured markers
    (smoothed by a centred moving average over `window` frames, as a user filters markers before
    differentiating; 1: not smoothed) against the nominal geometry, angular_velocity [K,S,3]
    differentiated from them (rate_from_orientations), position [K,S,3] the fitted origins, markers
    [K,S,M,3] as measured (NaN where absent), and the segments' true_orientation and true_rate."""
    rng = rng or np.random.default_rng(0)
    kin = body.kinematics(time, body.frames(setup.links))
    centre = (setup.mask[..., None] * setup.nominal).sum(1) / setup.mask.sum(1)[:, None]  # [S,3]
    actual = centre[:, None] + (setup.turn[:, None] @ (setup.nominal - centre[:, None])[..., None])[..., 0] \
        + setup.shift[:, None]  # [S,M,3]: where the markers really are on the segments
    markers = kin.position[:, :, None] + (kin.rotation[:, :, None] @ actual[..., None])[..., 0]
    markers = markers + setup.noise * rng.standard_normal(markers.shape)
    R, p = kabsch(setup.nominal, moving_average(markers, window), setup.mask)
    return dict(orientation=R, angular_velocity=rate_from_orientations(R, time), position=p,
                markers=np.where(setup.mask[..., None], markers, np.nan), true_orientation=kin.rotation,
                true_rate=kin.world_rate)


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average along axis 0 over `window` (odd) samples, the window shrinking
    symmetrically at the ends (zero phase throughout)."""
    if window <= 1:
        return x
    half, T = window // 2, len(x)
    cs = np.concatenate((np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)))
    k = np.arange(T)
    h = np.minimum(np.minimum(k, T - 1 - k), half)  # the half-width that fits at each sample
    return (cs[k + h + 1] - cs[k - h]) / (2 * h + 1).reshape(-1, *([1] * (x.ndim - 1)))


# ------------------------------------------------------------------------------ families
@dataclass
class Injected:
    """One effect put in a recording: family, its links (or joint, or "all"), its size per target
    (in `unit`), and what else defines it (axes, rates, the joint's motion ...)."""

    family: str
    targets: list[str]
    sizes: list[float]
    unit: str
    extra: dict = field(default_factory=dict)

    def kinds(self) -> tuple[str, ...]:
        """The diagnosis's effect kinds that name it."""
        return KINDS.get(self.family, (self.family,))


def unit_vectors(rng: np.random.Generator, k: int) -> np.ndarray:
    """k random directions, uniform on the sphere [k,3]."""
    v = rng.standard_normal((k, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def generate(seed: int, family: str, count: int | None = None, links=None, duration: float = 12.0,
             rate: float = 100.0, reference: Path | None = REFERENCE_DIR, oversample: int = 4, remove=()):
    """One recording of a family (FAMILIES): (Recording, [Injected], info).

    seed: the motion comes from (seed, 0), the sensors' configuration from (seed, 1), the noise
    from (seed, 2): one seed's recordings share their motion and noise across families. count: the
    number of sensors (or axes) the effect is on (default 1-4 at random, 1 for sensor_delay and
    missing_axis; stream_delay is on all). links: the segments with sensors (default Human48's 23;
    must hold "Pelvis"). reference: the folder of the published URDFs (None: torchik's human_urdf).
    info: the noise levels, the setup (ImuSetup or ClusterSetup), the motion's parameters, the
    measured orientation error of the sensors without an effect (deg rms), the truth (segments'
    orientation [T,L,3,3] and world rate [T,L,3], joint names and angles [T,dof]), the seconds taken.
    remove: sensors (links; "all" for a rate stream's delay) whose drawn effect is taken out again, the
    motion, the other sensors and the noise as they were: the same recording without those effects
    (what shows whether the data can see one; a missing axis cannot be removed)."""
    from torchik.io.recording import Recording
    from torchik.method.models import TRACKED_LINKS

    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; valid: {', '.join(FAMILIES)}")
    links = tuple(links or TRACKED_LINKS["human48"])
    if "Pelvis" not in links:
        raise ValueError("links must hold the base link 'Pelvis'")
    started = clock.perf_counter()
    rng_motion, rng_setup, rng_noise = (np.random.default_rng([seed, k]) for k in range(3))
    t = np.arange(int(round(duration * rate))) / rate
    body, injected, source = _body(family, rng_motion, rng_setup, count, duration, reference)
    optical = family in ("optical_clean", "cluster_offset")
    if optical:
        setup, extra = _draw_clusters(family, links, rng_setup, count)
        _remove_clusters(setup, links, remove)
        out = simulate_clusters(body, setup, t, rng_noise, window=OPTICAL_WINDOW)
    else:
        setup, extra = _draw_imus(family, links, body, duration, rate, rng_setup, count)
        _remove_imus(setup, links, remove)
        out = vars(simulate_imus(body, setup, t, oversample, rng_noise))
    injected += extra
    base = body.motion.base_state(t)
    model = "human66" if family == "missing_axis" else "human48"
    meta = dict(source="experiments/sensor_physics.py", family=family, seed=int(seed), model=model,
                mode="optical" if optical else "imu", urdf=source,
                orientation="Kabsch fit of marker clusters" if optical else "Mahony filter of simulated IMUs",
                angular_velocity=(f"np.gradient of the orientations of markers averaged over {OPTICAL_WINDOW} frames"
                                  if optical else "gyroscopes, integrate-and-dump at the output rate"))
    recording = Recording(time=t, links=links, orientation=out["orientation"], angular_velocity=out["angular_velocity"],
                          base_link="Pelvis", base_position=base["p"], base_linear_velocity=base["dp"], meta=meta)
    info = dict(seed=seed, family=family, model=model, urdf=source, setup=setup, noise=_noise_levels(setup, optical),
                motion=dict(stride_hz=body.motion.stride_hz, speed=body.motion.speed, turn_deg_s=body.motion.turn / DEG),
                orientation_error_deg=_unaffected_error(out, links, injected), truth=_truth(body, t, links))
    info["seconds"] = clock.perf_counter() - started
    return recording, injected, info


def _remove_imus(setup: "ImuSetup", links, remove) -> None:
    """The sensors named in `remove` put back as the base suit has them (generate)."""
    at = [links.index(x) for x in remove if x in links]
    setup.mount[at] = setup.assumed[at]
    setup.gyro_bias[at], setup.gyro_scale[at], setup.field_turn[at], setup.clock_delay[at] = 0.0, 0.0, 0.0, 0.0
    if setup.rate_scale is not None:
        setup.rate_scale[at] = 0.0
    setup.magnetometer[at], setup.compensated[at] = True, False
    if "all" in remove:
        setup.rate_delay[:] = 0.0


def _remove_clusters(setup: "ClusterSetup", links, remove) -> None:
    """The clusters named in `remove` put back where they are taken to sit (generate)."""
    at = [links.index(x) for x in remove if x in links]
    setup.turn[at], setup.shift[at] = np.eye(3), 0.0


def _body(family: str, rng_motion: np.random.Generator, rng_setup: np.random.Generator, count: int | None,
          duration: float, reference: Path | None) -> tuple[Body, list[Injected], str]:
    """The walking body (Human48; Human66 with missing axes moving for missing_axis), its injected
    axes, where its URDF came from."""
    model, source = human_model(48, reference)
    names, lower, upper = joint_table(model)
    motion = walking_motion(rng_motion, names, lower, upper, (-0.5, duration + 0.5))
    if family != "missing_axis":
        return Body(model, motion), [], source
    model, source = human_model(66, reference)
    motion, injected = _missing_axes(motion, rng_setup, count)
    return Body(model, motion), injected, source


def _unaffected_error(out: dict, links, injected: list[Injected]) -> float:
    """The rms angle (deg) between the reported and true orientations of the sensors no effect is on
    (a late rate stream leaves orientations as they are); NaN when there are none."""
    affected = {x for inj in injected if inj.family != "stream_delay" for x in inj.targets}
    clean = [k for k, name in enumerate(links) if name not in affected]
    if not clean:
        return float("nan")
    E = np.swapaxes(out["true_orientation"][:, clean], -1, -2) @ out["orientation"][:, clean]
    return float(np.degrees(np.sqrt((logm(E) ** 2).sum(-1).mean())))


def _truth(body: Body, t: np.ndarray, links) -> dict:
    """The segments' true orientation [T,L,3,3] and world rate [T,L,3], the joints' names and angles [T,dof]."""
    kin = body.kinematics(t, body.frames(links))
    model = body.model
    return dict(orientation=kin.rotation, angular_velocity=kin.world_rate,
                joint_names=[model.names[j] for j in range(2, model.njoints)],
                joint_positions=body.configuration(t)[0][:, 7:])


def _noise_levels(setup, optical: bool) -> dict:
    """The noise levels a recording was drawn with (means over the sensors)."""
    if optical:
        return dict(marker_m=setup.noise)
    return dict(gyro_rad_s=float(setup.gyro_noise.mean()), accel_m_s2=float(setup.accel_noise.mean()),
                magnetometer=float(setup.mag_noise.mean()), residual_share=setup.residual_share)


def _some(rng: np.random.Generator, candidates, count: int | None) -> list[str]:
    """`count` (default 1-4 at random) of the candidates, distinct."""
    k = min(count or int(rng.integers(1, 5)), len(candidates))
    return [str(x) for x in rng.choice(list(candidates), k, replace=False)]


def _base_imus(links, rng: np.random.Generator) -> ImuSetup:
    """A suit of 9-axis sensors reporting raw rates, each 3-8 cm off its segment's origin, with noise:
    gyro 0.005-0.02 rad/s, accelerometer 0.01-0.05 m/s^2, magnetometer 0.005-0.02, body model leaving 5 %."""
    S = len(links)
    offset = unit_vectors(rng, S) * rng.uniform(0.03, 0.08, (S, 1))
    sigma_g, sigma_a, sigma_m = rng.uniform(0.005, 0.02), rng.uniform(0.01, 0.05), rng.uniform(0.005, 0.02)
    jitter = lambda: rng.uniform(0.8, 1.2, S)  # noqa: E731
    return ImuSetup.ideal(links, offset, gyro_noise=sigma_g * jitter(), accel_noise=sigma_a * jitter(),
                          mag_noise=sigma_m * jitter(), residual_share=0.03)


def _draw_imus(family: str, links, body: Body, duration: float, rate: float, rng: np.random.Generator,
               count: int | None) -> tuple[ImuSetup, list[Injected]]:
    """The suit for a family (9-axis, raw rates unless the family says otherwise) and the effects it holds."""
    setup = _base_imus(links, rng)
    if family in ("clean", "missing_axis"):
        return setup, []
    if family == "stream_delay":
        samples = int(rng.integers(2, 8))
        setup.rate_delay[:] = samples / rate
        return setup, [Injected(family, ["all"], [1e3 * samples / rate], "ms", dict(samples=samples))]
    upright = [str(rng.choice([x for x in g if x in links])) for g in UPRIGHT_GROUPS if set(g) & set(links)]
    targets = _some(rng, upright if family == "vertical_bias" else links, count or (1 if family == "sensor_delay" else None))
    at = [links.index(x) for x in targets]
    k = len(targets)
    if family == "strap":
        axes, angles = unit_vectors(rng, k), rng.uniform(5, 15, k)
        setup.mount[at] = expm(axes * angles[:, None] * DEG)
        return setup, [Injected(family, targets, list(angles), "deg", dict(axes=axes.tolist()))]
    if family == "gyro_scale":  # the stream's conversion (ImuSetup.rate_scale): its own filter's would turn it
        scale = rng.choice([-1, 1], k) * rng.uniform(2, 8, k)
        setup.rate_scale = np.zeros(len(links))
        setup.rate_scale[at] = scale / 100
        return setup, [Injected(family, targets, list(scale), "%")]
    if family == "sensor_delay":
        delay = rng.uniform(30, 100, k)
        setup.clock_delay[at] = delay / 1e3
        return setup, [Injected(family, targets, list(delay), "ms")]
    if family == "magnetic_drift":
        # the disturbance there from the start (the recording begins beside the ferrous structure): one that
        # begins later makes a drift from then on, which a drift from the start fits short
        turn, start = rng.choice([-1, 1], k) * rng.uniform(0.5, 3, k), np.zeros(k)
        setup.field_turn[at], setup.field_start[at] = turn * DEG, start
        # the filter keeps the field where it was: its heading turns against the field
        return setup, [Injected(family, targets, list(-turn), "deg/s", dict(field_turn=list(turn), start=list(start)))]
    return _draw_bias(family, setup, targets, body, duration, rng)


def _draw_bias(family: str, setup: ImuSetup, targets: list[str], body: Body, duration: float,
               rng: np.random.Generator) -> tuple[ImuSetup, list[Injected]]:
    """gyro_bias (9-axis, raw rates), tilt_filter_bias (6-axis, raw or compensated), vertical_bias
    (6-axis, compensated; along the sensor axis closest to the vertical on average)."""
    at, k = [setup.links.index(x) for x in targets], len(targets)
    low, high = (0.5, 10) if family == "gyro_bias" else (1, 3)
    size = rng.uniform(low, high, k)
    if family == "vertical_bias":
        up = body.kinematics(np.linspace(0, duration, 25), body.frames(targets)).rotation[..., 2, :].mean(0)  # [k,3]
        axis = np.zeros((k, 3))
        which = np.argmax(np.abs(up), 1)
        axis[np.arange(k), which] = np.sign(up[np.arange(k), which])  # along the mean vertical: drift +size
        size = size * rng.choice([-1, 1], k)
        extra = dict(axes=axis.tolist(), sensor_axis=["xyz"[j] for j in which])
    else:
        axis = unit_vectors(rng, k)
        extra = dict(axes=axis.tolist())
    setup.gyro_bias[at] = axis * size[:, None] * DEG
    if family != "gyro_bias":
        # the biased sensors' filters have no heading reference (the others keep theirs: a heading-free
        # filter drifts a little on every sensor, from the walk's tilt errors its bias estimate takes up,
        # and the study names one undeclared effect a recording)
        setup.magnetometer[at] = False
        setup.compensated[at] = True if family == "vertical_bias" else bool(rng.uniform() < 0.5)
        extra.update(filter="6-axis", compensated=bool(setup.compensated[at[0]]))
    return setup, [Injected(family, targets, list(size), "deg/s", extra)]


def _missing_axes(motion: Motion, rng: np.random.Generator, count: int | None) -> tuple[Motion, list[Injected]]:
    """One (or count) of MISSING_AXES moving by its AXIS_AMPLITUDE at 0.2-1 Hz."""
    joints = _some(rng, MISSING_AXES, count or 1)
    injected = []
    for joint in joints:
        low, high = next(v for k, v in AXIS_AMPLITUDE.items() if k in joint)
        amp, freq, phase = rng.uniform(low, high), rng.uniform(0.2, 1.0), rng.uniform(0, 2 * math.pi)
        motion = motion.with_axis(joint, amp * DEG, freq, phase)
        injected.append(Injected("missing_axis", [joint.rsplit("_", 1)[0]], [amp], "deg",
                                 dict(joint=joint, frequency_hz=freq, phase=phase)))
    return motion, injected


def _draw_clusters(family: str, links, rng: np.random.Generator, count: int | None) -> tuple[ClusterSetup, list]:
    """Clusters with 0.5-1 mm marker noise; cluster_offset: 1-4 turned 5-15 deg and shifted up to 5 mm."""
    setup = ClusterSetup.draw(links, rng, noise=rng.uniform(0.0005, 0.001))
    if family == "optical_clean":
        return setup, []
    targets = _some(rng, links, count)
    at, k = [links.index(x) for x in targets], len(targets)
    axes, angles = unit_vectors(rng, k), rng.uniform(5, 15, k)
    setup.turn[at] = expm(axes * angles[:, None] * DEG)
    setup.shift[at] = rng.uniform(-0.005, 0.005, (k, 3))
    return setup, [Injected(family, targets, list(angles), "deg", dict(axes=axes.tolist(), shift=setup.shift[at].tolist()))]


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="clean", choices=FAMILIES)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=12.0)
    parser.add_argument("--rate", type=float, default=100.0)
    a = parser.parse_args()
    recording, injected, info = generate(a.seed, a.family, duration=a.duration, rate=a.rate)
    print(f"{a.family} seed {a.seed}: {len(recording.time)} frames of {len(recording.links)} links in "
          f"{info['seconds']:.2f} s; orientation error of the unaffected sensors "
          f"{info['orientation_error_deg']:.2f} deg rms")
    for inj in injected:
        print(f"  {inj.family}: {', '.join(f'{x} {s:.3g} {inj.unit}' for x, s in zip(inj.targets, inj.sizes))}")


if __name__ == "__main__":
    main()

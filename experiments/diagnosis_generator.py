"""The diagnosis study's recordings (experiments/diagnosis_study.py), made without torchik's kinematics.

Recordings come from the published Human48 (and, for a missing axis, Human66) URDF in
../shared/reference-models, through pinocchio's kinematics (not torchik's): a moving base (a walk
with turns, sway, roll and pitch) and every joint a sum of three sinusoids of random frequency
(0.1 to 1.2 Hz), phase and amplitude within its limits, nothing like the tracker's scenarios. Each
link's orientation and world angular velocity are pinocchio's; delays are the motion evaluated at
t - d (exact, not interpolated). Noise: white, AR(1) (phi 0.8 to 0.98) or 1/f, on orientations
(0.3 to 1 deg rms) and gyros (0.005 to 0.02 rad/s rms), the model and levels drawn per recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference-models" / "humanSubject01_{dof}dof.urdf"
FAMILIES = ("misalignment", "gyro_bias", "stream_delay", "heading_drift", "missing_axis", "sensor_delay")
OPTIONAL = ("gyro_scale",)
NOISES = ("white", "ar1", "pink")
# axes Human66 has and Human48 lacks, that a body makes: knee ab/adduction, elbow and wrist, head and spine rotation
MISSING_AXES = ("jRightKnee_rotx", "jLeftKnee_rotx", "jRightElbow_rotx", "jLeftElbow_rotx", "jC1Head_rotz",
                "jRightWrist_roty", "jLeftWrist_roty", "jL5S1_rotz")
DEG = math.pi / 180


@dataclass
class Injected:
    """One injected effect: family, the links (or the joint) it is on, its size per target (family's unit)."""

    family: str
    targets: list[str]
    sizes: list[float]
    unit: str
    extra: dict = field(default_factory=dict)

    def kinds(self) -> tuple[str, ...]:
        """The diagnosis' effect kinds that name it."""
        return {"missing_axis": ("missing_dof",)}.get(self.family, (self.family,))


# ------------------------------------------------------------------------------ motion (pinocchio)
class Body:
    """A pinocchio model (free-flyer base) of a reference URDF and a random smooth motion of its joints."""

    def __init__(self, dof: int, links, rng: np.random.Generator, moving: list[str], duration: float):
        import pinocchio

        self.pin = pinocchio
        self.model = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=dof), pinocchio.JointModelFreeFlyer())
        self.data = self.model.createData()
        self.frames = [self.model.getFrameId(name) for name in links]
        self.index = [self.model.joints[self.model.getJointId(n)].idx_q for n in moving]
        self.vindex = [self.model.joints[self.model.getJointId(n)].idx_v for n in moving]
        # the limits of Human48, the diagnosed model (Human66's are +-10 rad: none)
        limits = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=48))
        lo = np.array([limits.lowerPositionLimit[limits.joints[limits.getJointId(n)].idx_q] for n in moving])
        hi = np.array([limits.upperPositionLimit[limits.joints[limits.getJointId(n)].idx_q] for n in moving])
        # a posture about the T-pose (zero), swinging by at most 0.6 rad, within the limits: far from
        # zero, a shoulder with a 3-rad range puts the tracker's start on another branch of its IK
        half = np.minimum(0.5 * (hi - lo) - 0.05, 0.6)
        amplitude = half * rng.uniform(0.3, 1.0, len(moving))
        self.centre = np.clip(rng.uniform(-0.25, 0.25, len(moving)), lo + 0.05 + amplitude, hi - 0.05 - amplitude)
        self.amp = amplitude[:, None] * rng.dirichlet(np.ones(3), len(moving))  # [n,3]: sums to the amplitude
        self.freq = 2 * math.pi * rng.uniform(0.1, 1.2, (len(moving), 3))
        self.phase = rng.uniform(0, 2 * math.pi, (len(moving), 3))
        # base: a walk at 0.5-1.2 m/s that turns, sways and bobs; roll and pitch of a few degrees
        self.speed = rng.uniform(0.5, 1.2)
        self.turn = (rng.uniform(0.1, 0.5), 2 * math.pi * rng.uniform(0.03, 0.1), rng.uniform(0, 2 * math.pi))
        self.sway = [(rng.uniform(0.01, 0.04), 2 * math.pi * rng.uniform(0.8, 1.2), rng.uniform(0, 2 * math.pi))
                     for _ in range(5)]  # lateral, vertical, roll, pitch, yaw wobble
        self.heading0 = rng.uniform(-math.pi, math.pi)
        self.duration = duration

    def joints(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        arg = self.freq * t + self.phase
        return self.centre + (self.amp * np.sin(arg)).sum(1), (self.amp * self.freq * np.cos(arg)).sum(1)

    def base(self, t: float):
        """Base position, rotation, and world linear and angular velocity at t."""
        a, w, ph = self.turn
        heading = self.heading0 + a / w * (math.sin(w * t + ph) - math.sin(ph))
        heading_rate = a * math.cos(w * t + ph)
        wob = [(A * math.sin(f * t + p), A * f * math.cos(f * t + p)) for A, f, p in self.sway]
        (lat, dlat), (up, dup), (roll, droll), (pitch, dpitch), (yaw, dyaw) = wob
        yaw, dyaw = heading + 3 * yaw, heading_rate + 3 * dyaw
        forward = np.array([math.cos(heading), math.sin(heading), 0.0])
        left = np.array([-math.sin(heading), math.cos(heading), 0.0])
        p = self._path(t) + lat * left + np.array([0, 0, 0.95 + up])
        v = self.speed * forward + dlat * left - lat * heading_rate * forward + np.array([0, 0, dup])
        Rz, Ry, Rx = (self.pin.rpy.rpyToMatrix(0, 0, yaw), self.pin.rpy.rpyToMatrix(0, 3 * pitch, 0),
                      self.pin.rpy.rpyToMatrix(3 * roll, 0, 0))
        ex, ey, ez = np.eye(3)
        omega = dyaw * ez + Rz @ (3 * dpitch * ey + Ry @ (3 * droll * ex))
        return p, Rz @ Ry @ Rx, v, omega

    def _path(self, t: float, steps: int = 200) -> np.ndarray:
        """The integral of speed * forward(heading(s)) over [0, t] (trapezoid on a fine grid)."""
        s = np.linspace(0.0, t, steps)
        a, w, ph = self.turn
        heading = self.heading0 + a / w * (np.sin(w * s + ph) - math.sin(ph))
        f = self.speed * np.stack((np.cos(heading), np.sin(heading)), -1)
        xy = np.trapezoid(f, s, axis=0) if t > 0 else np.zeros(2)
        return np.array([xy[0], xy[1], 0.0])

    def sample(self, t: float, extra: dict | None = None):
        """Link rotations [L,3,3] and world angular velocities [L,3], base position and velocity at t;
        extra: {joint: (amplitude, freq, phase)} moved on top (a joint the diagnosed model lacks)."""
        pin = self.pin
        p, R, v, omega = self.base(t)
        s, ds = self.joints(t)
        q, dq = pin.neutral(self.model), np.zeros(self.model.nv)
        q[:3], q[3:7] = p, pin.Quaternion(R).coeffs()
        dq[:3], dq[3:6] = R.T @ v, R.T @ omega
        q[self.index], dq[self.vindex] = s, ds
        for name, (A, f, ph) in (extra or {}).items():
            j = self.model.joints[self.model.getJointId(name)]
            q[j.idx_q], dq[j.idx_v] = A * math.sin(f * t + ph), A * f * math.cos(f * t + ph)
        pin.forwardKinematics(self.model, self.data, q, dq)
        pin.updateFramePlacements(self.model, self.data)
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        rot = np.stack([self.data.oMf[f].rotation for f in self.frames])
        w = np.stack([pin.getFrameVelocity(self.model, self.data, f, frame).angular for f in self.frames])
        return rot, w, p, v

    def series(self, time_: np.ndarray, extra: dict | None = None):
        out = [self.sample(float(t), extra) for t in time_]
        return tuple(np.stack(x) for x in zip(*out))


# ------------------------------------------------------------------------------ noise and effects
def coloured(kind: str, shape: tuple, rng: np.random.Generator, phi: float) -> np.ndarray:
    """Unit-variance noise along axis 0: white, AR(1) with coefficient phi, or 1/f (pink)."""
    e = rng.standard_normal(shape)
    if kind == "white":
        return e
    if kind == "ar1":
        x = np.empty(shape)
        x[0] = e[0]
        for k in range(1, shape[0]):
            x[k] = phi * x[k - 1] + math.sqrt(1 - phi ** 2) * e[k]
        return x
    spectrum = np.fft.rfft(e, axis=0)
    f = np.fft.rfftfreq(shape[0])
    f[0] = f[1]
    x = np.fft.irfft(spectrum / np.sqrt(f).reshape(-1, *([1] * (len(shape) - 1))), n=shape[0], axis=0)
    return (x - x.mean(0)) / x.std(0)


def expm(vectors: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors [...,3] -> [...,3,3]."""
    import pinocchio

    flat = vectors.reshape(-1, 3)
    return np.stack([pinocchio.exp3(v) for v in flat]).reshape(*vectors.shape[:-1], 3, 3)


def unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def draw(family: str, links, rng: np.random.Generator, moving: list[str]) -> Injected:
    """A random instance of a family: links, sizes (misalignment 5-30 deg, bias 0.5-3 deg/s, stream
    delay 20-100 ms, drift 0.5-3 deg/s, missing axis swinging 5-15 deg, sensor delay 30-100 ms)."""
    some = lambda k: [str(x) for x in rng.choice(links, k, replace=False)]  # noqa: E731
    k = int(rng.integers(1, 5))
    if family == "misalignment":
        return Injected(family, some(k), list(rng.uniform(5, 30, k)), "deg", dict(axes=[unit(rng) for _ in range(k)]))
    if family == "gyro_bias":
        return Injected(family, some(k), list(rng.uniform(0.5, 3, k)), "deg/s", dict(axes=[unit(rng) for _ in range(k)]))
    if family == "gyro_scale":
        return Injected(family, some(k), list(rng.choice([-1, 1], k) * rng.uniform(2, 8, k)), "%")
    if family == "stream_delay":
        return Injected(family, ["all"], [float(rng.uniform(20, 100))], "ms")
    if family == "heading_drift":
        return Injected(family, some(k), list(rng.choice([-1, 1], k) * rng.uniform(0.5, 3, k)), "deg/s")
    if family == "sensor_delay":
        return Injected(family, some(1), [float(rng.uniform(30, 100))], "ms")
    if family == "missing_axis":
        joint = str(rng.choice(MISSING_AXES))
        amp = float(rng.uniform(5, 15))
        return Injected(family, [joint.rsplit("_", 1)[0]], [amp], "deg", dict(
            joint=joint, motion=(amp * DEG, 2 * math.pi * float(rng.uniform(0.2, 1.0)), float(rng.uniform(0, 6.3)))))
    raise ValueError(family)


@dataclass
class Case:
    """One recording of the study: its seed, the families injected (none: clean) and the noise model."""

    seed: int
    families: tuple[str, ...]
    noise: str

    @property
    def group(self) -> str:
        return {0: "clean", 1: self.families[0] if self.families else ""}.get(len(self.families), "two effects")


def generate(case: Case, links, duration: float, rate: float, gyro_frame: str = "true"):
    """(recording with the effects, the same without them, the Injected list, noise levels).

    gyro_frame: the rotation that takes each gyro's sensor-frame rate into the world frame the
    recording stores: "true" (the study's from its start), the noise-free orientation, which no
    device has: the gyro and the orientations then disagree on the frame by the orientation noise n,
    a term n x w in their difference that a fast link's rate w makes large; "estimated", the
    recording's own (noisy) orientation, as a suit's software or any user of an IMU must."""
    from torchik.io.recording import Recording

    rng = np.random.default_rng(case.seed)
    import pinocchio

    m48 = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=48), pinocchio.JointModelFreeFlyer())
    moving = [m48.names[j] for j in range(2, m48.njoints)]
    dof = 66 if "missing_axis" in case.families else 48
    body = Body(dof, links, rng, moving, duration)
    injected = [draw(f, links, rng, moving) for f in case.families]
    extra = {i.extra["joint"]: i.extra["motion"] for i in injected if i.family == "missing_axis"}
    t = np.arange(0.0, duration, 1.0 / rate)
    R, w, p, v = body.series(t, extra)
    R0, w0 = (body.series(t)[:2]) if extra else (R.copy(), w.copy())
    R, w = R.copy(), w.copy()
    for inj in injected:  # the streams' timing first: they are the motion at another time
        if inj.family == "stream_delay":
            w = body.series(t - inj.sizes[0] * 1e-3, extra)[1]
        if inj.family == "sensor_delay":
            i = links.index(inj.targets[0])
            late = body.series(t - inj.sizes[0] * 1e-3, extra)
            R[:, i], w[:, i] = late[0][:, i], late[1][:, i]
    for inj in injected:
        for n, (link, size) in enumerate(zip(inj.targets, inj.sizes)):
            i = links.index(link) if link in links else -1
            if inj.family == "misalignment":
                R[:, i] = R[:, i] @ expm(inj.extra["axes"][n] * size * DEG)
            elif inj.family == "heading_drift":
                Rz = expm(np.outer(size * DEG * (t - t[0]), [0.0, 0.0, 1.0]))
                R[:, i], w[:, i] = Rz @ R[:, i], (Rz @ w[:, i, :, None])[..., 0]
    for inj in injected:  # a gyro's own errors, in the frame of the sensor as it sits
        for n, (link, size) in enumerate(zip(inj.targets, inj.sizes)):
            i = links.index(link) if link in links else -1
            if inj.family == "gyro_bias":
                w[:, i] += R[:, i] @ (inj.extra["axes"][n] * size * DEG)
            elif inj.family == "gyro_scale":
                w[:, i] *= 1.0 + size / 100
    sigma_o, sigma_g = float(rng.uniform(0.3, 1.0)), float(rng.uniform(0.005, 0.02))
    phi = float(rng.uniform(0.8, 0.98))
    noise_o = expm(sigma_o * DEG * coloured(case.noise, (len(t), len(links), 3), rng, phi))
    noise_g = sigma_g * coloured(case.noise, (len(t), len(links), 3), rng, phi)
    frame = noise_o if gyro_frame == "estimated" else np.eye(3)

    def make(R_, w_):
        return Recording(time=t, links=tuple(links), orientation=noise_o @ R_,
                         angular_velocity=(frame @ w_[..., None])[..., 0] + noise_g,
                         base_link="Pelvis", base_position=p, base_linear_velocity=v)

    return make(R, w), make(R0, w0), injected, dict(noise=case.noise, orientation_deg=sigma_o, gyro_rad_s=sigma_g,
                                                    phi=phi if case.noise == "ar1" else None)

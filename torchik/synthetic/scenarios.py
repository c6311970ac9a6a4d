"""Built-in synthetic scenarios with ground truth: t-pose, walking (4 km/h), running (10 km/h).

Joint trajectories are smooth periodic functions (a constant and two harmonics) with their exact
derivatives; amplitudes and phases follow the joint's role (hip and knee flexion, arm swing ...),
matched by name on the human models and on iCub, left and right in antiphase. The pelvis moves
forward at the gait's speed, bobbing at twice the stride frequency and swaying sideways. Targets
are what perfect sensors on every tracked link would give; `orientation_noise` (rad) and
`gyro_noise` (rad/s) add seeded sensor effects.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording
from ..method import so3
from ..method.kinematics import KinematicModel
from .motion import Motion, _rz_ry_rx, targets_from_motion


@dataclass(frozen=True)
class Gait:
    """speed (m/s), stride frequency (Hz), bob (m), sway (m), yaw (rad), and per-joint patterns:
    (name regex, offset rad, first-harmonic amplitude rad, second-harmonic amplitude rad, phase rad)."""

    speed: float
    frequency: float
    bob: float
    sway: float
    yaw: float
    patterns: tuple[tuple[str, float, float, float, float], ...]
    default_amplitude: float


_ARMS_DOWN = (
    (r"^jRightShoulder_rotx$", 1.4, 0.0, 0.0, 0.0),
    (r"^jLeftShoulder_rotx$", -1.4, 0.0, 0.0, 0.0),
    (r"^[rl]_shoulder_roll$", 0.6, 0.0, 0.0, 0.0),  # iCub: arms by the sides, inside its coupled limits
)
# The joints a gait swings, with their phase in the stride; each gait gives their amplitudes.
_SWING = (
    (r"Hip_roty$|hip_pitch$", 0.0),
    (r"Knee_roty$|knee$", -1.2),
    (r"Ankle_roty$|ankle_pitch$", -2.0),
    (r"Shoulder_roty$|shoulder_pitch$", math.pi),
    (r"Elbow_roty$|elbow$", math.pi - 0.5),
    (r"^jL5S1_rotz$|^jT9T8_rotz$|torso_yaw$", math.pi),
)


def _swinging(amplitudes) -> tuple:
    """Patterns from (first, second harmonic) amplitudes in _SWING's order, arms down."""
    return _ARMS_DOWN + tuple((regex, 0.0, h1, h2, phase) for (regex, phase), (h1, h2) in zip(_SWING, amplitudes))


SCENARIOS = {
    "tpose": Gait(0.0, 0.25, 0.003, 0.005, 0.01, ((r"^[rl]_shoulder_roll$", 1.5, 0.0, 0.0, 0.0),),
                  default_amplitude=0.01),
    "walking": Gait(4.0 / 3.6, 0.9, 0.02, 0.025, 0.05, _swinging(
        ((0.35, 0.05), (0.30, 0.25), (0.15, 0.08), (0.25, 0.02), (0.15, 0.03), (0.06, 0.0))), default_amplitude=0.03),
    "running": Gait(10.0 / 3.6, 1.4, 0.05, 0.02, 0.08, _swinging(
        ((0.55, 0.10), (0.55, 0.35), (0.25, 0.10), (0.45, 0.05), (0.25, 0.05), (0.10, 0.0))), default_amplitude=0.05),
}


def _joint_patterns(model: KinematicModel, gait: Gait, rng: np.random.Generator):
    """Per joint: offset, amplitudes of harmonics 1 and 2, phase. Left joints are half a cycle behind."""
    n = model.n_dof
    offset, a1, a2, phase = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for j, name in enumerate(model.joint_names):
        for pattern, o, h1, h2, ph in gait.patterns:
            if re.search(pattern, name):
                offset[j] += o
                a1[j], a2[j], phase[j] = max(a1[j], h1), max(a2[j], h2), ph
        if a1[j] == 0 and a2[j] == 0:
            a1[j], phase[j] = gait.default_amplitude, rng.uniform(0, 2 * math.pi)
        if re.search(r"Left|^l_", name):
            phase[j] += math.pi
    # keep the motion inside finite limits (the clinical ranges of Human48, iCub's)
    lower, upper = model.lower.cpu().double().numpy(), model.upper.cpu().double().numpy()
    finite = (upper - lower) < 19.9
    centre = np.where(finite, np.clip(offset, lower + 0.05, upper - 0.05), offset)
    room = np.where(finite, np.minimum(centre - lower, upper - centre) - 0.02, np.inf)
    scale = np.minimum(1.0, room / np.maximum(a1 + a2, 1e-12))
    return centre, a1 * scale, a2 * scale, phase


def _within_linear_limits(model: KinematicModel, s: torch.Tensor, margin: float = 1e-3) -> bool:
    if model.linear_limits is None:
        return True
    A, b = model.linear_limits.A.cpu().double(), model.linear_limits.b.cpu().double()
    return bool((s.double() @ A.T <= b - margin).all())


def scenario_motion(name: str, model: KinematicModel, duration: float = 10.0, rate: float = 100.0,
                    seed: int = 0) -> Motion:
    """The configuration trajectory of a scenario, with exact velocities. Motion tensors [T,1,...]."""
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r}; valid: {', '.join(SCENARIOS)}")
    if duration <= 0 or rate <= 0:
        raise InputError(f"duration and rate must be positive, got {duration} s at {rate} Hz")
    gait = SCENARIOS[name]
    rng = np.random.default_rng(seed)
    centre, a1, a2, phase = (torch.from_numpy(x) for x in _joint_patterns(model, gait, rng))
    kw: dict[str, Any] = dict(dtype=torch.float64)
    t = torch.arange(int(round(duration * rate)) + 1, **kw) / rate
    w = 2 * math.pi * gait.frequency
    arg = w * t[:, None] + phase  # [T,n]
    if not _within_linear_limits(model, centre[None]):
        raise InputError(f"scenario {name!r}: the neutral posture of {model.name} violates its coupled limits")
    for _ in range(20):  # shrink the swing until the whole motion respects the coupled limits too
        s = centre + a1 * torch.sin(arg) + a2 * torch.sin(2 * arg)
        if _within_linear_limits(model, s):
            break
        a1, a2 = 0.8 * a1, 0.8 * a2
    s_dot = a1 * w * torch.cos(arg) + 2 * a2 * w * torch.cos(2 * arg)
    rest = model(*model.zero_configuration(1), model.link_names, jacobian=False).position
    assert rest is not None  # forward gives positions
    height = float(-rest[0, :, 2].min())
    p = torch.stack((gait.speed * t, gait.sway * torch.sin(w * t), height + gait.bob * torch.sin(2 * w * t)), -1)
    p_dot = torch.stack((torch.full_like(t, gait.speed), gait.sway * w * torch.cos(w * t),
                         2 * gait.bob * w * torch.cos(2 * w * t)), -1)
    yaw, pitch = gait.yaw * torch.sin(w * t), 0.5 * gait.yaw * torch.sin(2 * w * t)
    roll = 0.5 * gait.yaw * torch.sin(w * t + 1)
    d_yaw = gait.yaw * w * torch.cos(w * t)
    d_pitch = gait.yaw * w * torch.cos(2 * w * t)
    d_roll = 0.5 * gait.yaw * w * torch.cos(w * t + 1)
    R, Rz, Ry = _rz_ry_rx(yaw, pitch, roll)
    ez = torch.tensor([0.0, 0.0, 1.0], **kw)
    omega = d_yaw[..., None] * ez + d_pitch[..., None] * Rz[..., :, 1] + d_roll[..., None] * (Rz @ Ry)[..., :, 0]
    velocity = torch.cat((p_dot, omega, s_dot), -1)
    return Motion(t, p[:, None], R[:, None], s[:, None], velocity[:, None])


def scenario(name: str, model: KinematicModel, links, duration: float = 10.0, rate: float = 100.0, seed: int = 0,
             orientation_noise: float = 0.0, gyro_noise: float = 0.0) -> Recording:
    """A scenario as a recording of `links` (orientation targets; the base link gives the position),
    with the true joint positions. Noise: rad (a random rotation per sample) and rad/s."""
    motion = scenario_motion(name, model, duration, rate, seed)
    links = tuple(links)
    targets = targets_from_motion(model, motion, links)
    R = targets.rotation[:, 0]
    w = targets.angular_velocity[:, 0]
    g = torch.Generator().manual_seed(seed + 1)
    if orientation_noise:
        R = so3.exp(orientation_noise * torch.randn(R.shape[:-1], generator=g, dtype=R.dtype)) @ R
    if gyro_noise:
        w = w + gyro_noise * torch.randn(w.shape, generator=g, dtype=w.dtype)
    meta = dict(source=f"torchik scenario {name}", scenario=name, model=model.name, frame_rate=rate, seed=seed,
                orientation_noise=orientation_noise, gyro_noise=gyro_noise, speed_m_s=SCENARIOS[name].speed)
    return Recording(time=motion.time.numpy(), links=links, orientation=R.numpy(), angular_velocity=w.numpy(),
                     base_link=model.base_link, base_position=targets.position[:, 0, 0].numpy(),
                     base_linear_velocity=targets.linear_velocity[:, 0, 0].numpy(),
                     joint_names=model.joint_names, joint_positions=motion.joint_positions[:, 0].numpy(), meta=meta)

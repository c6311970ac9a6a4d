"""Synthetic motions with exact ground truth: smooth configuration trajectories with analytic
velocities, and the targets a perfect sensor would give for them (poses from the kinematics,
velocities from J(q) nu). Used by the tests and, later, the built-in scenarios."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from ..method.kinematics import KinematicModel
from ..method.state import State, TargetSequence


@dataclass(frozen=True)
class Motion:
    """A configuration trajectory: time [T]; base_position [T,B,3]; base_rotation [T,B,3,3];
    joint_positions [T,B,n]; velocity [T,B,6+n] = (p_dot_B, omega_B world, s_dot)."""

    time: torch.Tensor
    base_position: torch.Tensor
    base_rotation: torch.Tensor
    joint_positions: torch.Tensor
    velocity: torch.Tensor

    def state(self, k: int) -> State:
        """The State at sample k."""
        return State(self.base_position[k].clone(), self.base_rotation[k].clone(),
                     self.joint_positions[k].clone(), self.velocity[k].clone())


def _rz_ry_rx(yaw, pitch, roll):
    """Rotation Rz(yaw) Ry(pitch) Rx(roll) and the three factors; angles [...] -> [...,3,3] each."""
    def axis_rotation(angle, i):
        c, s = torch.cos(angle), torch.sin(angle)
        one, zero = torch.ones_like(angle), torch.zeros_like(angle)
        if i == 0:
            rows = (one, zero, zero, zero, c, -s, zero, s, c)
        elif i == 1:
            rows = (c, zero, s, zero, one, zero, -s, zero, c)
        else:
            rows = (c, -s, zero, s, c, zero, zero, zero, one)
        return torch.stack(rows, -1).reshape(angle.shape + (3, 3))

    Rz, Ry, Rx = axis_rotation(yaw, 2), axis_rotation(pitch, 1), axis_rotation(roll, 0)
    return Rz @ Ry @ Rx, Rz, Ry


def periodic_motion(model: KinematicModel, duration: float, rate: float, batch: int = 1, frequency: float = 1.0,
                    joint_amplitude: float = 0.4, forward_speed: float = 1.1, seed: int = 0,
                    dtype=torch.float64) -> Motion:
    """A smooth, walking-like motion sampled at `rate` Hz: every joint oscillates about mid-range at
    `frequency` (and its second harmonic) with its own phase, the base moves forward at
    `forward_speed` m/s while swaying, bobbing, yawing, pitching and rolling. Velocities are exact.
    Joints with finite limits stay inside them. The motion is drawn on the CPU, so a seed gives the
    same motion on every device, and returned on the model's device."""
    g = torch.Generator().manual_seed(seed)
    kw: dict[str, Any] = dict(dtype=dtype)
    t = torch.arange(int(round(duration * rate)) + 1, **kw) / rate  # [T]
    n = model.n_dof
    w = 2 * math.pi * frequency
    phase = 2 * math.pi * torch.rand(batch, n, generator=g, **kw)
    lower, upper = model.lower.to(device="cpu", **kw), model.upper.to(device="cpu", **kw)
    finite = torch.isfinite(lower) & torch.isfinite(upper) & ((upper - lower) < 19.9)
    centre = torch.where(finite, (lower + upper) / 2, torch.zeros_like(lower))
    amplitude = torch.where(finite, torch.minimum(0.4 * (upper - lower), torch.full_like(lower, joint_amplitude)),
                            torch.full_like(lower, joint_amplitude))
    amplitude = amplitude * (0.5 + 0.5 * torch.rand(batch, n, generator=g, **kw))
    arg = w * t[:, None, None] + phase  # [T,B,n]
    s = centre + amplitude * (0.8 * torch.sin(arg) + 0.2 * torch.sin(2 * arg))
    s_dot = amplitude * w * (0.8 * torch.cos(arg) + 0.4 * torch.cos(2 * arg))

    tt = t[:, None].expand(-1, batch)
    p = torch.stack((forward_speed * tt, 0.05 * torch.sin(w * tt), 0.95 + 0.02 * torch.sin(2 * w * tt)), -1)
    p_dot = torch.stack((torch.full_like(tt, forward_speed), 0.05 * w * torch.cos(w * tt),
                         0.04 * w * torch.cos(2 * w * tt)), -1)
    yaw, pitch, roll = 0.3 * torch.sin(w * tt), 0.1 * torch.sin(2 * w * tt + 0.5), 0.08 * torch.sin(w * tt + 1.0)
    d_yaw, d_pitch = 0.3 * w * torch.cos(w * tt), 0.2 * w * torch.cos(2 * w * tt + 0.5)
    d_roll = 0.08 * w * torch.cos(w * tt + 1.0)
    R, Rz, Ry = _rz_ry_rx(yaw, pitch, roll)
    ez = torch.tensor([0.0, 0.0, 1.0], **kw)
    omega = (d_yaw[..., None] * ez + d_pitch[..., None] * Rz[..., :, 1] + d_roll[..., None] * (Rz @ Ry)[..., :, 0])
    velocity = torch.cat((p_dot, omega, s_dot), dim=-1)
    return Motion(*(x.to(model.device) for x in (t, p, R, s, velocity)))


def targets_from_motion(model: KinematicModel, motion: Motion, orientation_links, position_links=None,
                        chunk: int = 8192) -> TargetSequence:
    """The targets of a motion: link poses from the kinematics, link velocities J(q) nu.
    Returns a TargetSequence with [T,B,...] tensors. The kinematics run on about `chunk`
    configurations at a time: the Jacobians of a 10-minute recording at once would take gigabytes."""
    position_links = tuple(position_links if position_links is not None else (model.base_link,))
    orientation_links = tuple(orientation_links)
    T, B = motion.joint_positions.shape[:2]
    steps = max(1, chunk // B)
    if T > steps:
        parts = [targets_from_motion(model, Motion(*(x[k:k + steps] for x in vars(motion).values())),
                                     orientation_links, position_links, chunk) for k in range(0, T, steps)]
        return TargetSequence(*(torch.cat([getattr(p, name) for p in parts]) for name in vars(parts[0])))
    flat = lambda x: x.reshape((T * B,) + x.shape[2:])  # noqa: E731
    kin_p = model(flat(motion.base_position), flat(motion.base_rotation), flat(motion.joint_positions), position_links)
    kin_o = model(flat(motion.base_position), flat(motion.base_rotation), flat(motion.joint_positions), orientation_links)
    nu = flat(motion.velocity)[:, None, :, None]
    assert kin_p.jacobian is not None and kin_o.jacobian is not None  # asked for (the default)
    v = (kin_p.jacobian[:, :, :3] @ nu).squeeze(-1)
    omega = (kin_o.jacobian[:, :, 3:] @ nu).squeeze(-1)
    unflat = lambda x: x.reshape((T, B) + x.shape[1:])  # noqa: E731
    return TargetSequence(motion.time, unflat(kin_p.position), unflat(v), unflat(kin_o.rotation), unflat(omega))

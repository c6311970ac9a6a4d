"""Synthetic recordings that carry an undeclared effect, for testing the diagnosis.

Measurement effects are injected into a scenario's recording with `Effect.inject`. Model effects
need the motion: `recording_of` turns any Motion of a (truth) model into a Recording with the
scenarios' sensor noise, and `with_missing_dof` / `beyond_limit` make the motions.
"""

from __future__ import annotations

import math

import torch

from ...io.recording import Recording
from ...method import so3
from ...method.kinematics import KinematicModel
from ...synthetic.motion import Motion, targets_from_motion
from ...synthetic.scenarios import scenario_motion
from .joints import MissingDof


def recording_of(model: KinematicModel, motion: Motion, links, seed: int = 0, orientation_noise: float = 0.0,
                 gyro_noise: float = 0.0, meta: dict | None = None) -> Recording:
    """A motion's recording of `links` with seeded noise (rad per sample, rad/s), as scenarios make."""
    links = tuple(links)
    targets = targets_from_motion(model, motion, links)
    R, w = targets.rotation[:, 0], targets.angular_velocity[:, 0]
    g = torch.Generator().manual_seed(seed + 1)
    if orientation_noise:
        R = so3.exp(orientation_noise * torch.randn(R.shape[:-1], generator=g, dtype=R.dtype)) @ R
    if gyro_noise:
        w = w + gyro_noise * torch.randn(w.shape, generator=g, dtype=w.dtype)
    return Recording(time=motion.time.numpy(), links=links, orientation=R.numpy(), angular_velocity=w.numpy(),
                     base_link=model.base_link, base_position=targets.position[:, 0, 0].numpy(),
                     base_linear_velocity=targets.linear_velocity[:, 0, 0].numpy(), meta=dict(meta or {}))


def _swing(motion: Motion, j: int, angle: torch.Tensor, rate: torch.Tensor) -> Motion:
    s, v = motion.joint_positions.clone(), motion.velocity.clone()
    s[:, 0, j], v[:, 0, 6 + j] = angle, rate
    return Motion(motion.time, motion.base_position, motion.base_rotation, s, v)


def with_missing_dof(urdf: str, effect: MissingDof, amplitude: float, frequency: float, phase: float,
                     name: str = "walking", duration: float = 5.0, rate: float = 50.0, seed: int = 0):
    """The truth model (the URDF with `effect` added) and a scenario motion on it in which the added
    joint swings by amplitude sin(2 pi frequency t + phase) (rad)."""
    truth = KinematicModel.from_urdf(effect.augment(urdf), name="truth")
    motion = scenario_motion(name, truth, duration, rate, seed)
    j = truth.joint_names.index(effect.joint_name())
    t = motion.time
    w = 2 * math.pi * frequency
    return truth, _swing(motion, j, amplitude * torch.sin(w * t + phase), amplitude * w * torch.cos(w * t + phase))


def beyond_limit(model: KinematicModel, joint: str, excess: float, side: str = "lower", name: str = "walking",
                 duration: float = 5.0, rate: float = 50.0, seed: int = 0) -> tuple[Motion, float]:
    """A scenario motion in which `joint` is shifted to pass its `side` limit by `excess` rad at its
    extreme; returns the motion and the angle reached."""
    motion = scenario_motion(name, model, duration, rate, seed)
    j = model.joint_names.index(joint)
    s = motion.joint_positions[:, 0, j]
    if side == "lower":
        reached = float(model.lower[j]) - excess
        s = s - (float(s.min()) - reached)
    else:
        reached = float(model.upper[j]) + excess
        s = s + (reached - float(s.max()))
    return _swing(motion, j, s, motion.velocity[:, 0, 6 + j]), reached

"""Configuration limits as bounds on the configuration velocity.

Joint limits s_min <= s <= s_max become, for the step from s with time step dt,

    -min(b tanh(K_g (s - s_min)), (s - s_min)/dt)  <=  s_dot  <=  min(b tanh(K_g (s_max - s)), (s_max - s)/dt)

the paper's tanh bound (b: the largest joint rate, K_g: how early it slows down), capped by the
gap over dt so that an Euler step can never cross a limit. General linear limits A s <= b follow
the same rule row by row, on the distance to the row's boundary. A state already outside a limit
is brought back at a bounded rate, b tanh(K_g gap) < 0, rather than in one jump.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch


class Bounds(NamedTuple):
    """lower <= x <= upper, elementwise; +-inf where free."""

    lower: torch.Tensor
    upper: torch.Tensor


class LinearRows(NamedTuple):
    """G x <= h: G [B,m,N], h [B,m]."""

    G: torch.Tensor
    h: torch.Tensor


@dataclass(frozen=True)
class LimitSettings:
    """max_rate: b, the largest joint rate (rad/s); gain: K_g (1/rad); base_linear, base_angular:
    optional bounds on the base velocity components (m/s, rad/s), None for free."""

    max_rate: float = 20.0
    gain: float = 10.0
    base_linear: float | None = None
    base_angular: float | None = None


def _bound(gap: torch.Tensor, max_rate: float, gain: float, dt: torch.Tensor | float) -> torch.Tensor:
    """Largest rate towards a boundary at distance `gap` (negative outside): [...] -> [...]."""
    # outside (gap < 0) the cap is 0 and the smooth bound, negative there, is the smaller
    return torch.minimum(max_rate * torch.tanh(gain * gap), gap.clamp(min=0.0) / dt)


def joint_velocity_bounds(s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, settings: LimitSettings,
                          dt: torch.Tensor | float) -> Bounds:
    """Bounds on s_dot from joint limits. s: [B,n]; lower, upper: [n]; dt: [B,1] or a float -> [B,n] each."""
    gaps = torch.stack((upper - s, s - lower))  # [2,B,n]: towards the upper, towards the lower limit
    ub, towards_lower = _bound(gaps, settings.max_rate, settings.gain, dt).unbind()
    return Bounds(torch.minimum(-towards_lower, ub), ub)  # past one limit by more than the range, the way back wins


def linear_limit_bounds(s: torch.Tensor, A: torch.Tensor, b: torch.Tensor, settings: LimitSettings,
                        dt: torch.Tensor | float) -> torch.Tensor:
    """Right-hand side h of `A s_dot <= h` from `A s <= b`. s: [B,n]; A: [m,n]; b: [m]; dt: [B,1] -> h [B,m].

    Each row is scaled to unit norm so that `gain` and `max_rate` mean the same as for a joint.
    """
    norm = A.norm(dim=-1)  # [m]
    gap = (b - s @ A.T) / norm
    return norm * _bound(gap, settings.max_rate, settings.gain, dt)


def velocity_bounds(s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, settings: LimitSettings,
                    dt: torch.Tensor | float, base: Bounds | None = None) -> Bounds:
    """Bounds on the whole nu = (p_dot_B, omega_B, s_dot). s: [B,n] -> [B,6+n] each (inf where free).

    base: the base's bounds from `base_velocity_bounds` (computed here when not given).
    """
    joints = joint_velocity_bounds(s, lower, upper, settings, dt)
    base = base if base is not None else base_velocity_bounds(s.shape[0], settings, s.dtype, s.device)
    return Bounds(torch.cat((base.lower, joints.lower), dim=1), torch.cat((base.upper, joints.upper), dim=1))


def base_velocity_bounds(batch: int, settings: LimitSettings, dtype=torch.float64, device="cpu") -> Bounds:
    """The base velocity's bounds: [B,6] each, +-inf where free."""
    ub = torch.full((batch, 6), torch.inf, dtype=dtype, device=device)
    if settings.base_linear is not None:
        ub[:, :3] = settings.base_linear
    if settings.base_angular is not None:
        ub[:, 3:] = settings.base_angular
    return Bounds(-ub, ub)

"""The invariant every state the tracker returns keeps: finite, its base rotation orthonormal to
ROTATION_TOLERANCE, its joints no further beyond a limit than they were (by LIMIT_TOLERANCE). A subject
whose new state breaks it restarts from its targets (`DynamicalIK.step`), its step marked failed."""

from __future__ import annotations

import torch

from . import so3
from .state import State

ROTATION_TOLERANCE = 1e-12  # max |R^T R - I| of a returned base rotation (float64; see rotation_tolerance)
LIMIT_TOLERANCE = 1e-6  # rad or m a joint may go further beyond its limit in a step (the QP's tolerance)


def _beyond_limits(s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """How far joints s [B,n] are outside [lower, upper] ([n] or [B,n]); 0 inside. [B,n]"""
    return (lower - s).clamp(min=0.0) + (s - upper).clamp(min=0.0)


def rotation_tolerance(dtype: torch.dtype) -> float:
    """ROTATION_TOLERANCE, or 100 roundings of `dtype` where that is coarser (float32: 1.2e-5; an
    orthonormalised float32 rotation is off by a few 1e-7, and every state would fail 1e-12)."""
    return max(ROTATION_TOLERANCE, 100 * torch.finfo(dtype).eps)


def invariant_measure(state: State, rotation: torch.Tensor, joints_before: torch.Tensor, lower: torch.Tensor,
                      upper: torch.Tensor) -> torch.Tensor:
    """[B]: how far each subject's `state` (its base rotation orthonormalised as `rotation` [B,3,3]) is
    from breaking the invariant, in tolerances: above 1 (or NaN, for a state that is not finite) where
    it is broken. Joints are measured by how much further beyond a limit they went since
    `joints_before` [B,n] (a state given outside its limits is pulled in, not failed). No synchronisation."""
    R = rotation
    deviation = (R.transpose(-1, -2) @ R - so3.identity(R.dtype, R.device)).abs().flatten(1).amax(-1)  # [B]
    outward = _beyond_limits(state.joint_positions, lower, upper) - _beyond_limits(joints_before, lower, upper)  # [B,n]
    furthest = outward.amax(-1) if outward.shape[-1] else torch.zeros_like(deviation)  # [B]
    measure = torch.maximum(deviation / rotation_tolerance(R.dtype), furthest / LIMIT_TOLERANCE)
    # alpha 0 keeps NaN and Inf of any value in the state (0 * Inf is NaN)
    values = torch.cat((state.base_position, state.joint_positions, state.velocity), dim=1).sum(-1)
    return torch.add(measure, values, alpha=0.0)  # [B]


def broken_subjects(state: State, rotation: torch.Tensor, joints_before: torch.Tensor, lower: torch.Tensor,
                    upper: torch.Tensor) -> torch.Tensor | None:
    """[B] bool: the subjects whose `state` breaks the invariant (`invariant_measure` above 1 or NaN);
    None when no subject does.

    One number leaves the device, from a bound of the measure that costs a third of its operations:
    the joints' distance beyond their limits now (at least how much further they went) and every
    value of the state in one vector, scaled by its tolerance (0 for the values that need only be
    finite: 0 * Inf is NaN). Only when that bound fails is the measure itself computed."""
    R = rotation
    B = R.shape[0]
    scale = _scales(state.joint_positions.shape[1], state.velocity.shape[1], R.dtype, R.device)
    s = state.joint_positions
    bound = torch.cat((torch.baddbmm(so3.identity(R.dtype, R.device), R.transpose(-1, -2), R, beta=-1.0).view(B, 9),
                       s - s.clamp(lower, upper), state.base_position, state.velocity), dim=1)
    if float(bound.abs().mul_(scale).amax()) <= 1.0:  # False for NaN
        return None
    return ~(invariant_measure(state, rotation, joints_before, lower, upper) <= 1.0)


_SCALES: dict[tuple, torch.Tensor] = {}


def _scales(n: int, N: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """[9+n+3+N]: 1/tolerance for the rotation's deviation and the joints' distance beyond a limit,
    0 for the base position and the velocity (which need only be finite). Made once per shape."""
    key = (n, N, dtype, device)
    if key not in _SCALES:
        _SCALES[key] = torch.cat((torch.full((9,), 1.0 / rotation_tolerance(dtype)), torch.full((n,), 1.0 / LIMIT_TOLERANCE),
                                  torch.zeros(3 + N))).to(dtype=dtype, device=device)
    return _SCALES[key]

"""The invariant every state the tracker returns keeps: finite, its base rotation orthonormal to
ROTATION_TOLERANCE, its joints no further beyond a limit than they were (by LIMIT_TOLERANCE). A subject
whose new state breaks it restarts from its targets (`DynamicalIK.step`), its step marked failed."""

from __future__ import annotations

import torch

from . import so3
from .state import State

ROTATION_TOLERANCE = 1e-12  # max |R^T R - I| of a returned base rotation (float64; see rotation_tolerance)
LIMIT_TOLERANCE = 1e-6  # rad or m a joint may go further beyond its limit in a step (the QP's tolerance)


def rotation_tolerance(dtype: torch.dtype) -> float:
    """ROTATION_TOLERANCE, or 100 roundings of `dtype` where that is coarser (float32: 1.2e-5; an
    orthonormalised float32 rotation is off by a few 1e-7, and every state would fail 1e-12)."""
    return max(ROTATION_TOLERANCE, 100 * torch.finfo(dtype).eps)


def _beyond_limits(s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """How far joints s [B,n] are outside [lower, upper] ([n] or [B,n]); 0 inside. [B,n]"""
    return (lower - s).clamp(min=0.0) + (s - upper).clamp(min=0.0)


def broken_subjects(state: State, rotation: torch.Tensor, joints_before: torch.Tensor, lower: torch.Tensor,
                    upper: torch.Tensor) -> torch.Tensor | None:
    """[B] bool: the subjects whose `state` (its base rotation orthonormalised as `rotation` [B,3,3])
    is not finite, whose rotation is not orthonormal to `rotation_tolerance`, or whose joints went
    further beyond a limit than LIMIT_TOLERANCE since `joints_before` [B,n] (a state given outside
    its limits is pulled in, not failed); None when no subject does. One number leaves the device in
    the usual case, NaN and Inf propagating through its sums."""
    R = rotation
    deviation = so3.gram_deviation(R).abs().amax(-1)  # [B]
    outward = _beyond_limits(state.joint_positions, lower, upper) - _beyond_limits(joints_before, lower, upper)  # [B,n]
    furthest = outward.amax(-1) if outward.shape[-1] else torch.zeros_like(deviation)  # [B]
    measure = torch.maximum(deviation / rotation_tolerance(R.dtype), furthest / LIMIT_TOLERANCE)
    # alpha 0 keeps NaN and Inf of any value in the state (0 * Inf is NaN)
    values = torch.cat((state.base_position, state.joint_positions, state.velocity), dim=1).sum(-1)
    measure = torch.add(measure, values, alpha=0.0)  # [B]
    if float(measure.amax()) <= 1.0:  # False for NaN
        return None
    return ~(measure <= 1.0)

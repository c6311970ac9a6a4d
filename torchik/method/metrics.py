"""The paper's tracking metrics, per time step and subject.

MNTE  = 1/n_o sum_i tr(I - R_hat_i^T R_i) / 2          (mean of 1 - cos(angle): 0 to 2)
RMSE  = sqrt(1/n_o sum_i ||omega_i - omega_hat_i||^2 / 3)
Statistics over time (after the transient the paper discards) are `pipelines.evaluation`'s.

tr(I - R_hat^T R)/2 = 1 - cos(angle) spans 0 (equal) to 2 (half a turn apart), not 0 to 1 as the
paper's text says.
"""

from __future__ import annotations

import torch

from .residual import orientation_residual
from .so3 import sum3


def orientation_error(R_target: torch.Tensor, R_estimate: torch.Tensor,
                      residual: torch.Tensor | None = None) -> torch.Tensor:
    """tr(I - R_hat^T R)/2 = 1 - cos(angle) per rotation. R_target, R_estimate: [...,3,3] (R_estimate
    orthonormal) -> [...]; residual: `orientation_residual(R_target, R_estimate)` [...,3] when
    already computed (the tracker's step has it).

    Accurate to rounding relative to the value, also for tiny errors: (3 - tr)/2 cancels to
    +-1e-16 absolute (so a converged solver would show negative MNTE), whereas
    1 - cos = sin^2 / (1 + cos) uses the skew part, whose size is sin(angle) itself: the
    orientation residual's norm. Beyond 90 degrees (cos < 0) the trace formula has no
    cancellation and is used as it is.
    """
    # 1 + cos = (1 + tr(R_hat^T R)) / 2, the trace without the product
    one_plus_cos = (R_estimate * R_target).sum((-1, -2)).add_(1.0).mul_(0.5)
    if residual is None:
        residual = orientation_residual(R_target, R_estimate)
    sin_squared = sum3(residual.square())
    # where cos <= 0 the quotient (maybe 0/0) is not used
    return torch.where(one_plus_cos > 1.0, sin_squared / one_plus_cos, 2.0 - one_plus_cos)


def mnte(R_target: torch.Tensor, R_estimate: torch.Tensor, present: torch.Tensor | None = None) -> torch.Tensor:
    """Mean normalised trace error. R_target, R_estimate: [..., n_o, 3, 3] -> [...]. present [..., n_o]
    bool: the targets to average over (the others may hold anything, NaN included); NaN where none is."""
    if present is None:
        return orientation_error(R_target, R_estimate).mean(-1)
    R_target = torch.where(present[..., None, None], R_target, R_estimate)  # no NaN into the sums
    return _present_mean(orientation_error(R_target, R_estimate), present)


def angular_velocity_rmse(omega_target: torch.Tensor, omega_estimate: torch.Tensor,
                          present: torch.Tensor | None = None) -> torch.Tensor:
    """RMS angular-velocity error. omega_*: [..., n_o, 3] -> [...] rad/s; present as `mnte`'s."""
    if present is None:
        return ((omega_target - omega_estimate).square().sum(-1) / 3.0).mean(-1).sqrt()
    omega_target = torch.where(present[..., None], omega_target, omega_estimate)
    return _present_mean((omega_target - omega_estimate).square().sum(-1) / 3.0, present).sqrt()


def _present_mean(values: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
    """values [..., n] averaged over `present` [..., n]: 0/0, NaN, where none is."""
    return torch.where(present, values, 0.0).sum(-1) / present.sum(-1)

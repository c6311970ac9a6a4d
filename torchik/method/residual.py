"""Task residuals and corrected velocities: what the step asks the configuration velocity to do.

position:    r_p = p_target - p(q)                                   [B,n_p,3]
orientation: r_o = R_hat sk(R_hat^T R_target)^vee                    [B,n_o,3]
The orientation residual is in the world frame, the frame of the angular velocity it corrects;
its norm is sin(angle) of the error, so its gain sets the rate near convergence.
Corrected velocities: v* = v + K r. The error the paper's MNTE averages, 1 - cos(angle), is
`metrics.orientation_error`.
"""

from __future__ import annotations

import torch

from .so3 import sum3


def position_residual(p_target: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """p_target - p. p_target, p: [B,n,3] -> [B,n,3]."""
    return p_target - p


def orientation_residual(R_target: torch.Tensor, R_hat: torch.Tensor) -> torch.Tensor:
    """World-frame orientation residual R_hat sk(R_hat^T R_target)^vee.

    R_target, R_hat: [B,n,3,3] link-to-world (R_hat orthonormal) -> [B,n,3].
    Conjugating sk(R_hat^T R_target) by R_hat gives sk(R_target R_hat^T), as R_hat hat(v) R_hat^T =
    hat(R_hat v); with columns h_i of R_hat and t_i of R_target, R_target R_hat^T = sum_i t_i h_i^T,
    whose skew part's vector is (1/2) sum_i h_i x t_i: three cross products, no matrix product.
    Summed over i, its x component is (row 1 of R_hat).(row 2 of R_target) - (row 2).(row 1), and
    so on cyclically: six dot products of rows (half the time of torch's cross along a middle
    dimension, on a CPU).
    """
    h0, h1, h2 = R_hat.unbind(-2)  # rows [B,n,3]
    t0, t1, t2 = R_target.unbind(-2)
    x, y, z = sum3(h1 * t2 - h2 * t1), sum3(h2 * t0 - h0 * t2), sum3(h0 * t1 - h1 * t0)
    return 0.5 * torch.stack((x, y, z), -1)


def corrected_velocity(velocity: torch.Tensor, residual: torch.Tensor, gain: torch.Tensor | float) -> torch.Tensor:
    """v* = v + K r in one operation. velocity, residual: [B,n,3]; gain: a scalar, or per target [n]
    or [n,1] (the tracker keeps it as [n,1]) -> [B,n,3]."""
    if not isinstance(gain, torch.Tensor):
        return torch.add(velocity, residual, alpha=float(gain))
    return torch.addcmul(velocity, gain[:, None] if gain.dim() == 1 else gain, residual)

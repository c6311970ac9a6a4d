"""The paper's tracking metrics, per time step and subject.

MNTE  = 1/n_o sum_i tr(I - R_hat_i^T R_i) / 2          (mean of 1 - cos(angle): 0 to 2)
RMSE  = sqrt(1/n_o sum_i ||omega_i - omega_hat_i||^2 / 3)
Statistics are taken after a transient (the paper discards the first 2 s).
"""

from __future__ import annotations

import torch


def mnte(R_target: torch.Tensor, R_estimate: torch.Tensor) -> torch.Tensor:
    """Mean normalised trace error. R_target, R_estimate: [..., n_o, 3, 3] -> [...]."""
    trace = (R_estimate * R_target).sum((-1, -2))  # tr(R_hat^T R)
    return ((3.0 - trace) / 2.0).mean(-1)


def angular_velocity_rmse(omega_target: torch.Tensor, omega_estimate: torch.Tensor) -> torch.Tensor:
    """RMS angular-velocity error. omega_*: [..., n_o, 3] -> [...] rad/s."""
    return ((omega_target - omega_estimate).square().sum(-1) / 3.0).mean(-1).sqrt()


def summary(values: torch.Tensor, time: torch.Tensor, transient: float = 2.0) -> dict[str, float]:
    """Median, 99th percentile, mean and max of values [T,...] over t >= time[0] + transient
    (all samples when the sequence is shorter than that)."""
    keep = time >= time[0] + transient
    v = values[keep] if bool(keep.any()) else values
    v = v.flatten().double()
    return dict(median=float(v.median()), p99=float(v.quantile(0.99)), mean=float(v.mean()), max=float(v.max()))

"""Integration of the configuration from its velocity nu = (p_dot_B, omega_B world, s_dot).

Joints and base position: Euler, `s + dt s_dot`. Base rotation, either
- 'baumgarte' (the paper's): R_dot = R (S(R^T omega) + rho/2 ((R^T R)^-1 - I)), one Euler step;
  the second term pulls R back towards SO(3), so ||R^T R - I|| stays near |omega|^2 dt / rho;
- 'exp': R <- exp(dt S(omega)) R, exact for a constant omega and orthonormal to rounding.
Whatever the state holds, `orthonormalize` gives the rotation the kinematics and the outputs use.
"""

from __future__ import annotations

import torch

from . import so3

ROTATION_INTEGRATORS = ("baumgarte", "exp")


def baumgarte_step(R: torch.Tensor, omega: torch.Tensor, dt: torch.Tensor | float, rho: float) -> torch.Tensor:
    """One Euler step of Baumgarte-stabilised R_dot. R: [B,3,3]; omega: [B,3] world; dt: [B,1] or a
    float (the same for every subject) -> [B,3,3].

    R_dot = R S(R^T omega) + rho/2 (R^-T - R), which is the paper's law, as R (R^T R)^-1 = R^-T;
    the inverse transpose is the cofactor matrix over the determinant (its columns are the cross
    products of R's columns), cheaper than a general inverse.
    The drift E = R^T R - I decays by about (1 - rho dt) per Euler step, which diverges for
    rho dt > 2: rho is capped at 1/dt (the fastest decay a step can give), so a gain tuned at
    100 Hz stays stable at 30 Hz."""
    B = R.shape[0]
    body = (omega.unsqueeze(1) @ R @ so3.hat_basis(R.dtype, R.device)).view(B, 3, 3)  # S(R^T omega)
    columns = _COLUMN_CYCLES.get(R.device) or _COLUMN_CYCLES.setdefault(
        R.device, (torch.tensor([1, 2, 0], device=R.device), torch.tensor([2, 0, 1], device=R.device)))
    cofactor = torch.linalg.cross(R.index_select(-1, columns[0]), R.index_select(-1, columns[1]), dim=-2)
    determinant = (R * cofactor).sum((-2, -1), keepdim=True) / 3.0  # each column gives det R
    pull = cofactor / determinant - R  # R^-T - R
    if not isinstance(dt, torch.Tensor):
        step = float(dt)
        return torch.add(R, torch.add(R @ body, pull, alpha=0.5 * min(rho, 1.0 / step)), alpha=step)
    gain, steps = torch.clamp(1.0 / dt, max=rho)[..., None], dt[..., None]  # [B,1,1]
    return torch.addcmul(R, steps, torch.addcmul(R @ body, 0.5 * gain, pull))


_COLUMN_CYCLES: dict[torch.device, tuple[torch.Tensor, torch.Tensor]] = {}


def exponential_step(R: torch.Tensor, omega: torch.Tensor, dt: torch.Tensor | float) -> torch.Tensor:
    """R <- exp(dt hat(omega)) R. R: [B,3,3]; omega: [B,3] world; dt: [B,1] or a float -> [B,3,3].

    One Newton-Schulz iteration after the product removes the rounding that would otherwise
    accumulate (about 1e-16 per step, 1e-11 after 10^5 steps)."""
    R = so3.exp(dt * omega) @ R
    eye = so3.identity(R.dtype, R.device)
    return 0.5 * R @ (3.0 * eye - R.transpose(-1, -2) @ R)


# Newton-Schulz iterations that bring a deviation max |R^T R - I| below these to rounding (1e-16)
ITERATIONS = ((1e-13, 0), (1e-8, 1), (1e-4, 2), (0.1, 3))  # beyond the last: the SVD projection


def orthonormalize(R: torch.Tensor) -> torch.Tensor:
    """The nearest rotation to nearly orthonormal matrices. [...,3,3] -> [...,3,3].

    Newton-Schulz iterations X <- X (3I - X^T X)/2 converge quadratically (1e-4 -> 1e-8 -> 1e-16);
    far from SO(3), where they would not converge, the SVD projection.
    """
    eye = so3.identity(R.dtype, R.device)
    X = R if R.dim() == 3 else R.reshape(-1, 3, 3)
    M = X.transpose(-1, -2) @ X
    deviation = float((M - eye).abs().max()) if X.shape[0] else 0.0
    if deviation > ITERATIONS[-1][0]:
        return so3.project(R)
    iterations = next((count for below, count in ITERATIONS[:-1] if deviation < below), ITERATIONS[-1][1])
    for i in range(iterations):
        if i:
            M = X.transpose(-1, -2) @ X
        X = torch.baddbmm(X, X, M, beta=1.5, alpha=-0.5)  # X (3I - X^T X) / 2 in one call
    return X.reshape(R.shape)


def orthonormalize_unsynchronised(R: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`orthonormalize` without a synchronisation, for a captured step: every Newton-Schulz
    iteration is computed and the one `orthonormalize` stops at picked by torch.where (from the
    batch's largest deviation, as it does). R [B,3,3] -> (X [B,3,3], ok: a bool tensor, False where
    `orthonormalize` would project by the SVD instead, or the deviation is not finite)."""
    X, M = R, R.transpose(-1, -2) @ R
    deviation = (M - so3.identity(R.dtype, R.device)).abs().amax()
    iterates = [R]
    for _ in range(ITERATIONS[-1][1]):
        X = torch.baddbmm(X, X, M, beta=1.5, alpha=-0.5)
        M = X.transpose(-1, -2) @ X
        iterates.append(X)
    picked = iterates[-1]
    for below, count in reversed(ITERATIONS[:-1]):
        picked = torch.where(deviation < below, iterates[count], picked)
    return picked, deviation <= ITERATIONS[-1][0]


def integrate(p: torch.Tensor, R: torch.Tensor, s: torch.Tensor, nu: torch.Tensor, dt: torch.Tensor | float,
              rotation: str = "baumgarte", rho: float = 100.0):
    """Configuration after dt. p: [B,3], R: [B,3,3], s: [B,n], nu: [B,6+n], dt: [B,1] or a float -> (p, R, s)."""
    if not isinstance(dt, torch.Tensor):
        p_next, s_next = torch.add(p, nu[:, :3], alpha=float(dt)), torch.add(s, nu[:, 6:], alpha=float(dt))
    else:
        p_next, s_next = torch.addcmul(p, dt, nu[:, :3]), torch.addcmul(s, dt, nu[:, 6:])
    if rotation == "baumgarte":
        R_next = baumgarte_step(R, nu[:, 3:6], dt, rho)
    else:
        R_next = exponential_step(R, nu[:, 3:6], dt)
    return p_next, R_next, s_next

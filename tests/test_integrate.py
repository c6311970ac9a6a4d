"""integrate: Baumgarte keeps R near SO(3) at the level dt |omega|^2 / rho; exp keeps it exact; outputs
are orthonormal whatever the integrator."""

import torch

from torchik.method import so3
from torchik.method.integrate import baumgarte_step, exponential_step, orthonormalize


def spin(step, steps: int):
    """Rotate at |omega| = 1.16 rad/s (dt = 0.01) about a slowly turning axis; return ||R^T R - I|| over time."""
    R = torch.eye(3, dtype=torch.float64)[None]
    dt = torch.full((1, 1), 0.01, dtype=torch.float64)
    eye = torch.eye(3, dtype=torch.float64)
    t = 0.01 * torch.arange(steps, dtype=torch.float64)
    axis = torch.stack((0.4 * torch.cos(0.1 * t), 0.4 * torch.sin(0.1 * t), torch.ones_like(t)), -1)
    omegas = (1.16 * axis / axis.norm(dim=-1, keepdim=True))[:, None]  # [steps,1,3]
    errors = torch.empty(steps, dtype=torch.float64)
    for k in range(steps):
        R = step(R, omegas[k], dt)
        errors[k] = torch.linalg.matrix_norm(R[0].T @ R[0] - eye)
    return errors, R


def test_baumgarte_keeps_the_drift_bounded_at_the_level_the_step_implies():
    errors, R = spin(lambda R, w, dt: baumgarte_step(R, w, dt, rho=100.0), 30_000)
    level = 1.16 ** 2 * 0.01 / 100.0  # |omega|^2 dt / rho = 1.35e-4
    assert float(errors.max()) < 2 * level
    assert float(errors[-3_000:].max()) <= 1.01 * float(errors[:3_000].max())  # does not grow with time
    assert float((orthonormalize(R)[0].T @ orthonormalize(R)[0] - torch.eye(3, dtype=torch.float64)).abs().max()) < 1e-12


def test_baumgarte_step_is_the_papers_law_with_its_inverse():
    """R + dt R (S(R^T omega) + rho/2 ((R^T R)^-1 - I)) with a general inverse, on matrices off SO(3),
    for one dt for all and for one dt per subject (rho capped at 1/dt)."""
    g = torch.Generator().manual_seed(4)
    R = so3.random_rotation((6,), g) + 1e-2 * torch.randn(6, 3, 3, generator=g, dtype=torch.float64)
    omega = torch.randn(6, 3, generator=g, dtype=torch.float64)
    eye = torch.eye(3, dtype=torch.float64)
    # 0.03: rho dt > 1, where the cap takes over
    for dt in (0.01, 0.03, torch.tensor([[0.004], [0.01], [0.02], [0.03], [0.01], [0.05]], dtype=torch.float64)):
        rho = torch.clamp(1.0 / torch.as_tensor(dt, dtype=torch.float64), max=100.0)
        rho = rho[..., None] if rho.dim() else rho
        dt_ = dt[..., None] if isinstance(dt, torch.Tensor) else dt
        body = so3.hat((R.transpose(-1, -2) @ omega[..., None])[..., 0])
        literal = R + dt_ * (R @ (body + 0.5 * rho * (torch.linalg.inv(R.transpose(-1, -2) @ R) - eye)))
        assert (baumgarte_step(R, omega, dt, rho=100.0) - literal).abs().max() < 1e-14


def test_without_stabilisation_the_drift_grows_without_bound():
    errors, _ = spin(lambda R, w, dt: baumgarte_step(R, w, dt, rho=0.0), 10_000)
    deciles = errors.reshape(10, -1).max(dim=1).values
    assert bool((deciles[1:] > deciles[:-1]).all())  # it keeps growing ...
    assert float(errors[-1]) > 5.0  # ... far past anything Baumgarte allows


def test_the_exponential_map_stays_orthonormal_to_rounding():
    errors, _ = spin(exponential_step, 30_000)
    assert float(errors.max()) < 1e-12


def test_orthonormalize_gives_rotations_near_and_far_from_so3():
    R = so3.random_rotation((20,), torch.Generator().manual_seed(0))
    eye = torch.eye(3, dtype=torch.float64)
    for noise in (1e-4, 0.3):
        A = R + noise * torch.randn(20, 3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
        Q = orthonormalize(A)
        assert float((Q.transpose(-1, -2) @ Q - eye).abs().max()) < 1e-12
        assert torch.allclose(Q, so3.project(A), atol=1e-10)


def test_baumgarte_stays_stable_when_the_gain_is_too_high_for_the_time_step():
    """rho = 100/s tuned for 100 Hz, run at 30 Hz with a fast spin: the cap rho <= 1/dt keeps it bounded."""
    R = torch.eye(3, dtype=torch.float64)[None]
    dt = torch.full((1, 1), 1 / 30, dtype=torch.float64)
    omega = torch.tensor([[3.0, -5.0, 8.0]], dtype=torch.float64)
    for _ in range(3000):
        R = baumgarte_step(R, omega, dt, rho=100.0)
    assert float((R[0].T @ R[0] - torch.eye(3, dtype=torch.float64)).abs().max()) < 1.0

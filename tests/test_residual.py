"""residual: the orientation residual is sin(angle) about the world-frame error axis; errors are 1 - cos."""

import math

import torch

from torchik.method import so3
from torchik.method.metrics import orientation_error
from torchik.method.residual import corrected_velocity, orientation_residual, position_residual


def test_orientation_residual_is_sine_of_the_angle_about_the_world_error_axis():
    g = torch.Generator().manual_seed(0)
    R_hat = so3.random_rotation((50, 4), g)
    axis = torch.randn(50, 4, 3, generator=g, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.rand(50, 4, generator=g, dtype=torch.float64) * 3.0
    R_target = so3.exp(axis * angle[..., None]) @ R_hat  # rotated about a world axis
    r = orientation_residual(R_target, R_hat)
    assert torch.allclose(r, torch.sin(angle)[..., None] * axis, atol=1e-12)


def test_orientation_error_is_one_minus_cosine():
    R = so3.random_rotation((2,), torch.Generator().manual_seed(1))
    e = orientation_error(R, R)
    assert torch.allclose(e, torch.zeros(2, dtype=torch.float64), atol=1e-15)
    turned = so3.exp(torch.tensor([0.0, 0.0, math.pi / 3], dtype=torch.float64)) @ R
    assert torch.allclose(orientation_error(turned, R), torch.full((2,), 0.5, dtype=torch.float64))


def test_corrected_velocity_applies_per_target_gains():
    v = torch.zeros(1, 2, 3, dtype=torch.float64)
    r = position_residual(torch.ones(1, 2, 3, dtype=torch.float64), torch.zeros(1, 2, 3, dtype=torch.float64))
    out = corrected_velocity(v, r, torch.tensor([2.0, 5.0], dtype=torch.float64))
    assert torch.equal(out[0, :, 0], torch.tensor([2.0, 5.0], dtype=torch.float64))

"""metrics: MNTE and angular-velocity RMSE on cases with known values."""

import math

import torch

from torchik import so3
from torchik.metrics import angular_velocity_rmse, mnte, summary


def test_mnte_is_zero_for_identical_rotations_and_a_quarter_for_60_degrees_on_one_of_two_links():
    R = so3.random_rotation((5, 2), torch.Generator().manual_seed(0))
    assert torch.allclose(mnte(R, R), torch.zeros(5, dtype=torch.float64), atol=1e-15)
    turned = R.clone()
    turned[:, 1] = so3.exp(torch.tensor([0.0, math.pi / 3, 0.0], dtype=torch.float64)) @ R[:, 1]
    assert torch.allclose(mnte(turned, R), torch.full((5,), 0.25, dtype=torch.float64))


def test_rmse_of_a_known_angular_velocity_error():
    w = torch.zeros(2, 4, 3, dtype=torch.float64)
    w_hat = w.clone()
    w_hat[:, 0] = torch.tensor([3.0, 0.0, 0.0])  # |error| = 3 on one of four links
    assert torch.allclose(angular_velocity_rmse(w, w_hat), torch.full((2,), math.sqrt(9 / 3 / 4), dtype=torch.float64))


def test_summary_discards_the_transient():
    t = torch.arange(400, dtype=torch.float64) / 100
    v = torch.where(t < 2, 100.0, 1.0)
    assert summary(v, t) == dict(median=1.0, p99=1.0, mean=1.0, max=1.0)

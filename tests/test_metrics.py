"""metrics: MNTE and angular-velocity RMSE on cases with known values."""

import math

import torch

from torchik.method import so3
from torchik.method.metrics import angular_velocity_rmse, mnte, orientation_error
from torchik.pipelines.evaluation import summary


def test_mnte_is_zero_for_identical_rotations_and_a_quarter_for_60_degrees_on_one_of_two_links():
    R = so3.random_rotation((5, 2), torch.Generator().manual_seed(0))
    assert torch.allclose(mnte(R, R), torch.zeros(5, dtype=torch.float64), atol=1e-15)
    turned = R.clone()
    turned[:, 1] = so3.exp(torch.tensor([0.0, math.pi / 3, 0.0], dtype=torch.float64)) @ R[:, 1]
    # 1 - cos(60 deg) = 1/2 on one link of two
    assert torch.allclose(mnte(turned, R), torch.full((5,), 0.25, dtype=torch.float64))


def test_the_error_spans_zero_to_two_and_is_one_minus_the_cosine_at_every_angle():
    angles = torch.linspace(0.0, math.pi, 37, dtype=torch.float64)
    axis = torch.nn.functional.normalize(torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64), dim=0)
    R = so3.random_rotation((37,), torch.Generator().manual_seed(1))
    turned = so3.exp(angles[:, None] * axis) @ R
    error = orientation_error(turned, R)
    assert torch.allclose(error, 1.0 - torch.cos(angles), atol=1e-14)
    assert abs(float(error[-1]) - 2.0) < 1e-14  # half a turn: 2, not 1 as the paper's text says


def test_a_tiny_error_is_measured_to_its_own_precision_not_to_the_traces_rounding():
    R = so3.random_rotation((3, 4), torch.Generator().manual_seed(2))
    turned = R.clone()
    turned[:, 2] = so3.exp(torch.tensor([1e-9, 0.0, 0.0], dtype=torch.float64)) @ R[:, 2]
    expected = (1e-9) ** 2 / 2 / 4  # 1 - cos(t) = t^2/2, on one link of four
    # (3 - tr)/2 would give rounding noise of 1e-16 here, possibly negative
    assert torch.allclose(mnte(turned, R), torch.full((3,), expected, dtype=torch.float64), rtol=1e-6, atol=0.0)


def test_rmse_of_a_known_angular_velocity_error():
    w = torch.zeros(2, 4, 3, dtype=torch.float64)
    w_hat = w.clone()
    w_hat[:, 0] = torch.tensor([3.0, 0.0, 0.0])  # |error| = 3 on one of four links
    assert torch.allclose(angular_velocity_rmse(w, w_hat), torch.full((2,), math.sqrt(9 / 3 / 4), dtype=torch.float64))


def test_with_targets_missing_each_metric_is_the_mean_over_those_present_and_nan_only_where_none_is():
    R = so3.random_rotation((3, 4), torch.Generator().manual_seed(3))
    turned = R.clone()
    turned[:, 1] = so3.exp(torch.tensor([0.0, math.pi / 3, 0.0], dtype=torch.float64)) @ R[:, 1]  # 1 - cos = 1/2
    w, w_hat = torch.zeros(3, 4, 3, dtype=torch.float64), torch.zeros(3, 4, 3, dtype=torch.float64)
    w_hat[:, 1, 0] = 3.0
    present = torch.tensor([[True, True, True, True], [False, True, False, True], [False] * 4])
    turned[~present], w[~present] = torch.nan, torch.nan  # what a missing target holds
    m, r = mnte(turned, R, present), angular_velocity_rmse(w, w_hat, present)
    assert torch.allclose(m[:2], torch.tensor([0.5 / 4, 0.5 / 2], dtype=torch.float64))  # over 4, then 2 targets
    assert torch.allclose(r[:2], torch.tensor([math.sqrt(3 / 4), math.sqrt(3 / 2)], dtype=torch.float64))
    assert torch.isnan(m[2]) and torch.isnan(r[2])  # no target at all


def test_summary_discards_the_transient():
    t = torch.arange(400, dtype=torch.float64) / 100
    v = torch.where(t < 2, 100.0, 1.0)
    assert summary(v, t) == dict(median=1.0, p99=1.0, mean=1.0, max=1.0)


def test_summary_of_a_sequence_shorter_than_the_transient_uses_every_sample():
    t = torch.arange(50, dtype=torch.float64) / 100  # 0.5 s
    v = t.clone()
    assert summary(v, t)["max"] == float(v.max()) and summary(v, t)["median"] < 0.5

"""limits: one Euler step with velocities inside the bounds never crosses a limit."""

import torch

from torchik.method.limits import LimitSettings, joint_velocity_bounds, linear_limit_bounds, velocity_bounds


def test_a_step_inside_the_bounds_stays_inside_the_limits():
    g = torch.Generator().manual_seed(0)
    lower, upper = torch.full((200,), -1.0, dtype=torch.float64), torch.full((200,), 0.5, dtype=torch.float64)
    s = lower + (upper - lower) * torch.rand(50, 200, generator=g, dtype=torch.float64)
    for dt in (0.001, 0.01, 0.1):
        lb, ub = joint_velocity_bounds(s, lower, upper, LimitSettings(max_rate=50.0, gain=100.0),
                                       torch.full((50, 1), dt, dtype=torch.float64))
        assert bool((s + dt * ub <= upper + 1e-15).all()) and bool((s + dt * lb >= lower - 1e-15).all())
        assert bool((lb <= 0).all()) and bool((ub >= 0).all())


def test_tanh_shape_full_rate_far_away_zero_at_the_limit_and_bounded_return_from_outside():
    settings = LimitSettings(max_rate=3.0, gain=10.0)
    lower, upper = torch.tensor([-1.0], dtype=torch.float64), torch.tensor([1.0], dtype=torch.float64)
    s = torch.tensor([[0.0], [1.0], [1.5]], dtype=torch.float64)
    lb, ub = joint_velocity_bounds(s, lower, upper, settings, torch.full((3, 1), 1e-3, dtype=torch.float64))
    assert abs(float(ub[0, 0]) - 3.0) < 1e-7  # tanh(10) ~ 1
    assert float(ub[1, 0]) == 0.0  # at the limit
    assert -3.0 < float(ub[2, 0]) < 0.0 and float(lb[2, 0]) <= float(ub[2, 0])  # outside: back, at a bounded rate


def test_linear_limit_bounds_keep_a_step_feasible():
    A = torch.tensor([[1.0, -1.0], [0.5, 2.0]], dtype=torch.float64)
    b = torch.tensor([0.3, 1.0], dtype=torch.float64)
    s = torch.tensor([[0.0, 0.0], [0.2, -0.05]], dtype=torch.float64)
    dt = torch.full((2, 1), 0.01, dtype=torch.float64)
    h = linear_limit_bounds(s, A, b, LimitSettings(max_rate=100.0, gain=1000.0), dt)
    # the extreme velocity allowed for row 0 alone: along A[0], with A[0] s_dot = h[:, 0]
    s_dot = h[:, :1] * A[0] / (A[0] @ A[0])
    assert bool((((s + dt * s_dot) @ A.T)[:, 0] <= b[0] + 1e-15).all())


def test_the_base_is_free_unless_bounded():
    s = torch.zeros(1, 2, dtype=torch.float64)
    lim = torch.ones(2, dtype=torch.float64)
    lb, ub = velocity_bounds(s, -lim, lim, LimitSettings(), torch.full((1, 1), 0.01, dtype=torch.float64))
    assert bool(torch.isinf(ub[:, :6]).all())
    lb, ub = velocity_bounds(s, -lim, lim, LimitSettings(base_linear=2.0, base_angular=3.0),
                             torch.full((1, 1), 0.01, dtype=torch.float64))
    assert ub[0, :6].tolist() == [2.0] * 3 + [3.0] * 3 and lb[0, :6].tolist() == [-2.0] * 3 + [-3.0] * 3


def test_far_outside_a_narrow_range_the_bounds_still_admit_a_velocity():
    lower, upper = torch.tensor([0.0], dtype=torch.float64), torch.tensor([0.01], dtype=torch.float64)
    s = torch.tensor([[0.06]], dtype=torch.float64)
    lb, ub = joint_velocity_bounds(s, lower, upper, LimitSettings(), torch.full((1, 1), 0.01, dtype=torch.float64))
    assert bool((lb <= ub).all()) and float(ub[0, 0]) < 0  # heading back towards the range

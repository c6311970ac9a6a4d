"""targets: non-finite targets are dropped and counted, near-rotations projected, far ones refused;
a sequence checked at once finds clean exactly the steps that the step-by-step check leaves as they are."""

import pytest
import torch

from torchik import InputError, so3
from torchik.method.targets import Targets, check_targets, clean_steps, clean_targets


def make(B=2, n_p=1, n_o=3, seed=0) -> Targets:
    g = torch.Generator().manual_seed(seed)
    return Targets(torch.randn(B, n_p, 3, generator=g, dtype=torch.float64),
                   torch.randn(B, n_p, 3, generator=g, dtype=torch.float64),
                   so3.random_rotation((B, n_o), g), torch.randn(B, n_o, 3, generator=g, dtype=torch.float64))


def test_nan_targets_are_dropped_and_counted():
    t = make()
    t.rotation[1, 2, 0, 0] = float("nan")
    t.linear_velocity[0, 0, 1] = float("inf")
    clean = clean_targets(t)
    assert clean.dropped.tolist() == [1, 1]
    assert clean.orientation_valid.tolist() == [[True, True, True], [True, True, False]]
    assert clean.position_valid.tolist() == [[False], [True]]
    assert bool(torch.isfinite(clean.targets.rotation).all() and torch.isfinite(clean.targets.linear_velocity).all())


def test_nearly_orthonormal_rotations_are_projected_and_counted():
    t = make()
    t.rotation[0, 1] += 1e-5
    clean = clean_targets(t)
    assert clean.projected.tolist() == [1, 0]
    R = clean.targets.rotation[0, 1]
    assert float((R.T @ R - torch.eye(3, dtype=torch.float64)).abs().max()) < 1e-14


def test_a_matrix_far_from_a_rotation_is_refused_naming_it():
    t = make()
    t.rotation[1, 0] *= 2.0
    with pytest.raises(InputError, match="target rotation 0 of subject 1 is not a rotation"):
        clean_targets(t)


def test_shapes_are_checked_with_the_expected_shape_in_the_message():
    with pytest.raises(InputError, match=r"targets.rotation: expected shape \[2, 4, 3, 3\], got \[2, 3, 3, 3\]"):
        check_targets(make(), 1, 4, torch.float64, torch.device("cpu"))


def test_a_sequence_checked_at_once_agrees_with_the_check_of_each_step():
    steps = [make(seed=k) for k in range(6)]
    steps[1].rotation[0, 2, 1, 1] = float("nan")
    steps[2].angular_velocity[1, 0, 0] = float("-inf")
    steps[3].rotation[1, 1] += 1e-7  # projected: not clean
    steps[4].rotation[0, 0] += 1e-12  # within rounding: clean
    fields = [torch.stack([getattr(t, name) for t in steps]) for name in vars(steps[0])]
    each = [(c.all_valid and not bool(c.projected.any())) for c in map(clean_targets, steps)]
    assert each == [True, False, False, False, True, True]
    assert clean_steps(*fields).tolist() == each
    # a large batch's steps, checked a few at a time, as each step alone
    large = [make(B=3000, n_o=23, seed=k) for k in range(8)]
    large[6].rotation[2999, 22, 2, 2] = float("nan")
    fields_large = [torch.stack([getattr(t, name) for t in large]) for name in vars(large[0])]
    each_large = [c.all_valid for c in map(clean_targets, large)]
    assert clean_steps(*fields_large).tolist() == each_large == [True] * 6 + [False, True]
    # not targets over time (a rotation field without its 3 x 3): none is taken as checked, the steps say why
    assert not clean_steps(fields[0], fields[1], fields[2][..., 0], fields[3]).any()

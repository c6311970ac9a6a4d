"""so3: the rotation utilities are exact inverses of each other and match known rotations."""

import math

import torch

from torchik.method import so3


def test_hat_is_cross_product_and_vee_inverts_it():
    g = torch.Generator().manual_seed(0)
    w, x = torch.randn(2, 100, 3, generator=g, dtype=torch.float64)
    assert torch.allclose(so3.hat(w) @ x.unsqueeze(-1), torch.linalg.cross(w, x).unsqueeze(-1))
    assert torch.equal(so3.vee(so3.hat(w)), w)


def test_exp_log_round_trip_including_small_and_near_pi_angles():
    g = torch.Generator().manual_seed(1)
    axis = torch.randn(400, 3, generator=g, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.cat([torch.logspace(-9, -1, 100, dtype=torch.float64),
                       torch.rand(200, generator=g, dtype=torch.float64) * 3.1,
                       math.pi - torch.logspace(-8, -3, 100, dtype=torch.float64)])
    w = axis * angle[:, None]
    R = so3.exp(w)
    assert torch.allclose(R.transpose(-1, -2) @ R, torch.eye(3, dtype=torch.float64).expand_as(R), atol=1e-14)
    assert torch.allclose(so3.log(R), w, atol=1e-7)
    assert torch.allclose(so3.axis_angle(axis, angle), R, atol=1e-14)


def test_skew_vee_is_sine_times_axis():
    axis = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    R = so3.exp(axis * 2.0)
    assert torch.allclose(so3.skew_vee(R), math.sin(2.0) * axis)
    assert torch.allclose(so3.vee(so3.skew_part(R)), so3.skew_vee(R))


def test_rpy_matches_the_urdf_convention():
    r, p, y = 0.3, -0.7, 1.1
    expected = so3.exp(torch.tensor([0, 0, y])) @ so3.exp(torch.tensor([0, p, 0])) @ so3.exp(torch.tensor([r, 0, 0]))
    assert torch.allclose(so3.rpy_to_matrix(torch.tensor([r, p, y])), expected, atol=1e-6)


def test_project_gives_the_nearest_rotation():
    R = so3.random_rotation((50,), torch.Generator().manual_seed(2))
    noisy = R + 1e-3 * torch.randn(50, 3, 3, dtype=torch.float64)
    P = so3.project(noisy)
    assert torch.allclose(P.transpose(-1, -2) @ P, torch.eye(3, dtype=torch.float64).expand_as(P), atol=1e-13)
    assert torch.allclose(torch.linalg.det(P), torch.ones(50, dtype=torch.float64))
    assert (P - R).abs().max() < 3e-3
    assert torch.allclose(so3.project(R), R, atol=1e-13)


def test_quaternion_to_matrix_of_a_quarter_turn_about_z():
    q = torch.tensor([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], dtype=torch.float64)
    expected = torch.tensor([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
    assert torch.allclose(so3.quaternion_to_matrix(q), expected, atol=1e-15)


def test_matrix_to_rpy_inverts_rpy_to_matrix_also_at_gimbal_lock():
    R = so3.random_rotation((200,), torch.Generator().manual_seed(0))
    assert torch.allclose(so3.rpy_to_matrix(so3.matrix_to_rpy(R)), R, atol=1e-12)
    rpy = torch.tensor([[0.3, math.pi / 2, -1.1], [0.3, -math.pi / 2, -1.1], [0.2, 0.4, 3.0]], dtype=torch.float64)
    locked = so3.rpy_to_matrix(rpy)
    assert torch.allclose(so3.rpy_to_matrix(so3.matrix_to_rpy(locked)), locked, atol=1e-12)
    assert torch.allclose(so3.matrix_to_rpy(locked)[2], rpy[2], atol=1e-12)  # away from the lock: the same angles

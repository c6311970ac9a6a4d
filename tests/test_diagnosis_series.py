"""The gyro-against-orientations disagreement e (torchik/pipelines/diagnosis/series.py: central_rate).

Property: on a rotation whose axis moves (coning), central_rate(w) agrees with the central
difference of the orientations, log(R_{k+1} R_{k-1}^T) / 2h, to fourth order in the step h; the
Simpson mean alone leaves a second-order error whose mean over time does not vanish (it would read
as a gyro bias). Both sides come from a closed-form motion, not from torchik's kinematics:
R(t) = Rz(a t) Rx(b t), whose world-frame rate is a z + Rz(a t) b x.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchik.io.recording import angular_velocity_from_orientations
from torchik.pipelines.diagnosis.series import central_rate, simpson

A, B = 2.0, 5.0  # rad/s: a limb swinging at 5 rad/s about an axis that turns at 2 rad/s


def _coning(rate: float, seconds: float = 3.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(time [T], R [T,3,3], world-frame rate w [T,3]) of R(t) = Rz(a t) Rx(b t) sampled at `rate` Hz."""
    t = np.arange(0.0, seconds, 1.0 / rate)
    c, s = np.cos(A * t), np.sin(A * t)
    cb, sb = np.cos(B * t), np.sin(B * t)
    one, zero = np.ones_like(t), np.zeros_like(t)
    Rz = np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)
    Rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cb, -sb], -1), np.stack([zero, sb, cb], -1)], -2)
    w = np.stack([B * c, B * s, A * one], -1)  # a z + Rz(a t) (b x)
    return torch.from_numpy(t), torch.from_numpy(Rz @ Rx), torch.from_numpy(w)


def _disagreement(rate: float, with_coning: bool) -> torch.Tensor:
    """e [T-4,3] of consistent streams at `rate` Hz, the ends (one-sided differences) left out."""
    t, R, w = _coning(rate)
    w_fd = torch.from_numpy(angular_velocity_from_orientations(R[:, None].numpy(), t.numpy()))[:, 0]
    mean_rate = central_rate(w, t) if with_coning else simpson(w)
    return (mean_rate - w_fd)[2:-2]


@pytest.mark.parametrize("rate", [50.0, 100.0])
def test_the_coning_term_makes_consistent_streams_agree_to_fourth_order(rate):
    coarse, fine = _disagreement(rate, True), _disagreement(2 * rate, True)
    order = math.log2(float(coarse.norm(dim=-1).max()) / float(fine.norm(dim=-1).max()))
    assert order > 3.7, order
    assert float(coarse.norm(dim=-1).max()) < 1e-3 * B


def test_without_it_a_steady_second_order_rate_is_left_that_would_pass_for_a_gyro_bias():
    simpson_only, with_coning = _disagreement(50.0, False), _disagreement(50.0, True)
    # the Simpson mean's error has a steady part along the turning axis z: (h^2/3) a b^2 for this motion
    h = 1.0 / 50.0
    assert float(simpson_only[:, 2].mean()) == pytest.approx(h * h / 3.0 * A * B * B, rel=0.05)
    assert float(with_coning.mean(0).norm()) < 0.01 * float(simpson_only.mean(0).norm())

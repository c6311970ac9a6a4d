"""The integral form of a gyro's disagreement (torchik/pipelines/diagnosis/integral.py).

Properties: the likelihood ratio `agreement` of a constant turn of e about the vertical is far above
zero for the rate e carries and far below it for a rate e does not carry (a drift the gyro would
show and does not), at a noise of e that hides the constant sample by sample; the GLS fit recovers
the rate within three standard errors. The noise model of the block averages (a stationary part and
a random walk, what averaging takes off the walk included) is the covariance sampled from simulated
gyro and orientation noise; in it, the likelihood ratio of a bias fitted on pure noise passes the
significance threshold for under one link in a hundred, white or AR(1) noise, gyro's or orientations'
or both, once the walk is at least what the gyros share; a 1.1 deg/s bias under coloured noise of
1 deg/s passes. The frame a gyro's disagreement is integrated in (world or sensor) is the one the gyro's
rates were put in the world frame by: the recorded orientations or noise-free ones.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchik.io.recording import angular_velocity_from_orientations
from torchik.method import so3
from torchik.pipelines.diagnosis.effect import SIGNIFICANT
from torchik.pipelines.diagnosis.gyro import _bias
from torchik.pipelines.diagnosis.integral import (
    _covariances,
    agreement,
    integral_fit,
    integrated,
    quieter_frame,
    sensor_integral,
    shared_walk,
    spacing,
)
from torchik.pipelines.diagnosis.series import central_rate


def _disagreement(rate: float, seed: int = 0):
    """e [T,3] of a still gyro at 50 Hz for 12 s: -rate about the vertical plus differentiated
    orientation noise (0.5 deg) and the gyro's own white noise (0.01 rad/s); its orientations R
    [T,3,3] and the drift's regressor G [T,3,1] = -z."""
    g = torch.Generator().manual_seed(seed)
    time = torch.arange(600, dtype=torch.float64) / 50.0
    n = math.radians(0.5) * torch.randn(601, 3, generator=g, dtype=torch.float64)
    e = -rate * torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) - torch.diff(n, dim=0) * 50.0 \
        + 0.01 * torch.randn(600, 3, generator=g, dtype=torch.float64)
    G = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand(600, 3)[..., None]
    return e, torch.eye(3, dtype=torch.float64).expand(600, 3, 3), G, torch.ones(600, dtype=torch.bool), time


def test_agreement_for_the_rate_carried_and_against_one_not_carried():
    rate = math.radians(1.0)
    e, R, G, keep, time = _disagreement(rate)
    assert e[:, 2].std() > 10 * rate  # sample by sample the drift is hidden
    assert agreement(e, R, G, keep, time, torch.tensor([rate], dtype=e.dtype)) > 50
    still, *_ = _disagreement(0.0, seed=1)
    assert agreement(still, R, G, keep, time, torch.tensor([rate], dtype=e.dtype)) < -50


def test_the_fit_of_the_integral_finds_the_rate():
    rate = math.radians(1.0)
    e, _, G, keep, time = _disagreement(rate, seed=2)
    theta, cov, _ = integral_fit(*integrated(e, G, keep, time, spacing(time)))
    assert abs(float(theta[0]) - rate) < 3 * float(cov[0, 0].sqrt())


TIME = torch.arange(600, dtype=torch.float64) / 50.0  # 12 s at 50 Hz, as the study's recordings
EVERY = torch.ones(600, dtype=torch.bool)


def _noise(generator: torch.Generator, gyro: float, orientation: float, phi: float = 0.0, axes: int = 3,
           draws: int = 1) -> torch.Tensor:
    """e [draws,600,axes]: white or AR(1) (coefficient phi, unit variance) gyro noise of rms `gyro`
    (rad/s) less the central rate of orientation noise of rms `orientation` (rad) of the same colour."""
    def coloured(n):
        x = torch.randn(draws, n, axes, generator=generator, dtype=torch.float64)
        for k in range(1, n) if phi else ():
            x[:, k] = phi * x[:, k - 1] + math.sqrt(1 - phi ** 2) * x[:, k]
        return x
    return gyro * coloured(600) - orientation * torch.diff(coloured(601), dim=1) * 50.0


def test_the_noise_model_of_the_block_averages_is_their_sampled_covariance():
    g = torch.Generator().manual_seed(3)
    gyro, orientation, stride = 0.0176, math.radians(0.5), 25
    G = torch.ones(600, 1, 1, dtype=torch.float64)
    draws = _noise(g, gyro, orientation, axes=1, draws=3000)
    samples = torch.stack([integrated(e, G, EVERY, TIME, stride)[0][:, 0] for e in draws])
    sampled = samples.T @ samples / len(samples)
    t = integrated(draws[0], G, EVERY, TIME, stride)[2]
    stationary, walk = _covariances(t)
    model = orientation ** 2 / stride * stationary + gyro ** 2 * 0.02 * walk  # 25 independent samples a block
    assert torch.allclose(sampled, model, rtol=0.1, atol=0.1 * float(model.diagonal().min()))


@pytest.mark.parametrize("gyro, orientation, phi", [(0.0176, 0.0, 0.0), (0.0, math.radians(0.5), 0.0),
                                                    (0.0176, math.radians(0.5), 0.0), (0.01, math.radians(1.0), 0.9)])
def test_a_bias_fitted_on_noise_alone_is_seldom_significant(gyro, orientation, phi):
    """200 still gyros of one make, as a suit's: the bias' likelihood ratio, in the noise model whose
    walk is at least what the gyros share (their median), passes the threshold for under one in a
    hundred."""
    g = torch.Generator().manual_seed(4)
    I = torch.eye(3, dtype=torch.float64).expand(600, 3, 3)
    draws = _noise(g, gyro, orientation, phi, draws=200)
    walk = shared_walk([sensor_integral(e, I, EVERY, TIME, 25) for e in draws])
    biases = [_bias("link", e, I, EVERY, TIME, walk) for e in draws]
    assert np.mean([b.score > SIGNIFICANT for b in biases]) < 0.01


def test_the_walk_a_suit_s_gyros_share_is_their_noise_s_from_four_seconds_of_each():
    """Suits of 23 gyros of white noise 0.02 rad/s (a walk of 8e-6 rad^2/s in their integral) and
    0.3 deg of orientation noise, 4 s each (nine blocks): their joint restricted likelihood puts the
    walk within a factor 2 of the truth on each of eight suits, within 20 % at the median."""
    g = torch.Generator().manual_seed(7)
    I = torch.eye(3, dtype=torch.float64).expand(200, 3, 3)
    truth = 0.02 ** 2 * 0.02
    ratios = []
    for _ in range(8):
        draws = _noise(g, 0.02, math.radians(0.3), draws=23)[:, :200]
        ratios.append(shared_walk([sensor_integral(e, I, EVERY[:200], TIME[:200], 20) for e in draws]) / truth)
    assert all(0.5 < r < 2.0 for r in ratios)
    assert abs(np.median(ratios) - 1.0) < 0.2


def test_a_bias_of_a_degree_a_second_under_coloured_noise_is_significant():
    """AR(1) gyro noise of 1 deg/s (0.8 from one sample to the next) and 1 deg of orientation noise,
    as the study's 10100: a 1.1 deg/s bias, hidden sample by sample, passes on each of 20 draws."""
    g = torch.Generator().manual_seed(6)
    I = torch.eye(3, dtype=torch.float64).expand(600, 3, 3)
    draws = _noise(g, 0.0175, math.radians(1.0), 0.8, draws=20)
    walk = shared_walk([sensor_integral(e, I, EVERY, TIME, 25) for e in draws])
    bias = math.radians(1.1) * torch.tensor([0.6, -0.64, 0.48], dtype=torch.float64)
    assert float(draws[0].std()) > 10 * float(bias.norm())
    assert all(_bias("link", e + bias, I, EVERY, TIME, walk).score > SIGNIFICANT for e in draws)


@pytest.mark.parametrize("gyro_frame, quieter", [("noise-free", "sensor"), ("recorded", "world")])
def test_the_frame_a_gyro_integrates_quietly_in_is_the_one_its_rates_share_with_the_orientations(gyro_frame, quieter):
    """A link spinning at 3.7 rad/s about a fixed axis, orientations with 1 deg of white noise N: a
    gyro whose world-frame rates were put there by the noise-free orientations disagrees with the
    recorded ones by n x w, which telescopes only in the sensor frame; one put there by the recorded
    orientations (N w) only by their noise's own rate, which telescopes in the world frame."""
    g = torch.Generator().manual_seed(5)
    w = torch.tensor([3.0, 1.0, 2.0], dtype=torch.float64)
    R = so3.exp(TIME[:, None] * w)
    N = so3.exp(math.radians(1.0) * torch.randn(600, 3, generator=g, dtype=torch.float64))
    rates = w.expand(600, 3) if gyro_frame == "noise-free" else N @ w
    gyro = rates + 0.005 * torch.randn(600, 3, generator=g, dtype=torch.float64)
    R_m = N @ R
    e = central_rate(gyro, TIME) - torch.from_numpy(angular_velocity_from_orientations(R_m[:, None].numpy(),
                                                                                      TIME.numpy()))[:, 0]
    frame = quieter_frame(e[1:-1], R_m[1:-1], [R_m[1:-1]], EVERY[1:-1], TIME[1:-1], 25)  # no one-sided ends
    assert frame.name == quieter

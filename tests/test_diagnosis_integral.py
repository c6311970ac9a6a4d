"""The integral form of a gyro's disagreement (torchik/pipelines/diagnosis/integral.py).

Properties: the likelihood ratio `agreement` of a constant turn of e about the vertical is far above
zero for the rate e carries and far below it for a rate e does not carry (a drift the gyro would
show and does not), at a noise of e that hides the constant sample by sample; the GLS fit recovers
the rate within three standard errors.
"""

from __future__ import annotations

import math

import torch

from torchik.pipelines.diagnosis.integral import agreement, integral_fit, integrated, spacing


def _disagreement(rate: float, seed: int = 0):
    """e [T,1] of a gyro at 50 Hz for 12 s: -rate plus differentiated orientation noise (0.5 deg)
    and the gyro's own white noise (0.01 rad/s); the drift regressor G [T,1,1] = -1."""
    g = torch.Generator().manual_seed(seed)
    time = torch.arange(600, dtype=torch.float64) / 50.0
    n = math.radians(0.5) * torch.randn(601, 1, generator=g, dtype=torch.float64)
    e = -rate - torch.diff(n, dim=0) * 50.0 + 0.01 * torch.randn(600, 1, generator=g, dtype=torch.float64)
    return e, -torch.ones(600, 1, 1, dtype=torch.float64), torch.ones(600, dtype=torch.bool), time


def test_agreement_for_the_rate_carried_and_against_one_not_carried():
    rate = math.radians(1.0)
    e, G, keep, time = _disagreement(rate)
    assert e.std() > 10 * rate  # sample by sample the drift is hidden
    assert agreement(e, G, keep, time, torch.tensor([rate], dtype=e.dtype)) > 50
    still, *_ = _disagreement(0.0, seed=1)
    assert agreement(still, G, keep, time, torch.tensor([rate], dtype=e.dtype)) < -50


def test_the_fit_of_the_integral_finds_the_rate():
    rate = math.radians(1.0)
    e, G, keep, time = _disagreement(rate, seed=2)
    theta, cov, _ = integral_fit(*integrated(e, G, keep, time), spacing(time))
    assert abs(float(theta[0]) - rate) < 3 * float(cov[0, 0].sqrt())

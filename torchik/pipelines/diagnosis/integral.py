"""The integral form of a gyro's disagreement with its orientations, e = S(w_m) - w_fd(R_m) (analysis.py).

The orientations' noise n enters e differentiated, a blue noise whose integral is n(t) - n(t0):
told from a constant only over long spans, not sample by sample. So an effect that makes e a
constant in some frame (a gyro's bias in its own, a heading drift about the world's vertical) is
fitted on C(t) = int e dt = G(t) theta + noise, its integral, whose noise is modelled as
A (I + 1 1^T) + q min(t_i, t_j) at samples SPACING apart: a stationary part (the orientations' noise
at the span's start and now) and a random walk (the gyro's own noise, and n x w where a world-frame
gyro and the noisy orientations disagree on the frame).
"""

from __future__ import annotations

import torch

SPACING = 0.5  # s: the integrals' samples fitted on, apart by more than the orientations' noise is correlated


def spacing(time: torch.Tensor) -> int:
    """The stride, in samples of time [T], that puts the fitted samples SPACING apart."""
    return max(1, int(round(SPACING / float(torch.diff(time).median()))))


def integrated(e: torch.Tensor, G: torch.Tensor, keep: torch.Tensor, time: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(C [K,d], int G [K,d,k], t [K]) over the K samples where keep [T]: e [T,d] and the effect's
    regressor G [T,d,k] integrated from the span's first kept sample (which then holds nothing: its
    noise is the others' constant), and the time since it."""
    dt = float(torch.diff(time).median())
    C = torch.cumsum(torch.where(keep[:, None], e, 0.0), 0)[keep] * dt
    GI = torch.cumsum(torch.where(keep[:, None, None], G, 0.0), 0)[keep] * dt
    return C - C[0], GI - GI[0], time[keep] - time[keep][0]


def integral_fit(C: torch.Tensor, G: torch.Tensor, t: torch.Tensor, stride: int
                  ) -> tuple[torch.Tensor, torch.Tensor, tuple[float, float]]:
    """(theta [k], its covariance [k,k], the noise's (A, q)) of C = G theta + noise (C [T,d], G [T,d,k]
    at times t [T]) by generalised least squares at every stride-th sample: the noise first estimated
    from C, then from what the fit leaves (a constant would pass for a random walk)."""
    d, k = G.shape[-2:]
    theta = torch.zeros(k, dtype=C.dtype)
    for _ in range(2):
        noise = integral_noise(C - G @ theta, t, stride)
        W = whitener(noise, t[stride::stride])
        n = len(W)
        X = (W @ G[stride::stride].reshape(n, d * k)).reshape(d * n, k)
        y = (W @ C[stride::stride]).reshape(d * n)
        N = X.T @ X
        theta = torch.linalg.solve(N, X.T @ y)
    return theta, float((y - X @ theta).square().mean()) * torch.linalg.inv(N), noise


def integral_noise(C: torch.Tensor, t: torch.Tensor, stride: int) -> tuple[float, float]:
    """(A, q) of the integral's noise C [T,d] (times t [T]): Sigma = A (I + 1 1^T) + q min(t_i, t_j),
    a stationary part (the orientations' noise, at the span's start and now) and a random walk. An
    increment over a lag l past the noise's correlation has the variance 2 A + q l: both from the
    increments at one stride and at four."""
    lags = (stride, min(4 * stride, len(C) // 2))
    V = [float((C[lag:] - C[:-lag]).square().mean()) for lag in lags]
    span = float(t[lags[1]] - t[lags[0]]) if lags[1] > lags[0] else 1.0
    q = max((V[1] - V[0]) / span, 0.0)
    return max((V[0] - q * float(t[lags[0]])) / 2.0, 1e-6 * max(V[0], 1e-30)), q


def whitener(noise: tuple[float, float], t: torch.Tensor) -> torch.Tensor:
    """[n,n] W with W Sigma W^T = I, Sigma the covariance integral_noise gives at times t [n]."""
    A, q = noise
    Sigma = A * (torch.eye(len(t), dtype=t.dtype) + 1.0) + q * torch.minimum(t[:, None], t[None, :])
    return torch.linalg.inv(torch.linalg.cholesky(Sigma))


def agreement(e: torch.Tensor, G: torch.Tensor, keep: torch.Tensor, time: torch.Tensor, theta: torch.Tensor) -> float:
    """What the integral of e [T,d] (where keep [T]) says of the value theta [k] of an effect whose
    regressor is G [T,d,k]: 2 log of the likelihood ratio of its prediction against none, |W C|^2 -
    |W (C - G theta)|^2, in the noise model of what e's own fit leaves (which W whitens to unit
    variance: not the variance a wrong prediction leaves, which would cap how far below zero it can
    go). Far below zero where e contradicts theta (it predicts a drift of the integral that is not
    there), near zero where e cannot tell."""
    C, GI, t = integrated(e, G, keep, time)
    stride = min(spacing(time), len(C) // 4)
    if stride < 1:
        return 0.0
    W = whitener(integral_fit(C, GI, t, stride)[2], t[stride::stride])
    return float((W @ C[stride::stride]).square().sum() - (W @ (C - GI @ theta)[stride::stride]).square().sum())

"""The integral form of a gyro's disagreement with its orientations, e = S(w_m) - w_fd(R_m) (analysis.py).

The orientations' noise n enters e differentiated, a blue noise whose integral is n(t) - n(t0):
told from a constant only over long spans, not sample by sample. So an effect that makes e a
constant in some frame (a gyro's bias in its own, a heading drift about the world's vertical) is
fitted on C(t) = int e dt = G(t) theta + noise, its integral (averaged over blocks SPACING long),
whose noise is modelled as A (I + 1 1^T) + q min(t_i, t_j): a stationary part (the orientations' noise
at the span's start and now) and a random walk (the gyro's own noise, and n x w where a world-frame
gyro and the noisy orientations disagree on the frame).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import torch

SPACING = 0.5  # s: the integrals' blocks, longer than the orientations' noise is correlated
SHARES = 43  # the grid of the stationary part's share in the integral's noise


def spacing(time: torch.Tensor) -> int:
    """The stride, in samples of time [T], that makes the blocks SPACING long."""
    return max(1, int(round(SPACING / float(torch.diff(time).median()))))


def integrated(e: torch.Tensor, G: torch.Tensor, keep: torch.Tensor, time: torch.Tensor, stride: int
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(C [K,d], int G [K,d,k], t [K]): e [T,d] and the effect's regressor G [T,d,k] integrated over
    the samples where keep [T], averaged over blocks of `stride` of them, each less the first block's
    average, and the time since the first block's middle. K is one less than the whole blocks.

    The average, not a sample: the orientations' noise in C is as large as a bias' integral over
    seconds, and over a block it averages down by the blocks' length in its correlation times; a
    bias' straight line keeps its value at the block's middle."""
    dt = float(torch.diff(time).median())
    C = torch.cumsum(torch.where(keep[:, None], e, 0.0), 0)[keep] * dt
    GI = torch.cumsum(torch.where(keep[:, None, None], G, 0.0), 0)[keep] * dt
    t = time[keep]
    blocks = len(t) // stride
    mean = lambda x: x[:blocks * stride].reshape(blocks, stride, *x.shape[1:]).mean(1)  # noqa: E731
    C, GI, t = mean(C), mean(GI), mean(t)
    return C[1:] - C[0], GI[1:] - GI[0], t[1:] - t[0]


def integral_fit(C: torch.Tensor, G: torch.Tensor, t: torch.Tensor, walk_floor: float = 0.0
                 ) -> tuple[torch.Tensor, torch.Tensor, tuple[float, float]]:
    """(theta [k], its covariance [k,k], the noise's (A, q)) of C = G theta + noise (C [K,d], G [K,d,k]
    at times t [K], as `integrated` gives them) by generalised least squares, in the noise model
    Sigma = A (I + 1 1^T) + q min(t_i, t_j) (_covariances) of the largest restricted likelihood: a
    stationary part (the orientations' noise, in the first block and now) and a random walk (the
    gyro's noise), their ratio searched on a logarithmic grid and their scale profiled out.

    walk_floor (rad^2/s): the least walk rate q (shared_walk: what the recording's other gyros show);
    where the likelihood puts q below it, q is raised to it and A kept, and both are scaled up if what
    the fit leaves is larger than that model says."""
    theta, N, fixed, rss, free = _restricted(C, G, t)
    scale = rss / free
    nll = fixed + free * torch.log(scale.clamp(min=1e-300))
    j = int(nll.argmin())
    rho, s2 = float(_SHARE[j]), float(scale[j])
    noise = (max(s2 * rho, 1e-12 * s2), s2 * (1.0 - rho) / float(t[-1]))
    if noise[1] >= walk_floor:
        return theta[j], s2 * torch.linalg.inv(N[j]), noise
    # a dozen blocks of one gyro often put its walk at zero (the likelihood's boundary), and a walk read
    # as a constant A leaves the bias' standard error far too small: on the study's clean white-noise
    # recordings, hands "biased" by 0.1 deg/s at 13 standard errors
    return _gls(C, G, t, (noise[0], walk_floor))


def _restricted(C: torch.Tensor, G: torch.Tensor, t: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """integral_fit's pieces on the grid of the stationary part's share (_SHARE, S values), where
    Sigma = scale (share S + (1 - share) B / t_K): the GLS theta [S,k] and its normal matrix N
    [S,k,k], and -2 log of the restricted likelihood as fixed [S] + free log scale + rss [S] / scale
    (free: the values less the fitted parameters)."""
    n, d, k = G.shape
    share = _SHARE.to(C.dtype)
    logdet_B, P, D = _basis(tuple(float(x) for x in t))
    P, D = P.to(C.dtype), D.to(C.dtype)
    zC, zG = P @ C, (P @ G.reshape(n, d * k)).reshape(n, d, k)  # B and S both diagonal in this basis
    v = share[:, None] * D + (1.0 - share[:, None])  # [S,n] Sigma's eigenvalues there
    N = torch.einsum("si,idk,idl->skl", 1.0 / v, zG, zG)
    theta = torch.linalg.solve(N, torch.einsum("si,idk,id->sk", 1.0 / v, zG, zC)[..., None])[..., 0]  # [S,k]
    # restricted likelihood: a walk over a dozen blocks looks much like the line theta draws, and the
    # plain likelihood, blind to what the fit took, put the walk's rate 17 times too low on one of the
    # study's links (10100's L3, 0.52 deg/s of "bias" at a standard error of 0.05)
    rss = ((zC - torch.einsum("idk,sk->sid", zG, theta)).square() / v[..., None]).sum((1, 2))
    return theta, N, d * (logdet_B + torch.log(v).sum(-1)) + torch.logdet(N), rss, max(n * d - k, 1)


def _gls(C: torch.Tensor, G: torch.Tensor, t: torch.Tensor, noise: tuple[float, float]
         ) -> tuple[torch.Tensor, torch.Tensor, tuple[float, float]]:
    """integral_fit's answer in the given noise model (A, q), scaled by the variance of what the fit
    leaves (whitened) where that is above one."""
    n, d, k = G.shape
    W = whitener(noise, t)
    zC, zG = W @ C, (W @ G.reshape(n, d * k)).reshape(n, d, k)
    N = torch.einsum("idk,idl->kl", zG, zG)
    theta = torch.linalg.solve(N, torch.einsum("idk,id->k", zG, zC))
    s2 = max(float((zC - zG @ theta).square().sum()) / max(n * d - k, 1), 1.0)
    return theta, s2 * torch.linalg.inv(N), (s2 * noise[0], s2 * noise[1])


def shared_walk(integrals: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> float:
    """The walk rate q (rad^2/s) the gyros of one recording share: that of the largest restricted
    likelihood of all their integrals together (integrals: each gyro's (C, int G, t) in its sensor
    frame, with the bias' regressor: sensor_integral), each gyro's stationary part its own. The gyros
    of one suit are one make, and in the sensor frame the walk is their own noise and the
    orientations', whatever the link does: a dozen blocks tell one gyro's walk poorly (often zero, the
    likelihood's boundary), two dozen gyros together well. 0 without any."""
    total = torch.zeros(len(_WALKS), dtype=torch.float64)
    for C, G, t in integrals:
        _, _, fixed, rss, free = _restricted(C, G, t)
        share = _SHARE[:-1]  # a share of 1 has no walk
        s2 = _WALKS[:, None] * float(t[-1]) / (1.0 - share)  # [Q,S] the scale that puts the walk at q
        total += (fixed[:-1] + free * torch.log(s2) + rss[:-1].to(torch.float64) / s2).min(1).values
    return float(_WALKS[int(total.argmin())]) if integrals else 0.0


_WALKS = torch.logspace(-12.0, 0.0, 241, dtype=torch.float64)  # rad^2/s: shared_walk's grid, 12 % apart


def halves_stride(keep: torch.Tensor, time: torch.Tensor) -> int | None:
    """The stride, in samples, of a gyro's blocks: SPACING long, and at least four blocks in each half
    of the time (valid where keep [T]) past its first; None where a half has under 8 valid samples."""
    first = torch.arange(len(time)) < len(time) // 2
    shortest = min(int((keep & first).sum()), int((keep & ~first).sum()))
    return None if shortest < 8 else min(spacing(time), shortest // 5)


def subject_walk(e: torch.Tensor, R: torch.Tensor, keep: torch.Tensor, time: torch.Tensor, gyros: torch.Tensor
                 ) -> float:
    """shared_walk of one subject's gyros: e [T,L,3] their disagreement with the orientations R
    [T,L,3,3], valid where keep [T,L], for the links where gyros [L] (those with a gyro of their own)."""
    integrals = []
    for i in range(e.shape[1]):
        stride = halves_stride(keep[:, i], time)
        if bool(gyros[i]) and stride is not None:
            integrals.append(sensor_integral(e[:, i], R[:, i], keep[:, i], time, stride))
    return shared_walk(integrals)


def sensor_integral(e: torch.Tensor, R: torch.Tensor, keep: torch.Tensor, time: torch.Tensor, stride: int
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """integrated's (C, int G, t) of a gyro's disagreement e [T,3] with its orientations R [T,3,3]
    (valid where keep [T]) in the sensor frame, G the bias' regressor there (the identity)."""
    e_sensor, (G_sensor,) = in_sensor_frame(e, [R], R)
    return integrated(e_sensor, G_sensor, keep, time, stride)


def in_sensor_frame(e: torch.Tensor, G: list[torch.Tensor], R: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """A gyro's disagreement e [T,3] and world-frame regressors G ([T,3,k] each) in its sensor's frame
    (R [T,3,3] sensor to world)."""
    Rt = R.transpose(-1, -2)
    return (Rt @ e[..., None])[..., 0], [Rt @ g for g in G]


_RATIO = torch.logspace(-4.0, 4.0, SHARES - 2, dtype=torch.float64)  # A / (q t_K): either part may dominate
_SHARE = torch.cat((torch.zeros(1, dtype=torch.float64), _RATIO / (1.0 + _RATIO), torch.ones(1, dtype=torch.float64)))


@functools.lru_cache(maxsize=64)
def _basis(t: tuple[float, ...]) -> tuple[float, torch.Tensor, torch.Tensor]:
    """(log det B, P [K,K], D [K]) for blocks at times t: B = the walk's covariance / t_K = L L^T, and
    P = U^T L^-1 with L^-1 S L^-T = U diag(D) U^T (S the stationary part's), so that P Sigma P^T =
    share D + (1 - share) for every share at once. The same times come back round after round."""
    stationary, walk = _covariances(torch.tensor(t, dtype=torch.float64))
    L = torch.linalg.cholesky(walk / t[-1])
    Linv = torch.linalg.solve_triangular(L, torch.eye(len(t), dtype=torch.float64), upper=False)
    D, U = torch.linalg.eigh(Linv @ stationary @ Linv.T)
    return 2.0 * float(torch.log(torch.diagonal(L)).sum()), U.T @ Linv, D


def _covariances(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The covariances [K,K] of integrated's blocks at times t [K] of a unit stationary noise, I + 1 1^T
    (its block and the first's), and of a unit random walk: min(t_i, t_j) between blocks' averages
    less (s/6)(I + 1 1^T) for blocks s long, what averaging a walk over its block and the first's
    takes off (left in the stationary part's place, it needs a negative A where the walk dominates)."""
    both = torch.eye(len(t), dtype=t.dtype) + 1.0
    block = float(t[1] - t[0]) if len(t) > 1 else float(t[0])
    return both, torch.minimum(t[:, None], t[None, :]) - block / 6.0 * both


def whitener(noise: tuple[float, float], t: torch.Tensor) -> torch.Tensor:
    """[n,n] W with W Sigma W^T = I, Sigma the covariance of integral_fit's noise (A, q) at times t [n]."""
    A, q = noise
    stationary, walk = _covariances(t)
    Sigma = A * stationary + q * walk
    return torch.linalg.inv(torch.linalg.cholesky(Sigma))


def vertical_turn(time: torch.Tensor) -> torch.Tensor:
    """[T,3,1] the world-frame regressor of a heading drift's rate in e: a turn about the vertical
    that the orientations make and the gyro does not see gives e = -rate z."""
    return torch.tensor([0.0, 0.0, -1.0], dtype=time.dtype).expand(len(time), 3)[..., None]


class Frame(NamedTuple):
    """quieter_frame's answer: the frame's name, e [T,3] and the regressors [T,3,k] in it, the
    integral of e and G[0] there (integrated's (C, int G, t)) and its fit (integral_fit's theta,
    covariance and noise)."""

    name: str
    e: torch.Tensor
    G: list[torch.Tensor]
    integral: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    fit: tuple[torch.Tensor, torch.Tensor, tuple[float, float]]


def quieter_frame(e: torch.Tensor, R: torch.Tensor, G: list[torch.Tensor], keep: torch.Tensor, time: torch.Tensor,
                  stride: int, walk_floor: float = 0.0) -> Frame:
    """e [T,3], a gyro's disagreement with its orientations R [T,3,3] (valid where keep [T]), and the
    world-frame regressors G ([T,3,k] each) in the frame, "world" or "sensor", where the integral's
    noise (fitted with G[0], the walk at least walk_floor: integral_fit) is smaller at the end; with that fit.

    A recording's gyro rates are in the world frame, put there by some orientation: the recorded one
    (a suit's own fusion), and e = -dn/dt, whose integral telescopes in the world frame; or another
    (a reference's, a second fusion), which differs by the orientations' noise n, and e = -dn/dt + w x n
    = -R dn'/dt with n' = R^T n: its integral telescopes in the sensor frame, and in the world frame
    holds a random walk as large as n w (on a fast limb, several times the gyro's own noise)."""
    options = [("world", e, G), ("sensor", *in_sensor_frame(e, G, R))]
    frames = []
    for name, e_F, G_F in options:
        C, GI, t = integrated(e_F, G_F[0], keep, time, stride)
        fit = integral_fit(C, GI, t, walk_floor)
        A, q = fit[2]
        frames.append((2.0 * A + q * float(t[-1]), Frame(name, e_F, G_F, (C, GI, t), fit)))  # the noise at the end
    return min(frames, key=lambda option: option[0])[1]


def agreement(e: torch.Tensor, R: torch.Tensor, G: torch.Tensor, keep: torch.Tensor, time: torch.Tensor,
              theta: torch.Tensor) -> float:
    """What the integral of a gyro's disagreement e [T,3] with its orientations R [T,3,3] (where keep
    [T]) says of the value theta [k] of an effect whose regressor is G [T,3,k] (world frame): 2 log of
    the likelihood ratio of its prediction against none, |W C|^2 - |W (C - G theta)|^2, in the frame
    where e is quieter (quieter_frame) and the noise model of what e's own fit leaves (which W whitens
    to unit variance: not the variance a wrong prediction leaves, which would cap how far below zero
    it can go). Far below zero where e contradicts theta (it predicts a drift of the integral that is
    not there), near zero where e cannot tell."""
    stride = min(spacing(time), int(keep.sum()) // 5)
    if stride < 1:
        return 0.0
    frame = quieter_frame(e, R, [G], keep, time, stride)
    C, GI, t = frame.integral
    W = whitener(frame.fit[2], t)
    return float((W @ C).square().sum() - (W @ (C - GI @ theta)).square().sum())

"""What every candidate effect is, and how a fit is scored.

An effect is something real recordings carry and the model does not declare. Each kind states

- its signature: the residual it leaves (in the gyro's disagreement with its own orientations e,
  or in the orientation residual r = M delta, see analysis.py);
- a fit of its parameters from that residual, on the training half of the time;
- how to add it: `correct(recording)` undoes a measurement effect in the recording (what a
  calibration file does), `augment(urdf)` adds a model effect to the URDF; `inject` is the
  forward model, used to make synthetic recordings that carry it.

Score (a BIC difference, 2 log of the approximate Bayes factor, on held-out time): with y the
channel's residual on the test half, y - y_hat what is left once the effect fitted on the train
half is removed, sigma^2 the variance of what is left and tau its autocorrelation time (the
samples are not independent; n/tau are),

    score = (|y|^2 - |y - y_hat|^2) / (sigma^2 tau) - k log(n / tau)

k the parameters (for an effect with a value per sample, such as a joint angle, one per
independent sample). An effect is significant when score > SIGNIFICANT (Kass and Raftery's "very
strong" evidence), also once the noise's variance is taken from how the gains scatter across
stretches of the test time, where they scatter more than sigma^2 tau says (Score.calibrated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch

from ...io.recording import Recording
from .series import autocorrelation_time, lowpass

SIGNIFICANT = 10.0


@dataclass
class Score:
    """score (see module docstring), explained: share of the channel's test residual the effect
    removes, sigma2 and tau of what is left, n test values; chunks: what the effect explains,
    |y|^2 - |y - y_hat|^2, and predicted: the power it predicts, |y_hat|^2, on each of CHUNKS
    stretches of the test time (both in noise units, sigma2 tau)."""

    score: float
    explained: float
    sigma2: float
    tau: float
    n: int
    chunks: tuple[float, ...] = ()
    predicted: tuple[float, ...] = ()

    @property
    def dispersion(self) -> float:
        """How many times more the stretches' gains scatter than the noise the score assumes (see dispersion)."""
        return dispersion(self.chunks, self.predicted)

    @property
    def calibrated(self) -> float:
        """The score with the noise's variance as the stretches show it, where they scatter more than
        the score assumes (a quasi-likelihood correction): the gain divided by the dispersion, less the
        same penalty. A real effect keeps its score; the slow wander of coloured noise, which explains
        the residual in some stretches and not in others, loses it."""
        gain = sum(self.chunks)
        return gain / max(self.dispersion, 1.0) - (gain - self.score)


CHUNKS = 8  # stretches of the test time on which the explained part is compared
ABOVE_NOISE = 3.0  # an effect fitted sample by sample must move its angle this many times the noise's rms


def dispersion(gains, predicted) -> float:
    """The scatter of the stretches' gains g_c (what the effect explains on each, in noise units) over
    the scatter the score's noise model gives them. An effect's strength varies with the motion (a
    scale error or a delay shows only while its link moves), so the gain of stretch c is compared with
    the power the effect predicts there, P_c = |y_hat_c|^2: with y = y_hat + noise, g_c = P_c + 2 <noise,
    y_hat_c>, of variance 4 P_c. With m = sum g_c / sum P_c (the ratios g_c / P_c weighted by their
    inverse variance),

        dispersion = sum_c (g_c - m P_c)^2 / P_c / (4 (n - 1)),

    about 1 when the noise is what the score assumes, more when the gains come and go (noise slower or
    stronger along y_hat than sigma^2 tau says). Stretches where the effect predicts no power (below
    1e-9 of the largest) carry no information and are left out; fewer than three stretches give 1."""
    g, P = np.asarray(gains, dtype=np.float64), np.asarray(predicted, dtype=np.float64)
    if len(P) and P.max() > 0:
        keep = P > 1e-9 * P.max()
        g, P = g[keep], P[keep]
    if len(g) < 3:
        return 1.0
    m = float(g.sum() / P.sum())
    return float((np.square(g - m * P) / P).sum() / (4.0 * (len(g) - 1)))


def score(y: torch.Tensor, leftover: torch.Tensor, k: float, per_sample: int = 0, free: float = math.inf) -> Score:
    """Score of an effect on test data. y, leftover: [n_t, d] (time first); k parameters plus
    `per_sample` values fitted one per time sample (counted per independent sample, and at most
    `free`: those of a series smoothed to a bandwidth B over a time T are 2 B T)."""
    y, leftover = y.reshape(y.shape[0], -1), leftover.reshape(leftover.shape[0], -1)
    n_t, d = y.shape
    if n_t < 4 or d == 0:  # nothing to score on (too short, or an effect that predicts no residual)
        return Score(-math.inf, 0.0, math.nan, math.nan, n_t * d)
    rss0, rss1 = float(y.square().sum()), float(leftover.square().sum())
    tau = autocorrelation_time(leftover)
    sigma2 = max(rss1 / (n_t * d), 1e-30)
    n_eff = n_t * d / tau
    penalty = (k + min(per_sample / tau, free)) * math.log(max(n_eff, 2.0))
    parts = list(zip(y.tensor_split(min(CHUNKS, n_t)), leftover.tensor_split(min(CHUNKS, n_t))))
    chunks = tuple(float(a.square().sum() - b.square().sum()) / (sigma2 * tau) for a, b in parts)
    predicted = tuple(float((a - b).square().sum()) / (sigma2 * tau) for a, b in parts)
    return Score((rss0 - rss1) / (sigma2 * tau) - penalty, (rss0 - rss1) / max(rss0, 1e-30), sigma2, tau, n_t * d,
                 chunks, predicted)


def combine(*scores: tuple[Score, float]) -> Score:
    """One score from channels fitted jointly: (channel score computed with k = 0, k), the
    parameters counted once (the largest k given)."""
    k = max(kk for _, kk in scores)
    total = sum(s.score for s, _ in scores)
    n_eff = sum(s.n / s.tau for s, _ in scores)
    explained = sum(s.explained for s, _ in scores) / len(scores)
    chunks = tuple(sum(c) for c in zip(*(s.chunks for s, _ in scores)))
    predicted = tuple(sum(c) for c in zip(*(s.predicted for s, _ in scores)))
    return Score(total - k * math.log(max(n_eff, 2.0)), explained, scores[0][0].sigma2, scores[0][0].tau,
                 sum(s.n for s, _ in scores), chunks, predicted)


GUARD = 0.2  # s: the delay fits look 0.1 s either way; the tracker smooths over 1 / K, 0.05 s at its default


def halves(time: torch.Tensor, block: float = 1.0, transient: float = 1.0, guard: float | None = None
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """Train and test masks [T]: alternate blocks of `block` seconds (even train, odd test), so
    that both halves see every phase of a periodic motion and a drift's whole span. The first
    `transient` seconds, while the tracker converges from its initial posture, are in neither
    (none when the recording is shorter than three times that); a recording shorter than one and
    a half blocks alternates quarters instead.

    Samples within guard / 2 of a block's edge are in neither half. The fits low-pass within each
    block (lowpass_blocks), but the residual itself is the tracker's output, which smooths the
    measurements over about 1 / K (0.05 s at the default K = 20 / s), and the delay fits look up to 0.1 s
    away: without the gap a test sample would hold the noise of the training samples beside it (and
    the reverse), which makes the held-out score optimistic. The default guard is 0.2 s (at least
    four samples), at most half a block; guard = 0 gives every sample a half."""
    if guard is None:
        guard = max(GUARD, 4.0 * float(torch.diff(time).median())) if len(time) > 1 else 0.0
    start = float(time[0]) + (transient if float(time[-1] - time[0]) > 3 * transient else 0.0)
    position = (time - start) / block  # in blocks
    if float(position.max()) < 1.5:  # too short for a test block: alternate quarters
        block = max(float(time[-1] - start), 1e-9) / 4
        position = (time - start) / block
    index = torch.floor(position).long()
    phase = position - index  # where in its block, 0 to 1
    margin = min(0.5 * guard / block, 0.25)
    inside = (time >= start) & (phase >= margin) & (phase < 1.0 - margin)
    return (index % 2 == 0) & inside, (index % 2 == 1) & inside


def blocks(train: torch.Tensor, test: torch.Tensor) -> torch.Tensor:
    """[T] the run of halves() each sample belongs to: runs of train or test samples numbered in
    time, and every sample in neither half (a guard, the transient) given to the nearest run."""
    side = torch.where(train, 1, torch.where(test, 2, 0))
    marked = torch.nonzero(side > 0)[:, 0]
    if len(marked) == 0:
        return torch.zeros_like(side)
    run = torch.cat((torch.zeros(1, dtype=torch.long), torch.cumsum(side[marked][1:] != side[marked][:-1], 0)))
    after = torch.searchsorted(marked, torch.arange(len(side))).clamp(max=len(marked) - 1)
    before = (after - 1).clamp(min=0)
    t = torch.arange(len(side))
    nearest = torch.where((t - marked[before]).abs() <= (marked[after] - t).abs(), before, after)
    return run[nearest]


def lowpass_blocks(x: torch.Tensor, time: torch.Tensor, cutoff: float, train: torch.Tensor,
                   test: torch.Tensor) -> torch.Tensor:
    """lowpass (analysis.py) of x [T,...] within each run of blocks(train, test) on its own, so that
    no filtered train value holds a test sample and no filtered test value a train sample: filtered
    over the whole series, a test sample's value near a block edge would carry the noise of the
    training samples beside it (the filter's response beyond the 0.2 s guard still holds 2-3 % of
    its energy) and the held-out score would be optimistic."""
    label = blocks(train, test)
    edges = torch.nonzero(torch.diff(label))[:, 0] + 1
    starts = [0] + edges.tolist()
    ends = edges.tolist() + [len(label)]
    return torch.cat([lowpass(x[a:b], time[a:b], cutoff) for a, b in zip(starts, ends)])


@dataclass
class Effect:
    """A fitted effect: kind, target (a link or joint), params and their standard errors (JSON-ready
    lists or floats), n_params, its Score, and notes (what could not be identified)."""

    kind: str = ""
    target: str = ""
    params: dict = field(default_factory=dict)
    stderr: dict = field(default_factory=dict)
    n_params: int = 0
    fit: Score | None = None
    notes: str = ""

    model_effect = False  # True: added to the URDF (augment); False: to the measurements (correct)
    additive: ClassVar[tuple[str, ...]] = ()  # the parameters that compose by addition (refine)
    judged: ClassVar[tuple[str, ...]] = ()  # params set beside the held-out score (candidates.py): a refit keeps them
    error = "mnte"  # the overall error it must lower to be kept (Errors.overall's key)

    per_sample = False  # a value fitted at every sample (a joint angle): it explains noise on its test samples too
    floor: ClassVar[float] = 0.0  # the size, in `unit`, below which the effect matters to no one (relevance)
    unit: ClassVar[str] = ""

    @property
    def score(self) -> float:
        return self.fit.score if self.fit is not None else -math.inf

    def significant(self, threshold: float, noise_rms: float) -> str:
        """Why the fit is not significant ("" when it is): for a fixed set of parameters, its held-out
        score, calibrated on the scatter of its gains across stretches of the test time (see
        Score.calibrated), not above `threshold`; for an effect fitted sample by sample, its score
        not above `threshold` or an angle within ABOVE_NOISE times the noise's rms (rad, per axis: what
        a correct model leaves, analysis.noise_floor): what it explains on its test samples is
        theirs, and only its size tells it from the noise along its axis."""
        if self.score <= threshold:
            return f"score {self.score:.1f}, not above {threshold:g}"
        if self.per_sample:
            size = self.angle_rms()
            return "" if size > ABOVE_NOISE * noise_rms else (
                f"its angle's rms {math.degrees(size):.2f} deg is within {ABOVE_NOISE:g} times the noise's "
                f"{math.degrees(noise_rms):.2f} deg")
        assert self.fit is not None
        fit = self.fit
        return "" if fit.calibrated > threshold else (
            f"it explains the residual in some stretches of time and not in others: their gains scatter "
            f"{fit.dispersion:.1f} times more than the noise the score assumes, so corrected its score is "
            f"{fit.calibrated:.1f}, not above {threshold:g} (the noise's slow wander)")

    def angle_rms(self) -> float:
        """The rms (rad) of what a per-sample effect moves (per_sample effects define it)."""
        return math.inf

    def size(self, dt: float) -> float:
        """The effect's size in `unit` (the families define it; dt: the recording's sample period, s)."""
        return math.inf

    def relevance_floor(self, dt: float) -> float:
        """The size below which the effect matters to no one, in `unit` (`floor`, unless it depends on dt)."""
        return self.floor

    def below_floor(self, dt: float) -> str:
        """Why the effect, however significant, is too small to matter (\"\" when it is not): its size under
        the family's floor (`relevance_floor`). Significance says the data show it; the floor says whether
        anyone should care: a gyro scale error of 0.1 % can be significant over 12 s of a fast limb and
        changes no joint angle a researcher reports. Such effects are listed as negligible, never added."""
        size, floor = self.size(dt), self.relevance_floor(dt)
        if not math.isfinite(size) or size >= floor:
            return ""
        return f"{size:.3g} {self.unit}, below the {floor:.3g} {self.unit} that matters"

    def directions(self, name: str) -> np.ndarray:
        """[size, k] the directions in which the data determine parameter `name` (its values flattened):
        a joint fit moves it only along them (jointfit.py). All of them, unless the effect knows better."""
        return np.eye(np.asarray(self.params[name]).size)

    def overlaps(self, other: "Effect") -> bool:
        """Whether the two would correct the same thing (same kind, same target or one of them on all)."""
        return self.kind == other.kind and (self.target == other.target or "all" in (self.target, other.target))

    def implausible(self) -> str:
        """Why the fitted parameters are beyond what this effect can be ("" when they are not): a
        linearised fit can take a large residual of another cause for an absurd value of this one."""
        return ""

    def correct(self, recording: Recording) -> Recording:
        """The recording with the effect removed."""
        return self.apply(recording, -1.0)

    def inject(self, recording: Recording) -> Recording:
        """The recording as a sensor with this effect would give it."""
        return self.apply(recording, 1.0)

    def apply(self, recording: Recording, sign: float) -> Recording:
        """The effect added (sign 1) or removed (sign -1): measurement effects define it."""
        return recording

    def augment(self, urdf: str) -> str:
        """The URDF with the effect added (model effects)."""
        return urdf

    def refine(self, update: "Effect") -> "Effect":
        """This effect composed with a fitted correction `update` of the same kind and target (a
        Gauss-Newton step: the fit is linearised and the tracker absorbs part of an effect). By
        default the `additive` parameters add up; the standard errors are the update's."""
        for name in self.additive:
            self.params[name] = (np.asarray(self.params[name]) + np.asarray(update.params[name])).tolist()
        self.stderr = update.stderr
        return self

    def within_error(self) -> bool:
        """Whether this fit, taken as a correction (a refine step's update), moves every parameter by no
        more than its standard error: the data cannot tell the refined effect from the one in place, so
        applying it and re-tracking (a second of a 12 s recording) would change nothing they show."""
        for name, sd in self.stderr.items():
            if name in self.params and np.any(np.abs(np.asarray(self.params[name], dtype=np.float64))
                                              > np.asarray(sd, dtype=np.float64)):
                return False
        return bool(self.stderr)

    def summary(self) -> str:
        return f"{self.kind} at {self.target}"

    def to_json(self) -> dict:
        return dict(kind=self.kind, target=self.target, params=self.params, stderr=self.stderr,
                    n_params=self.n_params, score=None if self.fit is None else self.fit.score,
                    explained=None if self.fit is None else self.fit.explained, notes=self.notes)


def replace(recording: Recording, **changes) -> Recording:
    """A copy of `recording` with some arrays replaced (validated again)."""
    fields: dict[str, Any] = dict(time=recording.time, links=recording.links, orientation=recording.orientation,
                  angular_velocity=recording.angular_velocity, base_link=recording.base_link,
                  base_position=recording.base_position, base_linear_velocity=recording.base_linear_velocity,
                  joint_names=recording.joint_names, joint_positions=recording.joint_positions,
                  meta=dict(recording.meta))
    fields.update(changes)
    return Recording(**fields)


def rotation_about(axis, angle) -> np.ndarray:
    """R = exp(angle * axis), axis [3] unit, angle [T] -> [T,3,3] (numpy)."""
    from ...method import so3

    axis = torch.as_tensor(np.asarray(axis, dtype=np.float64))
    angle = torch.as_tensor(np.asarray(angle, dtype=np.float64))
    return so3.exp(angle[..., None] * axis).numpy()


def shift(values: np.ndarray, time: np.ndarray, delay: float, rotations: bool = False) -> np.ndarray:
    """values [T,...] taken at t + delay (linear interpolation; slerp for rotations [T,3,3]); the
    ends held. A stream that lags by `delay` is corrected by shift(x, t, +delay)."""
    from ...method import so3

    x = np.interp(time + delay, time, np.arange(len(time), dtype=np.float64))
    k = np.clip(np.floor(x).astype(int), 0, len(time) - 2)
    a = np.clip(x - k, 0.0, 1.0)
    lo, hi = values[k], values[k + 1]
    if not rotations:
        return lo + a.reshape(-1, *([1] * (values.ndim - 1))) * (hi - lo)
    R0, R1 = torch.from_numpy(lo), torch.from_numpy(hi)
    step = so3.log(R1 @ R0.transpose(-1, -2))
    return (so3.exp(torch.from_numpy(a).view(-1, *([1] * (step.dim() - 1))) * step) @ R0).numpy()

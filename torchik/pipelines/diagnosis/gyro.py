"""Effects of a gyro against its own orientations: bias, scale error, and a delay between the two
streams. Their signature is e = S(w_m) - w_fd(R_m) (analysis.py), which needs no model:

- bias b, constant in the sensor frame:          e = R_m b
- scale error kappa (w_m = (1 + kappa) w):       e = kappa / (1 + kappa) S(w_m)
- gyro late by d (w_m(t) = w(t - d)):            S(w_m)(t + d) = w_fd(t)

All in the world frame, as recordings store angular velocity. Orientation noise, differentiated,
makes e noisy at high frequencies, where these effects have little power: both sides of the scale
and delay fits are low-passed at `cutoff` (linear, so the parameters are unchanged). A bias is
fitted on e's integral instead (_bias): the differentiated noise telescopes there, and a bias of a
degree per second, far below e's noise sample by sample, shows as the orientations' change over
seconds. Fits are closed form: a regression, and a lag search refined by a parabola.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ...io.recording import Recording
from .analysis import Analysis
from .effect import Effect, Score, lowpass_blocks, replace, score, shift
from .integral import halves_stride, integrated, quieter_frame, subject_walk, vertical_turn, whitener
from .placement import DELAY_FLOOR, MAX_DELAY
from .series import simpson

MAX_SCALE = 0.1  # a gyro whose scale is off by more than this is broken, not miscalibrated
# deg/s: a MEMS gyro's zero-rate offset before any calibration is within +-20 deg/s by its datasheet
# (InvenSense MPU-6000/6050, "initial ZRO tolerance"; Bosch BMI160 +-10 deg/s); beyond, a unit or axis error
MAX_BIAS = 25.0
# Relevance floors (Effect.below_floor): what matters to a researcher reporting joint angles.
# A bias of 0.2 deg/s turns an integrated heading by 2 deg over a 10 s trial (the misalignment's
# floor, placement.py, is 1 deg) and is the order of a calibrated MEMS gyro's in-run bias; below it
# a gyro's bias changes no joint angle anyone reports.
BIAS_FLOOR = 0.2  # deg/s
# A tilt-correcting filter pulls its orientations toward what its accelerometer says is up, and on a
# segment that accelerates (a foot, a shank) the walk's accelerations its body model leaves in the
# accelerometer pull the tilt back and forth: the gyro's disagreement with its own orientations wanders
# from one two-second block to the next by a degree per second on a walking foot, against a tenth or two
# on the trunk (the orientations' noise). That pull has a constant part too, of the order of a quarter to
# a third of its wander (a Mahony filter leaving 3 % of the walk's accelerations: 0.2-0.4 deg/s on the
# feet of experiments/sensor_physics.py's walks, none injected), which no data tell from a bias. A
# bias under WANDER_SHARE of the wander is the filter's as much as the gyro's: listed, not added.
WANDER_SHARE = 0.5
WANDER_BLOCK = 2.0  # s
# A scale error of 0.5 % is within the tolerance a vendor calibrates a gyro's sensitivity to, and on a
# limb turning at 5 rad/s it is 0.025 rad/s, a gyro's own noise.
SCALE_FLOOR = 0.5  # %


def _link(recording: Recording, name: str) -> int:
    return recording.links.index(name)


@dataclass
class GyroBias(Effect):
    """A constant angular-velocity bias params['bias'] [3] (rad/s, sensor frame) on a link's gyro."""

    additive, error, judged = ("bias",), "rmse", ("drift_score", "drift_kept")
    floor, unit = BIAS_FLOOR, "deg/s"

    def size(self, dt):
        return float(np.degrees(np.linalg.norm(self.params["bias"])))

    def relevance_floor(self, dt):
        """BIAS_FLOOR, or WANDER_SHARE of how much the gyro's disagreement with its orientations wanders
        (params['wander'], rad/s: _wander) where that is more."""
        return max(self.floor, WANDER_SHARE * math.degrees(self.params.get("wander", 0.0)))

    def apply(self, recording, sign):
        i, b = _link(recording, self.target), np.asarray(self.params["bias"])
        w = recording.angular_velocity.copy()
        w[:, i] += sign * recording.orientation[:, i] @ b
        return replace(recording, angular_velocity=w)

    def implausible(self):
        size = float(np.degrees(np.linalg.norm(self.params["bias"])))
        # candidates._weigh_turns: the same link's drift, its score on the orientations alone (without its
        # own gyro's part, which says what this bias' own score says) the orientations' word
        drift = self.params.get("drift_score", math.inf)
        if self.params.get("drift_kept"):  # loop._choose
            return (f"what its gyro shows is a turn at a constant rate about the vertical (score "
                    f"{self.params['vertical_turn_score']:.0f} with one parameter, against {self.score:.0f} with the "
                    f"bias' three), on a sensor whose heading drift is kept: what that drift's rate left")
        if "vertical_turn_score" in self.params and drift > 0:
            return (f"what its gyro shows is a turn at a constant rate about the vertical (score "
                    f"{self.params['vertical_turn_score']:.0f} with one parameter, against {self.score:.0f} with the "
                    f"bias' three): a heading drift of this sensor, which also turns its orientations"
                    + (f" (the drift scores {drift:.0f} on them)" if math.isfinite(drift) else ""))
        return (f"a bias of {size:.3g} deg/s, beyond the {MAX_BIAS:g} deg/s a gyro has: a sign of a stream in other "
                f"units or axes, or of orientations that are not this sensor's" if size > MAX_BIAS else "")

    def summary(self):
        b = np.asarray(self.params["bias"])
        components = ", ".join(f"{x:+.4f}" for x in b)
        return f"gyro bias on {self.target}: {np.linalg.norm(b) * 180 / np.pi:.2f} deg/s ({components} rad/s, sensor frame)"


@dataclass
class GyroScale(Effect):
    """A gyro scale error params['scale_error'] = kappa: the gyro stream reads (1 + kappa) w, and the
    orientations do not carry it: they come from elsewhere (markers, another fusion) or from a filter fed
    with the calibrated gyro while the stream is the raw one converted with the datasheet's nominal
    sensitivity (MEMS gyros are specified to +-3 %, InvenSense's MPU-6050 for one). A scale error the
    orientations' own filter integrates turns them too, in phase with the limb's swing, as the filter's
    leak of the limb's acceleration into its tilt does: the data do not tell the two apart (see
    docs/diagnosis.md)."""

    error = "rmse"
    floor, unit = SCALE_FLOOR, "%"

    def size(self, dt):
        return 100.0 * abs(self.params["scale_error"])

    def apply(self, recording, sign):
        i = _link(recording, self.target)
        w = recording.angular_velocity.copy()
        w[:, i] *= (1.0 + self.params["scale_error"]) ** sign
        return replace(recording, angular_velocity=w)

    def refine(self, update):
        k = (1.0 + self.params["scale_error"]) * (1.0 + update.params["scale_error"]) - 1.0
        self.params["scale_error"], self.stderr = k, update.stderr
        return self

    def implausible(self):
        k = self.params["scale_error"]
        return (f"a scale error of {100 * k:+.1f} %, beyond {100 * MAX_SCALE:.0f} %: a sign of a gyro in other units, "
                f"or of rates too small to tell a scale" if abs(k) > MAX_SCALE else "")

    def summary(self):
        return f"gyro scale error on {self.target}: {100 * self.params['scale_error']:+.2f} %"


@dataclass
class StreamDelay(Effect):
    """The gyro of a link lags its orientations by params['delay'] seconds; target "all": every
    gyro of params['links'] by the same delay (a device's, not a sensor's)."""

    additive, error = ("delay",), "rmse"
    unit = "ms"

    def size(self, dt):
        return 1e3 * abs(self.params["delay"])

    def relevance_floor(self, dt):
        return 1e3 * dt * DELAY_FLOOR

    def apply(self, recording, sign):
        w = recording.angular_velocity.copy()
        for name in self.params.get("links", [self.target]):
            i = _link(recording, name)
            w[:, i] = shift(w[:, i], recording.time, -sign * self.params["delay"])
        return replace(recording, angular_velocity=w)

    def implausible(self):
        delay = self.params["delay"]
        return (f"a delay of {delay:.3g} s, beyond the {MAX_DELAY} s a stream has: a sign of streams of different "
                f"takes, or of a clock error" if abs(delay) > MAX_DELAY else "")

    def summary(self):
        which = f"every gyro ({len(self.params['links'])} sensors)" if self.target == "all" else f"gyro of {self.target}"
        return f"{which} late on its orientations by {1e3 * self.params['delay']:.1f} ms"


NO_GYRO = "not identifiable: the angular velocity is the orientations' derivative, not a gyro of its own"


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, derived: torch.Tensor | None = None,
        max_delay: float = 0.1, cutoff: float = 5.0, target: str | None = None) -> list[Effect]:
    """Bias, scale and stream-delay candidates for every link of subject b, and one delay common to
    all its gyros (target "all"). derived [L]: links whose angular velocity is computed from the
    orientations (default: analysis.derived), where these effects cannot be told (they come back
    without a fit, saying so). target: only that link's candidates (or, "all", the common delay's)."""
    out, rates = [], []
    time = analysis.time
    derived = analysis.derived[b] if derived is None else derived
    dt = float(torch.diff(time).median())
    cutoff = min(cutoff, 0.25 / dt)
    ok = analysis.valid[:, b]  # [T,L]
    low = lambda x: lowpass_blocks(x, time, cutoff, train, test)  # noqa: E731  (all links at once)
    e_low = low(analysis.e[:, b])
    w_lows = low(simpson(torch.where(ok[..., None], analysis.w_m[:, b], 0.0)))
    walk = subject_walk(analysis.e[:, b], analysis.R_m[:, b], ok, time, ~derived)
    for i, name in enumerate(analysis.links):
        if target not in (None, "all", name):
            continue
        if bool(derived[i]):
            out += [GyroBias("gyro_bias", name, notes=NO_GYRO), GyroScale("gyro_scale", name, notes=NO_GYRO),
                    StreamDelay("stream_delay", name, notes=NO_GYRO)]
            continue
        tr, te = ok[:, i] & train, ok[:, i] & test
        if int(tr.sum()) < 8 or int(te.sum()) < 8:
            continue
        e, w_low = e_low[:, i], w_lows[:, i]
        bias = _bias(name, analysis.e[:, b, i], analysis.R_m[:, b, i], ok[:, i], time, walk)
        if bias is not None:
            out.append(bias)
        # scale: e = gamma S(w_m), gamma = kappa / (1 + kappa)
        power = float(w_low[tr].square().sum().clamp(min=1e-12))
        gamma = float((e[tr] * w_low[tr]).sum()) / power
        fit_s = score(e[te], e[te] - gamma * w_low[te], 1)
        sd = (fit_s.sigma2 * fit_s.tau / power) ** 0.5 / (1 - gamma) ** 2
        out.append(GyroScale("gyro_scale", name, dict(scale_error=gamma / (1.0 - gamma)), dict(scale_error=sd), 1, fit_s))
        # delay: the lag that best lines the gyro up with the orientations' rate
        out.append(_delay(name, w_low, e, tr, te, time, max_delay))
        rates.append((name, w_low, e, tr, te))
    if len(rates) > 1 and target in (None, "all"):
        names = [name for name, *_ in rates]
        common = _delay("all", torch.cat([r[1] for r in rates], -1), torch.cat([r[2] for r in rates], -1),
                        torch.stack([r[3] for r in rates]).all(0), torch.stack([r[4] for r in rates]).all(0),
                        time, max_delay)
        common.params["links"] = list(names)
        out.append(common)
    return out


def _bias(name: str, e: torch.Tensor, R: torch.Tensor, ok: torch.Tensor, time: torch.Tensor, walk: float = 0.0
          ) -> GyroBias | None:
    """The GyroBias of one gyro from its disagreement e [T,3] with its orientations R [T,3,3] (valid
    where ok [T]), fitted in integral form (integral.py): C(t) = int F e dt = int F R dt b + noise,
    and scored by the likelihood ratio against no bias over the whole time, less BIC's charge for its
    three parameters. None where either half of the time has under 8 valid samples.

    The integral's noise: a stationary part (the orientations' noise n, whose derivative telescopes)
    and a random walk (the gyro's own noise, and n x w where the gyro's rates were put in the world
    frame by other orientations than the recorded ones), fitted with the bias (so a bias does not
    pass for a walk), the walk at least `walk` (rad^2/s), what the recording's gyros share
    (integral.subject_walk). The frame F, world or sensor, is the one the noise is smaller in
    (integral.quieter_frame).

    The whole time, not a held-out half: the noise model is fitted, not the score's judge, and a
    half's six seconds halve the span a bias' line is seen over. Over the study's 90 recordings
    (1711 gyros without a bias), the largest likelihood ratio was 11.9, against a pass mark of 22.7;
    held out both ways, 29 of the 38 biased gyros had passed, 36 pass now."""
    stride = halves_stride(ok, time)
    if stride is None:  # as every fit here: too short a recording to fit on
        return None
    frame = quieter_frame(e, R, [R, vertical_turn(time)], ok, time, stride, walk)
    bias, cov, noise = frame.fit
    C, GI, t = frame.integral
    W = whitener(noise, t)
    y, leftover = W @ C, W @ (C - GI @ bias)
    fit = _likelihood_ratio(y, leftover, 3)
    params: dict = dict(bias=bias.tolist(), frame=frame.name, wander=_wander(e, R, ok, time))
    # a heading drift makes e a constant -rate z in the world frame: one parameter for what a bias
    # would need three, and where it leaves about as little (the likelihood ratio less what the bias'
    # two more parameters cost), it is the drift
    GT = integrated(frame.e, frame.G[1], ok, time, stride)[1]
    zG = W @ GT[..., 0]
    rate = float((zG * y).sum()) / max(float(zG.square().sum()), 1e-300)
    turn_leftover = y - rate * zG
    n = y.numel()
    if n * math.log(float(turn_leftover.square().sum()) / float(leftover.square().sum())) <= 2 * math.log(n):
        params["vertical_turn_score"] = _likelihood_ratio(y, turn_leftover, 1).score
    return GyroBias("gyro_bias", name, params, dict(bias=cov.diagonal().sqrt().tolist()), 3, fit)


def _wander(e: torch.Tensor, R: torch.Tensor, ok: torch.Tensor, time: torch.Tensor, transient: float = 1.0) -> float:
    """How much a gyro's disagreement e [T,3] (world frame) with its orientations R [T,3,3] wanders, in
    rad/s: the rms of its means over WANDER_BLOCK-second blocks (sensor frame, valid samples where ok
    [T], past the first `transient` seconds) about their mean; 0 with under four blocks."""
    keep = ok & (time >= time[0] + transient)
    stride = max(1, int(round(WANDER_BLOCK / float(torch.diff(time).median()))))
    e_sensor = (R.transpose(-1, -2) @ e[..., None])[..., 0][keep]
    blocks = len(e_sensor) // stride
    if blocks < 4:
        return 0.0
    means = e_sensor[:blocks * stride].reshape(blocks, stride, 3).mean(1)
    return float((means - means.mean(0)).square().sum(-1).mean().sqrt())


def _likelihood_ratio(y: torch.Tensor, leftover: torch.Tensor, k: int) -> Score:
    """The Score of an effect of k parameters that leaves `leftover` of y (both [K,d], whitened to unit
    variance by the noise model): 2 log of the likelihood ratio, |y|^2 - |leftover|^2, less k log(K d)."""
    gain = float(y.square().sum() - leftover.square().sum())
    return Score(gain - k * math.log(max(y.numel(), 2)), gain / max(float(y.square().sum()), 1e-300), 1.0, 1.0,
                 y.numel())


def _delay(name: str, w_low: torch.Tensor, e: torch.Tensor, tr: torch.Tensor, te: torch.Tensor, time: torch.Tensor,
           max_delay: float) -> StreamDelay:
    """The StreamDelay of gyro rates w_low [T,d] (low-passed) that disagree with the orientations' by e."""
    dt = float(torch.diff(time).median())
    d, sd = _lag(w_low, w_low - e, tr, max(3, int(round(max_delay / dt))), dt)
    shifted = torch.from_numpy(shift(w_low.numpy(), time.numpy(), d))
    return StreamDelay("stream_delay", name, dict(delay=d), dict(delay=sd), 1, score(e[te], (shifted - (w_low - e))[te], 1))


def _lag(x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor, max_lag: int, dt: float) -> tuple[float, float]:
    """d (s) minimising sum |x(t + d) - y(t)|^2 over the masked t: integer lags, then the parabola
    through the best and its neighbours. Also its standard error from the parabola's curvature."""
    T = x.shape[0]
    lags = range(-max_lag, max_lag + 1)
    inner = mask.clone()
    inner[:max_lag] = False
    inner[T - max_lag:] = False
    t = torch.nonzero(inner)[:, 0]
    cost = (x[(t + torch.arange(-max_lag, max_lag + 1)[:, None]) % T] - y[t]).square().sum((1, 2))  # every lag at once
    j = int(cost.argmin())
    if 0 < j < len(cost) - 1:
        c0, c1, c2 = (float(c) for c in cost[j - 1:j + 2])
        curvature = c0 - 2 * c1 + c2
        offset = 0.5 * (c0 - c2) / curvature if curvature > 0 else 0.0
        n = int(inner.sum()) * x.shape[-1]
        sigma2 = c1 / max(n, 1)
        # cost(d) ~ c1 + curvature/2 (d - d*)^2 in samples: var(d*) = 2 sigma^2 / curvature
        sd = (2.0 * sigma2 / curvature) ** 0.5 * dt if curvature > 0 else float("inf")
    else:
        offset, sd = 0.0, float("inf")
    return (lags[j] + offset) * dt, sd

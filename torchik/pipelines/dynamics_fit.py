"""The loop closed on forces: what the base's residual wrench says the model or the plates lack.

Along a motion with measured ground reactions, the floating base's wrench (`tk.trajectory_dynamics`)
less the plates' wrench is what neither the model's masses nor the plates explain: zero for a perfect
model and perfect plates. A segment's mass or centre of mass off, a plate's centre of pressure off,
and a lag between the plates and the motion each leave a signature in it, linear in the effect's
parameters for a given motion (`dynamics_effects.py`), so each is fitted by least squares over the
trajectory: r(theta) = r + G theta, weighted to one scale (forces in body weights M g, moments in
M g times LEVER), the lag by Gauss-Newton with the plates shifted exactly at each iteration.

The effects are added one at a time (forward selection). In each round every remaining effect is
fitted, with those already added, on one half of the time and scored on the other, both ways
(held-out halves), by the score of `pipelines/diagnosis/effect.py`:
(|y|^2 - |y - y_hat|^2) / (sigma^2 tau) - k log(n / tau), y the held-out residual, sigma^2 and tau
the variance and autocorrelation time of what is left, k the effect's parameters. The best one is
added when its score exceeds SIGNIFICANT, it explains more than FLOOR (a residual below it is
explained already), the two halves' estimates agree (within AGREEMENT of the larger), and its value
on the whole time is plausible (LIMITS: a mass off by more than a quarter of the segment's, the whole
body's by more than a tenth, a centre of mass or of pressure by more than 5 cm, a lag of more than
0.1 s is a fault of another kind); one
that is not is refused, with the reason, and the next one tried. What each effect explains is the
residual on the whole time before and after it was added; the report gives the residual's RMS as a
force in body weights and a moment in N m per kilogram of body mass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from ..errors import InputError
from ..method.dynamics import CUTOFF, low_pass, trajectory_dynamics
from ..method.dynamics.inverse import GRAVITY
from ..method.dynamics.trajectory import Sampled
from ..method.kinematics.mass import total_mass
from ..method.kinematics.model import KinematicModel
from . import dynamics_effects as effects
from .diagnosis.series import autocorrelation_time
from .dynamics_effects import Effect

SIGNIFICANT = 10.0  # held-out score (2 log of the approximate Bayes factor), Kass and Raftery's "very strong"
FLOOR = 1e-3  # weighted residual RMS (body weights): what an effect must explain at least
AGREEMENT = 0.5  # the two halves' estimates differ by at most this fraction of the larger
LIMITS = {"mass": 0.25, "com": 0.05, "cop": 0.05, "lag": 0.1}  # fraction of the segment's mass, m, m, s
BODY_LIMIT = 0.1  # the whole body's mass: a stated body mass off by more is another subject's
MIN_SAMPLES = 20  # samples to fit on: two halves of ten
LEVER = 1.0  # m: a moment of M g LEVER weighs as a force of M g


@dataclass(frozen=True)
class Residual:
    """The base's residual wrench, RMS over the fitted time: force in body weights, moment in N m per kg."""

    force: float
    moment: float

    def __str__(self) -> str:
        return f"force {100 * self.force:.3g} % of body weight, moment {self.moment:.3g} N m/kg"


@dataclass(frozen=True)
class FittedEffect:
    """An effect added: `value` (units in `labels`) fitted on the whole time with all those added;
    `halves` its estimates on each half alone when added; `score` its held-out score then; `before`,
    `after` the residual on the whole time when it was added; `relative` a mass's change as a
    fraction of the segment's."""

    name: str
    kind: str
    labels: tuple[str, ...]
    value: tuple[float, ...]
    halves: tuple[tuple[float, ...], tuple[float, ...]]
    score: float
    before: Residual
    after: Residual
    relative: float | None = None

    def __str__(self) -> str:
        values = ", ".join(f"{v:+.4g} {label}" for label, v in zip(self.labels, self.value))
        share = "" if self.relative is None else f" ({100 * self.relative:+.1f} % of the segment's)"
        return f"{self.name}: {values}{share}; score {self.score:.0f}; residual {self.before} -> {self.after}"


@dataclass(frozen=True)
class Refused:
    """An effect significant but not added: its value on the whole time and why."""

    name: str
    value: tuple[float, ...]
    reason: str


@dataclass
class DynamicsFit:
    """The residual `before` and `after` the `effects` (in the order added); `refused` those
    significant but implausible or unstable; `scores` the last round's held-out score of every effect
    not added; `model` the model with the fitted masses and centres of mass; `plate_wrenches` [T,P,6]
    the plates as given with the fitted offsets undone, read at the fitted `lag` (s)."""

    before: Residual
    after: Residual
    effects: list[FittedEffect]
    refused: list[Refused]
    scores: dict[str, float]
    model: KinematicModel
    plate_wrenches: torch.Tensor
    lag: float = 0.0

    def summary(self) -> str:
        lines = [f"base residual before: {self.before}", f"base residual after:  {self.after}"]
        lines += [f"  added {e}" for e in self.effects] or ["  nothing added: no effect explains the residual"]
        lines += [f"  refused {r.name} ({', '.join(f'{v:+.4g}' for v in r.value)}): {r.reason}" for r in self.refused]
        return "\n".join(lines)


class _Residuals:
    """The weighted residual's least-squares problems over samples of the trajectory, at any lag."""

    def __init__(self, free: torch.Tensor, plates: torch.Tensor, p_B: torch.Tensor, rate: float, scale: torch.Tensor):
        self.free, self.plates, self.p_B, self.rate, self.scale = free, plates, p_B, rate, scale
        self._lags: dict[float, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}

    def at_lag(self, lag: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The plates read at t + lag [T,P,6], and their sum's wrench about the base's origin and its
        derivative [T,6] (each lag's made once: the folds and the rounds ask again)."""
        if lag not in self._lags:
            shifted = self.plates if lag == 0.0 else effects.shift(self.plates, self.rate, lag)
            E = shifted.sum(1)
            dE = torch.gradient(E, spacing=1.0 / self.rate, dim=0)[0]
            self._lags[lag] = (shifted, self._about_base(E), self._about_base(dE))
        return self._lags[lag]

    def _about_base(self, E: torch.Tensor) -> torch.Tensor:
        """[T,6] (force; moment about the world origin) -> moment about the base's origin."""
        return torch.cat((E[:, :3], E[:, 3:] - torch.linalg.cross(self.p_B, E[:, :3])), -1)

    def problem(self, chosen: Sequence[Effect], lag: float, at: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """y [t,6] the weighted residual on samples `at` with the plates at `lag`, G [t,6,k] its columns."""
        shifted, E, dE = self.at_lag(lag)
        y = (self.free - E)[at] * self.scale
        cols = [e.columns(shifted)[at] if e.columns is not None else -dE[at][..., None] for e in chosen]
        G = torch.cat(cols, -1) * self.scale[:, None] if cols else y.new_zeros(len(at), 6, 0)
        return y, G

    def solve(self, chosen: Sequence[Effect], at: torch.Tensor) -> tuple[torch.Tensor, float]:
        """theta [k] of `chosen` fitted on samples `at` (a lag among them by Gauss-Newton), and the lag."""
        lag = 0.0
        i = _lag_index(chosen)
        for _ in range(8):
            y, G = self.problem(chosen, lag, at)
            if G.shape[-1] == 0:
                return G.new_zeros(0), lag
            theta = torch.linalg.lstsq(G.reshape(-1, G.shape[-1]), -y.reshape(-1, 1)).solution[:, 0]
            if i is None:
                return theta, lag
            step = float(theta[i])
            lag += step
            theta[i] = lag
            if abs(step) < 1e-6 or abs(lag) > 2 * LIMITS["lag"]:
                break
        return theta, lag

    def left(self, chosen: Sequence[Effect], theta: torch.Tensor, lag: float, at: torch.Tensor) -> torch.Tensor:
        """What is left [t,6] of the weighted residual on samples `at` with `chosen` at theta: the lag
        is in the plates' shift, its column not added again."""
        y, G = self.problem(chosen, lag, at)
        i = _lag_index(chosen)
        if i is not None:
            keep = torch.arange(G.shape[-1]) != i
            G, theta = G[..., keep], theta[keep]
        return y + G @ theta


def fit_dynamics(model: KinematicModel, trajectory: Sampled, plate_wrenches: torch.Tensor,
                 plate_normals: torch.Tensor | None = None, segments: dict[str, Sequence[str]] | None = None,
                 centre_of_mass: Sequence[str] = ("trunk",), cutoff: float = CUTOFF,
                 frames: torch.Tensor | None = None, plate_names: Sequence[str] | None = None,
                 filter_plates: bool = True) -> DynamicsFit:
    """What explains the base's residual wrench along `trajectory` (one subject, [T,1,...], a constant
    rate) with the plates' `plate_wrenches` [T,P,6] (force N; moment N m about the world origin; world
    axes; NaN where unknown: those samples are left out), as the module's docstring says.

    plate_normals [P,3] each plate's upward normal (default the world's z); segments: name -> the links
    whose mass may be off together (default `dynamics_effects.HUMAN_SEGMENTS`, their links with a
    mass); centre_of_mass: the segments whose centre of mass may be off along them; cutoff: the
    low-pass (Hz) of the motion's derivative (`trajectory_dynamics`) and, with filter_plates, of the
    plates (without, they are fitted as given: the residual an inverse dynamics with them has); frames [T]
    (bool): the samples to fit on (default all; a walk's where the plates carry every foot on the
    ground: elsewhere the residual holds the reaction of a foot no plate sees); plate_names [P] what the
    effects call the plates (default "plate 1", ...)."""
    T, B = trajectory.velocity.shape[:2]
    if B != 1:
        raise InputError(f"fit_dynamics fits one subject: the trajectory has {B}")
    if plate_wrenches.dim() != 3 or plate_wrenches.shape[0] != T or plate_wrenches.shape[2] != 6:
        raise InputError(f"plate_wrenches must be [T={T},P,6], got {list(plate_wrenches.shape)}")
    P, dtype = plate_wrenches.shape[1], model.dtype
    rate = 1.0 / float(trajectory.time.diff().double().mean())
    mass = float(total_mass(model)[0])
    weight = mass * math.hypot(*GRAVITY)
    scale = torch.tensor([1 / weight] * 3 + [1 / (weight * LEVER)] * 3, dtype=dtype)
    groups = effects.segments(model, segments)
    normals = torch.tensor([[0.0, 0.0, 1.0]] * P, dtype=dtype) if plate_normals is None else plate_normals.to(dtype)

    free = trajectory_dynamics(model, trajectory, cutoff=cutoff).base_wrench[:, 0]  # [T,6] no contact
    plates = torch.nan_to_num(plate_wrenches.to(dtype))
    if filter_plates:
        plates = low_pass(plates, rate, cutoff)
    residuals = _Residuals(free, plates, trajectory.base_position[:, 0].to(dtype), rate, scale)
    pool = [effects.mass_effect(model, trajectory, name, links, cutoff, BODY_LIMIT if name == effects.BODY else None)
            for name, links in groups.items()]
    pool += [effects.com_effect(model, trajectory, name, groups[name], cutoff) for name in centre_of_mass
             if name in groups]
    pool += [effects.cop_effect(k, normals[k], None if plate_names is None else plate_names[k]) for k in range(P)]
    pool += [effects.lag_effect()] if P else []

    edge = min(T // 4, int(math.ceil(2 * rate / cutoff)))  # the filter's ends are less exact
    rows = torch.isfinite(plate_wrenches).all(-1).all(-1)
    if frames is not None:
        if frames.shape != (T,):
            raise InputError(f"frames must be [T={T}], got {list(frames.shape)}")
        rows &= frames.to(torch.bool)
    rows[:edge] = rows[T - edge:] = False
    index = rows.nonzero()[:, 0]
    if len(index) < MIN_SAMPLES:
        raise InputError(f"{len(index)} samples to fit on (finite plates, within `frames`, off the filter's ends): "
                         f"at least {MIN_SAMPLES} are needed")
    halves = (index[:len(index) // 2], index[len(index) // 2:])
    folds = (halves, halves[::-1])

    def residual(chosen: list[Effect]) -> Residual:
        r = residuals.left(chosen, *residuals.solve(chosen, index), index) / scale  # N, N m
        return Residual(float(r[:, :3].square().sum(-1).mean().sqrt()) / weight,
                        float(r[:, 3:].square().sum(-1).mean().sqrt()) / mass)

    def held_out(chosen: list[Effect], extra: Effect, baseline) -> tuple[float, float, list[torch.Tensor]]:
        """Adding `extra`: its held-out score (both folds summed), the RMS it explains, its estimate on each half."""
        total, explained, estimates = 0.0, 0.0, []
        for before, (train, test) in zip(baseline, folds):
            theta, lag = residuals.solve(chosen + [extra], train)
            after = residuals.left(chosen + [extra], theta, lag, test)
            estimates.append(theta[-len(extra.labels):])
            rss0, rss1, n = float(before.square().sum()), float(after.square().sum()), after.numel()
            tau, sigma2 = autocorrelation_time(after), max(float(after.square().mean()), FLOOR ** 2)
            total += (rss0 - rss1) / (sigma2 * tau) - len(extra.labels) * math.log(n / tau)
            explained += max(rss0 - rss1, 0.0) / n
        return total, math.sqrt(explained / 2), estimates

    def implausible(e: Effect, value: torch.Tensor) -> str:
        """Why the effect's value is implausible ('' when it is not)."""
        limit = LIMITS[e.kind] if e.limit is None else e.limit
        if e.kind == "mass":
            share = float(value[0]) / effects.segment_mass(model, e.segment)
            return "" if abs(share) <= limit else \
                f"{100 * share:+.0f} % of the segment's mass, beyond the plausible {100 * limit:.0f} %"
        unit = "s" if e.kind == "lag" else "m"
        size = float(value.norm())
        return "" if size <= limit else f"{size:.3g} {unit} is beyond the plausible {limit:g} {unit}"

    chosen: list[Effect] = []
    added: list[FittedEffect] = []
    refused: list[Refused] = []
    scores: dict[str, float] = {}
    while pool:
        baseline = [residuals.left(chosen, *residuals.solve(chosen, train), test) for train, test in folds]
        scored = sorted(((held_out(chosen, e, baseline), e) for e in pool), key=lambda x: -x[0][0])
        scores = {e.name: s for (s, _, _), e in scored}
        pick = None
        for (score, explained, (a, b)), e in scored:
            if score < SIGNIFICANT or explained < FLOOR:
                break
            value = residuals.solve(chosen + [e], index)[0][-len(e.labels):]
            reason = implausible(e, value)
            if float((a - b).norm()) > AGREEMENT * max(float(a.norm()), float(b.norm())):
                reason = f"the halves disagree: {_listed(a)} and {_listed(b)} {e.labels[0]}"
            if not reason:
                pick = (e, score, (tuple(a.tolist()), tuple(b.tolist())))
                break
            refused.append(Refused(e.name, tuple(value.tolist()), reason))
            pool.remove(e)
        if pick is None:
            break
        e, score, estimates = pick
        was = residual(chosen)
        chosen.append(e)
        pool.remove(e)
        scores.pop(e.name)
        added.append(FittedEffect(e.name, e.kind, e.labels, (), estimates, score, was, residual(chosen)))

    theta, lag = residuals.solve(chosen, index)
    values = list(torch.split(theta, [len(e.labels) for e in chosen])) if chosen else []
    added = [FittedEffect(a.name, a.kind, a.labels, tuple(v.tolist()), a.halves, a.score, a.before, a.after,
                          float(v[0]) / effects.segment_mass(model, e.segment) if e.kind == "mass" else None)
             for a, e, v in zip(added, chosen, values)]
    fitted = list(zip(chosen, values))
    return DynamicsFit(residual([]), residual(chosen), added, refused, scores, effects.corrected_model(model, fitted),
                       effects.corrected_plates(plate_wrenches.to(dtype), fitted, rate, lag), lag)


def _lag_index(chosen: Sequence[Effect]) -> int | None:
    """The lag's place in theta, None without one."""
    k = 0
    for e in chosen:
        if e.kind == "lag":
            return k
        k += len(e.labels)
    return None


def _listed(x: torch.Tensor) -> str:
    return ", ".join(f"{v:+.4g}" for v in x.tolist())

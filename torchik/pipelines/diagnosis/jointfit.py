"""The kept effects fitted jointly at the end of the loop, with standard errors from the joint fit.

The loop fits each effect on its own with the others in place, and its standard error is the one of
that fit: where two effects explain part of the same residual (a hand's misalignment and its
forearm's, a foot's drift and its toe's), each one's error is conditional on the other being right,
and too small. Here every parameter theta of the kept measurement effects is stacked, and the
whitened residual rho(theta) of the tracked recording (orientation r, angular velocity u, the gyro's
disagreement with its own orientations e, base position r_p; each channel divided by its rms) is
linearised about the loop's values by finite differences, every perturbed recording tracked in one
batch:

    J = d rho / d theta   [N, P],   one Gauss-Newton step  delta = -(J_tr^T J_tr)^-1 J_tr^T rho_tr
                                    on the train half, the covariance  sigma^2 tau (J^T J)^-1

(sigma^2 the variance of what the step leaves, tau its autocorrelation time: the residual's samples
are not independent). Its diagonal gives each parameter's standard error; where two effects are
correlated it is larger than 1 / (J^T J)_ii, the error with the others held (`Joint.conditional`).
A parameter moves only along the directions its fit identifies (Effect.directions).

The step is taken if, re-tracked, what it explains of the whitened residual on the test half is
significant by the loop's own test (effect.score with its Q moved directions as parameters, above
SIGNIFICANT; re-tracked only where the linearisation predicts it is): the loop's fits work on the
channel where each effect shows best, low-passed, and a step that explains no more than the noise
would move them by chance. Otherwise the loop's values stay and `Joint.note` says so (and whether
the step raised the test half's residual). Model effects (a missing axis, a moved limit) stay as
fitted: they change the model, and their variants would not track in one batch.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np
import torch

from .analysis import Analysis, analyse
from .effect import SIGNIFICANT, Effect, halves, score
from .elimination import MODEL_FREE, related
from .series import autocorrelation_time
from .subject import Subject, analyse_subjects, trajectory_of

CHANNELS = ("r", "u", "e", "r_p")  # the residuals the measurement effects act on (see Analysis)
STEP = 0.5  # the finite-difference step, in standard errors of the loop's fit
VARIANT_SAMPLES = 2  # the sample times of the perturbed recordings' task Jacobian, which the fit does not use


@dataclass
class Joint:
    """The joint fit of one subject: names [P] ('kind at target: parameter[i]'), the loop's values
    theta [P], the joint step delta [P], the joint standard errors stderr [P] and those with the
    others held (conditional [P]), the test half's whitened residual before and after the step, and
    whether the step was kept (a note saying which)."""

    names: list[str]
    theta: np.ndarray
    delta: np.ndarray
    stderr: np.ndarray
    conditional: np.ndarray
    test_before: float
    test_after: float
    kept: bool
    gain: float = float("nan")  # the step's held-out score (effect.score)
    directions: int = 0  # Q: the directions the step moves (the parameters the data determine)
    scale: torch.Tensor | None = None  # [4] the channels' rms at the loop's values (residual)
    linearised: bool = False  # test_after and gain as the linearisation predicts them (not re-tracked)

    @property
    def note(self) -> str:
        what = f"{len(self.names)} parameters of the kept measurement effects fitted jointly (one Gauss-Newton step)"
        if self.kept:
            return (f"parameters and standard errors from the joint fit: {what}; the test half's residual "
                    f"{self.test_before:.4g} -> {self.test_after:.4g} (held-out score {self.gain:.0f})")
        why = (f"raised the test half's residual from {self.test_before:.4g} to {self.test_after:.4g}"
               f"{' (linearised)' if self.linearised else ''}"
               if self.test_after > self.test_before else
               f"explained too little of the test half's residual ({self.test_before:.4g} -> {self.test_after:.4g}"
               f"{', linearised' if self.linearised else ''}, held-out score {self.gain:.1f}, not above "
               f"{SIGNIFICANT:g})")
        return (f"standard errors from the joint fit ({what}), parameters from the loop's sequential fit: the "
                f"joint step {why}, so it was not taken")

    def to_json(self) -> dict:
        return dict(names=self.names, sequential=self.theta.tolist(), step=self.delta.tolist(),
                    stderr=self.stderr.tolist(), conditional_stderr=self.conditional.tolist(),
                    test_before=self.test_before, test_after=self.test_after, linearised=self.linearised,
                    gain=self.gain, kept=self.kept,
                    note=self.note)


def fitted(effect: Effect) -> list[str]:
    """The numeric parameters of a measurement effect that the joint fit moves (those with a standard error)."""
    if effect.model_effect:
        return []
    return [n for n in effect.stderr if n in effect.params and np.asarray(effect.params[n]).dtype.kind == "f"]


def _vector(effects: Sequence[Effect]) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """The stacked parameters theta [P], their loop standard errors [P], names, and the directions
    [P, Q] in which the data determine them (Effect.directions, block by block)."""
    theta, sd, names, blocks = [], [], [], []
    for e in effects:
        for n in fitted(e):
            v = np.atleast_1d(np.asarray(e.params[n], dtype=np.float64)).ravel()
            theta.append(v)
            sd.append(np.broadcast_to(np.atleast_1d(np.asarray(e.stderr[n], dtype=np.float64)).ravel(), v.shape))
            blocks.append(e.directions(n))
            names += [f"{e.kind} at {e.target}: {n}" + (f"[{i}]" if v.size > 1 else "") for i in range(v.size)]
    if not theta:
        return np.zeros(0), np.zeros(0), [], np.zeros((0, 0))
    basis = np.zeros((sum(len(b) for b in blocks), sum(b.shape[1] for b in blocks)))
    r = c = 0
    for b in blocks:
        basis[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return np.concatenate(theta), np.concatenate(sd), names, basis


def _unstack(effects: Sequence[Effect], values: np.ndarray) -> list[dict]:
    """Stacked values [P] (parameters or standard errors) back into one dict per effect, each in its
    parameter's shape (a float for a scalar)."""
    out, k = [], 0
    for e in effects:
        part = {}
        for n in fitted(e):
            shape = np.asarray(e.params[n]).shape
            size = int(np.prod(shape))
            value = values[k:k + size].reshape(shape)
            part[n] = float(value) if not shape else value.tolist()
            k += size
        out.append(part)
    return out


def _set(effects: Sequence[Effect], theta: np.ndarray) -> list[Effect]:
    """Copies of the effects with the stacked parameters theta [P]."""
    out = []
    for e, params in zip(effects, _unstack(effects, theta)):
        e = copy.copy(e)
        e.params = {**e.params, **params}
        out.append(e)
    return out


def _rebuild(s: Subject, effects: Sequence[Effect]) -> Subject:
    """Subject s's source recording with the measurement effects corrected, on s's (augmented) model."""
    assert s.source is not None, "set by the loop"
    recording = s.source[0]
    for e in effects:
        if not e.model_effect:
            recording = e.correct(recording)
    return Subject(recording, s.urdf, s.model, chunking=s.chunking)


def residual(analysis: Analysis, b: int, used: torch.Tensor, scale: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Subject b's residual channels (CHANNELS; e only on the links with a gyro of their own, where it
    is no rounding error) at the time samples `used` [T] (bool), each divided by its rms (`scale` [4],
    from the loop's values; computed here when None): [n_used, D] and the scale."""
    gyro = ~analysis.derived[b]
    channels = {c: getattr(analysis, c)[:, b] for c in CHANNELS}
    channels["e"] = channels["e"] * gyro[None, :, None].to(channels["e"].dtype)
    parts = [torch.nan_to_num(x).reshape(len(analysis.time), -1)[used] for x in channels.values()]
    if scale is None:
        scale = torch.stack([p.square().mean().sqrt().clamp(min=1e-12) for p in parts])
    return torch.cat([p / k for p, k in zip(parts, scale)], dim=-1), scale


class Plan(NamedTuple):
    """A subject's stacked problem before its step: theta [P], the loop's errors sd [P], the names, the
    directions basis [P, Q], the finite-difference steps h [Q] and the variants moved by them [Q],
    and which of them move only MODEL_FREE effects (analysed on the subject's trajectory, not tracked:
    what such an effect changes of the tracking is second order to what it changes of the channel it
    is fitted on, as backward elimination takes it)."""

    subject: Subject
    theta: np.ndarray
    sd: np.ndarray
    names: list[str]
    basis: np.ndarray
    h: np.ndarray
    variants: list[Subject]
    free: list[bool]  # per variant: it moves only effects fitted on a sensor's own streams (elimination.MODEL_FREE)


def plan(s: Subject) -> Plan | None:
    """Subject s's stacked problem, variants not tracked yet; None when no two kept measurement effects
    share a residual (elimination.related: the same links or one joint apart): each one's fit with the
    others in place is then the joint fit's, to the step the linearisation would take, and tracking a
    variant per parameter to find that out would cost seconds for nothing."""
    theta, sd, names, basis = _vector(s.effects)
    measured = [e for e in s.effects if fitted(e)]
    links = s.current[0].links
    if not any(related(a, b, s.model, s.urdf, links) for k, a in enumerate(measured) for b in measured[k + 1:]):
        return None
    h = STEP * step_scale(basis, sd)
    h = np.where(np.isfinite(h) & (h > 0), h, 1e-6 * max(float(np.abs(theta).max()), 1.0))
    variants = [_rebuild(s, _set(s.effects, theta + h[q] * basis[:, q])) for q in range(basis.shape[1])]
    kinds = [e.kind for e in s.effects for n in fitted(e) for _ in range(np.asarray(e.params[n]).size)]  # per row
    free = [all(kinds[p] in MODEL_FREE for p in np.flatnonzero(basis[:, q])) for q in range(basis.shape[1])]
    return Plan(s, theta, sd, names, basis, h, variants, free)


def step_scale(basis: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """[Q] the loop's standard error along each direction of `basis` [P, Q] (sd [P]): the smallest of
    the components it mostly lies along (|basis| >= 0.5; a unit vector has one). Not their mix: the
    error of a component the data do not determine is meaningless (a misalignment's), often huge."""
    along = np.abs(basis) >= 0.5
    return np.where(along, sd[:, None], np.inf).min(0)


def refit(subjects: Sequence[Subject], links, gain: float, progress: bool, max_samples: int) -> list[Joint | None]:
    """The joint fit of each subject's kept effects (None where no measurement effect is kept); the
    subjects whose step is kept end with their effects moved, re-tracked and analysed. The variants of
    all subjects track as one batch per model, and so do the subjects moved by their steps."""
    plans = [plan(s) for s in subjects]
    # only their residuals are read: the task Jacobian at a handful of samples, not max_samples (a fifth of the cost)
    analyse_subjects([v for p in plans if p is not None for v, free in zip(p.variants, p.free) if not free], links,
                     gain, progress, VARIANT_SAMPLES)
    for kept in (p for p in plans if p is not None):
        for v in (v for v, free in zip(kept.variants, kept.free) if free):
            v.analysis = (analyse(v.model, [v.recording], links, trajectory_of(*kept.subject.current), gain,
                                  VARIANT_SAMPLES), 0)
    steps = [None if p is None else _step(p) for p in plans]
    # a step that its linearisation says explains too little is not worth re-tracking (a second of a 12 s recording)
    promising = [step for step in steps if step is not None and step[1].gain > SIGNIFICANT]
    analyse_subjects([moved for moved, *_ in promising], links, gain, progress, max_samples)
    for p, step in zip(plans, steps):
        if p is not None and step is not None:
            _settle(p.subject, *step)
    return [None if step is None else step[1] for step in steps]


def _step(p: Plan) -> tuple[Subject, Joint, torch.Tensor]:
    """The linearised stacked problem of p in the coordinates z of its directions (theta + basis z):
    the subject moved by the step, the step and covariance, and the test half's residual [n_test, D]."""
    s, theta, sd, names, basis, h, variants, _ = p
    analysis, b = s.current
    train, test = halves(analysis.time)
    used = train | test
    rho, scale = residual(analysis, b, used)
    J = torch.stack([(residual(v.current[0], v.current[1], used, scale)[0] - rho).reshape(-1) / float(hq)
                     for v, hq in zip(variants, h)], dim=-1)  # [N, Q]
    rows = train[used]
    per_row = rho.shape[-1]
    tr = rows.repeat_interleave(per_row)
    delta = -torch.linalg.lstsq(J[tr], rho.reshape(-1)[tr, None]).solution[:, 0]
    left = rho + (J @ delta).reshape(rho.shape)
    sigma2 = float(left.square().mean())
    tau = autocorrelation_time(left)
    normal = J.T @ J
    B = torch.from_numpy(basis).to(J.dtype)
    cov = B @ torch.linalg.pinv(normal) @ B.T * sigma2 * tau  # [P, P]
    conditional = B.square() @ (sigma2 * tau / normal.diagonal().clamp(min=1e-300))
    delta = B @ delta
    moved = _rebuild(s, _set(s.effects, theta + delta.numpy()))
    # a component the directions leave out keeps the loop's error (which says it is not identified)
    outside = (1.0 - B.square().sum(-1)).clamp(min=0.0) * torch.from_numpy(sd).to(J.dtype).square()
    stderr, conditional = (cov.diagonal().clamp(min=0) + outside).sqrt(), (conditional + outside).sqrt()
    predicted = left[~rows]  # the test half's residual after the step, as the linearisation gives it
    joint = Joint(names, theta, delta.numpy(), stderr.numpy(), conditional.numpy(),
                  float(rho[~rows].square().mean()), float(predicted.square().mean()), False,
                  score(rho[~rows], predicted, k=basis.shape[1]).score, basis.shape[1], scale)
    return moved, joint, rho[~rows]


def _settle(s: Subject, moved: Subject, joint: Joint, before: torch.Tensor) -> None:
    """Take the step if what it explains of the test half's residual (`before` [n_test, D]) is
    significant (else keep the loop's values); the joint standard errors either way."""
    if moved.analysis is not None:  # re-tracked: the step's gain as it is, not as linearised
        analysis, b = moved.current
        _, test = halves(analysis.time)
        after = residual(analysis, b, test, joint.scale)[0]
        joint.test_after = float(after.square().mean())
        joint.gain = score(before, after, k=joint.directions).score
    else:
        joint.linearised = True
    joint.kept = joint.gain > SIGNIFICANT
    theta = joint.theta + joint.delta if joint.kept else joint.theta
    for e, params, stderr in zip(s.effects, _unstack(s.effects, theta), _unstack(s.effects, joint.stderr)):
        e.params = {**e.params, **params}
        e.stderr = {**e.stderr, **stderr}
    if joint.kept:
        s.recording, s.analysis = moved.recording, moved.analysis

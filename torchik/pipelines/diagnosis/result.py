"""What the diagnosis loop returns for one recording (Diagnosis), the steps it took (Step), the
tracking errors before and after each (Errors), and why it stopped (STOPS)."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import torch

from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from ...method.metrics import orientation_error
from . import jointfit
from .analysis import Analysis, NoiseFloor
from .calibration import FORMAT
from .effect import Effect

STOPS = {"noise": "consistent with noise: no candidate is significant, and the noise accounts for what remains",
         "unexplained": "no candidate is both significant and plausible, but more remains than the noise accounts "
                        "for: a cause none of the candidates describes",
         "unidentifiable": "nothing identifiable: no candidate can be fitted on these data",
         "negligible": "what the data still show significantly is below the size that matters (listed as negligible)",
         "cap": "cap reached: candidates were still significant after the last round allowed (--max-effects)"}


@dataclass
class Errors:
    """Per link: mnte (mean of 1 - cos of the orientation error) and rmse (rad/s, angular velocity),
    over the time after the transient; overall: their means over the links; base_velocity: the
    rms of the base's measured linear velocity against the estimate (m/s, per axis)."""

    links: tuple[str, ...]
    mnte: np.ndarray
    rmse: np.ndarray
    base_velocity: float = float("nan")

    @property
    def overall(self) -> dict:
        return dict(mnte=float(np.nanmean(self.mnte)), rmse=float(np.nanmean(self.rmse)),
                    base_velocity_rmse=self.base_velocity)

    def to_json(self) -> dict:
        return dict(overall=self.overall, per_link={n: dict(mnte=float(m), rmse=float(r))
                                                    for n, m, r in zip(self.links, self.mnte, self.rmse)})


WORSE = 1e-3  # an effect that raises its error by more than this share once re-tracked is taken back (or not taken)


def errors(analysis: Analysis, b: int, transient: float = 1.0) -> Errors:
    """The tracking errors of subject b against its (current, corrected) measurements."""
    time = analysis.time
    keep = time >= time[0] + (transient if float(time[-1] - time[0]) > 3 * transient else 0.0)
    ok = analysis.valid[:, b] & keep[:, None]  # [T,L]
    err = orientation_error(torch.where(ok[..., None, None], analysis.R_m[:, b], analysis.R_hat[:, b]), analysis.R_hat[:, b])
    dw = torch.where(ok[..., None], analysis.w_m[:, b] - analysis.w_hat[:, b], 0.0).square().sum(-1) / 3.0
    n = ok.sum(0).clamp(min=1)
    v_hat = analysis.trajectory.velocity[:, b, :3]
    if analysis.trajectory.velocity.shape[0] > 1:  # the midpoint scheme's nu_k is the mean over the step before t_k
        v_hat = torch.cat((0.5 * (v_hat[:-1] + v_hat[1:]), v_hat[-1:]))
    dv = (analysis.v_m[:, b] - v_hat)[keep]
    dv = dv[torch.isfinite(dv).all(-1)]
    return Errors(analysis.links, (err.sum(0) / n).numpy(), (dw.sum(0) / n).sqrt().numpy(),
                  float(dv.square().mean().sqrt()) if len(dv) else float("nan"))


@dataclass
class Step:
    """One added effect with the errors before and after it."""

    effect: Effect
    before: Errors
    after: Errors


@dataclass
class Diagnosis:
    """What the loop found for one recording: the effects (in the order added) with the errors
    before and after each, the corrected recording and the (augmented) URDF, the first and last
    analyses (subject `index` of their batches), the best candidate left (not significant), where
    the residual sits at the end (link_summary rows, largest first), the joints at a limit, and
    the candidates the data cannot identify (no fit, notes saying why), and the significant ones
    not kept (implausible values, or added and taken back because re-tracking with them did not
    lower the error; notes saying which). complete: the loop ended because no candidate was
    significant any more (not at max_effects)."""

    steps: list[Step]
    recording: Recording
    original: Recording
    urdf: str
    model: KinematicModel
    links: tuple[str, ...]
    first: tuple[Analysis, int]
    last: tuple[Analysis, int]
    best_rejected: Effect | None
    remaining: list[dict] = field(default_factory=list)
    limits: list[dict] = field(default_factory=list)
    unobservable: list[Effect] = field(default_factory=list)
    rejected: list[Effect] = field(default_factory=list)
    complete: bool = True
    stop: str = ""  # why the loop stopped: a key of STOPS
    noise: NoiseFloor | None = None  # what a correct model would leave, estimated on the last analysis
    joint: jointfit.Joint | None = None  # the kept measurement effects fitted jointly at the end (jointfit.py)
    rounds: int = 0  # the rounds that added effects
    negligible: list[Effect] = field(default_factory=list)  # significant, but below their family's floor: not added
    unseen: dict = field(default_factory=dict)  # link: [m,3] directions (link frame) of a sensor turn the joints follow
    confounded: dict = field(default_factory=dict)  # link: its sensor's turns told from a neighbour's only poorly

    @property
    def why_stopped(self) -> str:
        share = "" if self.noise is None else f" (the noise accounts for {100 * self.noise.share:.0f} % of the residual)"
        return STOPS.get(self.stop, self.stop) + share

    @property
    def effects(self) -> list[Effect]:
        return [s.effect for s in self.steps]

    @functools.cached_property  # the report reads them dozens of times; each is a pass over [T,L] rotations
    def before(self) -> Errors:
        return errors(*self.first)

    @functools.cached_property
    def after(self) -> Errors:
        return errors(*self.last)

    def calibration(self) -> dict:
        """The measurement effects, as `apply_calibration` reads them (JSON-ready)."""
        return dict(format=FORMAT, links=list(self.links),
                    effects=[e.to_json() for e in self.effects if not e.model_effect],
                    fit=None if self.joint is None else self.joint.note)

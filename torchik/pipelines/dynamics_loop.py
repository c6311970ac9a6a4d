"""The loop on forces closed on a tracked walk: what `torchik dynamics` runs after the inverse dynamics.

1. **The plates**: the feet's ground reactions (`MotionDynamics.wrenches`, one per foot) taken back to
   the plates that measured them [T,P,6], by the contacts the reader gave the feet
   (meta["force_plates"]["contacts"], through the link map's segments): a plate's centre of pressure
   off is the plate's, not the foot's. Where a foot stands on two plates at once, or one plate carries
   two feet, the plates' shares are unknown (NaN) and those frames are left out of the fit. Without
   the contacts (a recording that kept only the feet's wrenches) each foot counts as a plate.
2. **The fit**: `fit_dynamics` over `residual_frames` (the plates carry every foot on the ground, one
   is loaded, and none is missing within the low-pass' reach: elsewhere the residual holds a foot's
   reaction no plate measured), with the plates as read low-passed at the motion's cutoff: the
   residual is a linear balance, the model's free base wrench less the plates', so through one filter
   it is the filtered residual of the unfiltered signals; through two (the plates at 30 Hz, the motion
   at 6 Hz) it also holds the plates' content between the cut-offs, the impacts most (Kristianslund
   et al. 2012, J Biomech 45:666, on matching the cut-offs of forces and motion), which no effect
   explains. The torques keep the plates as the inverse dynamics took them (`--wrench-cutoff`): the
   residual fitted and reported is the matched one, `ClosedLoop.wrench_before`, `wrench_after`.
3. **The correction**: the kept effects applied (the model's masses and centres of mass; each plate's
   centre of pressure offset undone on the foot it carried; the feet's reactions read at the fitted
   lag) and the forces computed again on the same trajectory (masses do not move the kinematics).

The residual is compared before and after over the same frames, in the weight and mass the subject
was given (`LoopResidual`): the fitted body mass does not rescale the yardstick.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording
from ..method.dynamics.inverse import GRAVITY
from ..method.kinematics import KinematicModel
from .dynamics import MotionDynamics, residual_frames, with_forces
from .dynamics_effects import cop_effect, corrected_plates, shift
from .dynamics_fit import DynamicsFit, fit_dynamics


@dataclass(frozen=True)
class LoopResidual:
    """The base's residual over the fitted frames: force (fraction of the body weight given) rms and
    max, moment (N m per kg of the body mass given) rms and max."""

    force_rms: float
    force_max: float
    moment_rms: float
    moment_max: float

    def to_json(self) -> dict:
        return dict(force_rms_per_weight=self.force_rms, force_max_per_weight=self.force_max,
                    moment_rms_n_m_per_kg=self.moment_rms, moment_max_n_m_per_kg=self.moment_max)


@dataclass
class ClosedLoop:
    """`before` and `after` the loop (the same motion; `after` with the corrected model and plates),
    wrench_before and wrench_after [T,6] their base residuals with the plates low-passed as the motion
    is (module docstring, 2), `frames` [T] those fitted and compared, `fit` what was found (None when
    nothing could be fitted: `reason` says why), `plates` the plates' names in the fit's order, `mass`
    (kg) the body mass given."""

    before: MotionDynamics
    after: MotionDynamics
    wrench_before: np.ndarray
    wrench_after: np.ndarray
    frames: np.ndarray
    fit: DynamicsFit | None
    plates: tuple[str, ...]
    mass: float
    reason: str = ""

    def residual(self, wrench: np.ndarray) -> LoopResidual:
        """The residual `wrench` [T,6] (`wrench_before` or `wrench_after`) over `frames`."""
        wrench = wrench[self.frames]
        force = np.linalg.norm(wrench[:, :3], axis=-1) / (self.mass * float(np.linalg.norm(GRAVITY)))
        moment = np.linalg.norm(wrench[:, 3:], axis=-1) / self.mass
        rms = lambda x: float(np.sqrt(np.nanmean(x ** 2))) if np.isfinite(x).any() else float("nan")  # noqa: E731
        top = lambda x: float(np.nanmax(x)) if np.isfinite(x).any() else float("nan")  # noqa: E731
        return LoopResidual(rms(force), top(force), rms(moment), top(moment))

    def to_json(self) -> dict:
        fit = self.fit
        return dict(frames=int(self.frames.sum()), plates=list(self.plates), not_fitted=self.reason or None,
                    before=self.residual(self.wrench_before).to_json(), after=self.residual(self.wrench_after).to_json(),
                    kept=[] if fit is None else [dict(name=e.name, value=list(e.value), units=list(e.labels),
                                                      relative=e.relative, score=e.score, halves=[list(h) for h in e.halves])
                                                 for e in fit.effects],
                    refused=[] if fit is None else [dict(name=r.name, value=list(r.value), reason=r.reason)
                                                    for r in fit.refused],
                    scores_not_kept={} if fit is None else fit.scores)

    def lines(self) -> list[str]:
        """What the command prints: the residual before and after, the effects kept and refused."""
        b, a = self.residual(self.wrench_before), self.residual(self.wrench_after)
        out = [f"loop on forces over the {int(self.frames.sum())} frames the plates carry every foot: residual force "
               f"rms {100 * b.force_rms:.1f} -> {100 * a.force_rms:.1f} % of body weight (max {100 * b.force_max:.1f} "
               f"-> {100 * a.force_max:.1f}), moment rms {b.moment_rms:.3f} -> {a.moment_rms:.3f} N m/kg"]
        if self.fit is None:
            return out + [f"    not fitted: {self.reason}"]
        out += [f"    kept {_kept(e)}" for e in self.fit.effects] or ["    kept nothing: no effect explains the residual"]
        out += [f"    refused {r.name} ({_values(r.value)}): {r.reason}" for r in self.fit.refused]
        return out


def close_loop(model: KinematicModel, recording: Recording, dynamics: MotionDynamics) -> ClosedLoop:
    """The loop of the module docstring on `dynamics` (`motion_dynamics` of `recording`, mapped, on
    `model`): the fit, and the forces again with what it kept."""
    frames = residual_frames(dynamics)
    plates, names, owner = plate_wrenches(dynamics, recording)
    matched = matched_residual(dynamics, model, recording, dynamics.wrenches) if dynamics.wrench_links else \
        dynamics.base_wrench
    loop = ClosedLoop(dynamics, dynamics, matched, matched, frames, None, names, dynamics.mass)
    if not dynamics.wrench_links:
        loop.reason = "no ground reactions on the model"
        return loop
    try:
        fit = fit_dynamics(model, dynamics.trajectory, torch.as_tensor(plates, dtype=model.dtype),
                           cutoff=dynamics.notes["cutoff_hz"], frames=torch.as_tensor(frames), plate_names=names)
    except InputError as error:
        loop.reason = str(error)
        return loop
    loop.fit = fit
    if fit.effects:
        rate = 1.0 / float(np.median(np.diff(dynamics.time)))
        wrenches = corrected_wrenches(dynamics.wrenches, plates, names, owner, fit, rate)
        loop.after = with_forces(dynamics, fit.model, recording, wrenches)
        loop.wrench_after = matched_residual(loop.after, fit.model, recording, wrenches)
    return loop


def matched_residual(dynamics: MotionDynamics, model: KinematicModel, recording: Recording,
                     wrenches: np.ndarray) -> np.ndarray:
    """[T,6] the base's residual of `dynamics`' motion on `model` with the feet's `wrenches` low-passed
    at the motion's cutoff, whatever the torques took them at (module docstring, 2)."""
    notes = dict(dynamics.notes, wrench_cutoff_hz=dynamics.notes["cutoff_hz"])
    return with_forces(replace(dynamics, notes=notes), model, recording, wrenches).base_wrench


def plate_wrenches(dynamics: MotionDynamics, recording: Recording) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """The plates' wrenches [T,P,6] (NaN where a plate's share is unknown), their names, and owner
    [T,P] each plate's foot (its column in `wrench_links`, -1 for none) (module docstring, 1)."""
    W, links = dynamics.wrenches, dynamics.wrench_links
    T = len(W)
    contacts = ((recording.meta.get("force_plates") or {}).get("contacts")) or []
    to_link = {segment: link for link, segment in ((recording.meta.get("link_map") or {}).get("segments") or {}).items()}
    numbers = sorted({c["plate"] for c in contacts})
    if not numbers or not any(to_link.get(c["link"], c["link"]) in links for c in contacts):  # each foot a plate
        return W.copy(), tuple(f"{link}'s plates" for link in links), np.broadcast_to(np.arange(len(links)),
                                                                                       (T, len(links))).copy()
    owner = np.full((T, len(numbers)), -1)
    for c in contacts:
        link = to_link.get(c["link"], c["link"])
        if link in links:
            owner[c["start_frame"]:min(c["stop_frame"], T), numbers.index(c["plate"])] = links.index(link)
    plates = np.zeros((T, len(numbers), 6))
    for p in range(len(numbers)):
        on = owner[:, p] >= 0
        plates[on, p] = W[on, owner[on, p]]
        twice = on & ((owner == owner[:, p:p + 1]).sum(-1) > 1)  # the foot on another plate too: shares unknown
        plates[twice, p] = np.nan
    return plates, tuple(f"plate {n}" for n in numbers), owner


def corrected_wrenches(wrenches: np.ndarray, plates: np.ndarray, names: tuple[str, ...], owner: np.ndarray,
                       fit: DynamicsFit, rate: float) -> np.ndarray:
    """The feet's wrenches [T,L,6] with each plate's fitted centre-of-pressure offset undone on the foot
    it carried (where its share is known) and read at the fitted lag."""
    out = wrenches.copy()
    level = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # the fit's plates' normal: level plates
    kept = {e.name: e for e in fit.effects if e.kind == "cop"}
    known = torch.as_tensor(np.nan_to_num(plates))
    for p, name in enumerate(names):
        e = kept.get(f"{name} centre of pressure")
        if e is None:
            continue
        effect = cop_effect(p, level, name)
        undone = corrected_plates(known, [(effect, torch.tensor(e.value))], rate, 0.0).numpy()
        on = (owner[:, p] >= 0) & np.isfinite(plates[:, p]).all(-1)
        out[on, owner[on, p], 3:] += (undone - plates)[on, p, 3:]
    if fit.lag:
        unknown = np.isnan(out)  # shifted as zero, unknown again after
        out = shift(torch.as_tensor(np.nan_to_num(out)), rate, fit.lag).numpy()
        out[unknown] = np.nan
    return out


def _values(values) -> str:
    return ", ".join(f"{v:+.4g}" for v in values)


def _kept(e) -> str:
    values = ", ".join(f"{v:+.4g} {label}" for label, v in zip(e.labels, e.value))
    share = "" if e.relative is None else f" ({100 * e.relative:+.1f} % of the segment's)"
    return f"{e.name}: {values}{share}; held-out score {e.score:.0f}"

"""`torchik retarget`: a human recording to iCub joint trajectories a position controller can stream.

The recording (the human models' links, or any skeleton through --map) goes through the built-in
human-to-iCub map (models/maps/human_to_icub.toml), is resampled to the controller's rate when it
has another (orientations by slerp, velocities and the base position linearly), and iCub tracks it
with dynamical IK (midpoint scheme). The start is the whole-body IK solution of the first frame,
inside every limit, so every sample is: each step's velocity bounds keep the joints within
their limits and the coupled shoulder/elbow limits A s <= b, and the output is checked against
both before it is written (1e-6 rad).

Output (.npz): time [T] s, joint_names [n], joint_positions [T,n] rad, joint_velocities [T,n]
rad/s, base_position [T,3], base_rotation [T,3,3], mnte [T] (iCub link orientations against the
mapped human ones), rate_hz. The rates are the steps' own: s_k = s_{k-1} + dt * rate_k exactly, so
angles and rates agree, and both are what the limits allowed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import InputError
from ..io.files import replacing
from ..io.maps import apply_map, load_map
from ..io.recording import Recording
from ..io.targets import recording_targets
from ..method import so3
from ..method.baselines import WholeBodyIK
from ..method.kinematics import KinematicModel
from ..method.limits import LimitSettings
from ..method.models import load_model
from ..method.settings import TrackerSettings
from ..method.state import State
from ..method.targets import Targets
from ..method.tracker import DynamicalIK
from .evaluation import known_targets, summary, tracking_errors

LIMIT_TOLERANCE = 1e-6  # rad (and the units of A s <= b): the largest excursion accepted in the output
MIN_RATE = 50.0  # Hz: slower streams make a position controller's steps too coarse


@dataclass(frozen=True)
class Retargeted:
    """iCub trajectories: time [T]; joint_names (n); joint_positions, joint_velocities [T,n];
    base_position [T,3]; base_rotation [T,3,3]; mnte [T]; limit_excess: the largest excursion
    beyond a joint or coupled limit over the whole trajectory (<= 0: all inside)."""

    time: np.ndarray
    joint_names: tuple[str, ...]
    joint_positions: np.ndarray
    joint_velocities: np.ndarray
    base_position: np.ndarray
    base_rotation: np.ndarray
    mnte: np.ndarray
    limit_excess: float


def human_to_icub(recording: Recording, icub: KinematicModel) -> Recording:
    """A recording in the human models' links, in iCub's through the built-in human_to_icub map."""
    return apply_map(recording, load_map("human_to_icub"), icub)


def resample(recording: Recording, rate: float) -> Recording:
    """The recording at `rate` Hz over its own time span: orientations by slerp between the frames
    around each new instant, angular velocities, base position and velocity linearly. A new sample
    next to a missing frame (NaN) is missing too."""
    t = recording.time
    new = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1) / rate
    k = np.clip(np.searchsorted(t, new, side="right") - 1, 0, len(t) - 2)  # frame before each new instant
    alpha = np.clip((new - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
    R0, R1 = torch.from_numpy(recording.orientation[k]), torch.from_numpy(recording.orientation[k + 1])
    a = torch.from_numpy(alpha)[:, None, None]
    rotation = R0 @ so3.exp(a * so3.log(R0.transpose(-1, -2) @ R1))  # [T',L,3,3]
    lerp = lambda x: x[k] + alpha.reshape((-1,) + (1,) * (x.ndim - 1)) * (x[k + 1] - x[k])  # noqa: E731
    meta = dict(recording.meta, resampled_from_hz=recording.frame_rate, frame_rate=rate)
    return Recording(time=new, links=recording.links, orientation=rotation.numpy(),
                     angular_velocity=lerp(recording.angular_velocity), base_link=recording.base_link,
                     base_position=lerp(recording.base_position), base_linear_velocity=lerp(recording.base_linear_velocity),
                     meta=meta)


def limit_excess(model: KinematicModel, joint_positions: torch.Tensor) -> float:
    """The largest amount by which joint_positions [T,n] exceed a joint limit or a coupled limit
    row (negative: the smallest margin)."""
    return float(limit_excess_rows(model, joint_positions).amax())


def limit_excess_rows(model: KinematicModel, joint_positions: torch.Tensor) -> torch.Tensor:
    """Per row of joint_positions [T,n], the largest excess beyond a joint or coupled limit [T]."""
    excess = torch.maximum(joint_positions - model.upper, model.lower - joint_positions).amax(-1)
    if model.linear_limits is not None:
        A, b = model.linear_limits.A, model.linear_limits.b
        excess = torch.maximum(excess, (joint_positions @ A.T - b).amax(-1))
    return excess


def check_retargeting(rate: float, gain: float, limits: LimitSettings) -> None:
    """InputError unless a position controller can be streamed at `rate` Hz with gain K and `limits`."""
    if rate < MIN_RATE:
        raise InputError(f"rate {rate:g} Hz: a position controller needs {MIN_RATE:g} Hz or more")
    if gain <= 0 or gain / rate >= 2.0:
        raise InputError(f"gain {gain:g} 1/s at {rate:g} Hz: K must be positive with K dt < 2 (stability)")
    if limits.max_rate <= 0:
        raise InputError(f"the largest joint rate must be positive, got {limits.max_rate:g} rad/s")


class RetargetIK(DynamicalIK):
    """iCub's tracker: every start (the first, and a restart after a gap in time or a broken step)
    from the whole-body IK fit of the targets, inside every limit. iCub's zero configuration, where
    the tracker would otherwise restart, is outside its coupled shoulder limits, and the tracker
    would return from there at a bounded rate only."""

    def __init__(self, icub: KinematicModel, links, **settings):
        super().__init__(icub, links, **settings)
        self.whole_body = WholeBodyIK(icub, links)

    def initial_state(self, targets: Targets) -> State:
        return self.whole_body.solve(targets, super().initial_state(targets)).state


def icub_tracker(icub: KinematicModel, links, rate: float, gain: float, limits: LimitSettings,
                 backend: str = TrackerSettings.backend, max_gap: float = TrackerSettings.max_gap) -> RetargetIK:
    """iCub's tracker for the links at `rate` Hz with gain K and `limits`; start it at
    `initial_state` of the first targets. max_gap: see TrackerSettings (inf: never restart after a gap)."""
    return RetargetIK(icub, links, position_gain=gain, orientation_gain=gain, dt=1.0 / rate, limits=limits,
                      backend=backend, max_gap=max_gap)


def retarget(recording: Recording, rate: float = 100.0, gain: float = TrackerSettings.orientation_gain,
             progress: bool | None = None, transient: float = 2.0,
             limits: LimitSettings = LimitSettings()) -> tuple[Retargeted, dict]:
    """Retarget a recording in the human models' links to iCub at `rate` Hz with gain K (1/s) and
    the tracker's `limits` (limits.max_rate caps every joint's rate, rad/s). Returns the iCub
    trajectories and a report (MNTE after `transient` s, the limits' margin, the rate)."""
    check_retargeting(rate, gain, limits)
    icub = load_model("icub")
    mapped = human_to_icub(recording, icub)
    if len(mapped.time) < 2:
        raise InputError("the recording has fewer than two frames")
    if abs(mapped.frame_rate - rate) > 1e-6 * rate:
        mapped = resample(mapped, rate)
    links = mapped.links
    sequence = recording_targets(mapped, links, dtype=icub.dtype, device=icub.device)
    tracker = icub_tracker(icub, links, rate, gain, limits)
    start = tracker.initial_state(sequence[0])
    trajectory = tracker.run(sequence, start, progress=progress)
    error = tracking_errors(icub, trajectory, sequence, links)["mnte"][:, 0]  # NaN where a target is missing
    known = known_targets(sequence)[:, 0]
    s = trajectory.joint_positions[:, 0]
    host = lambda x: x.detach().cpu().numpy()  # noqa: E731
    result = Retargeted(host(trajectory.time), icub.joint_names, host(s), host(trajectory.velocity[:, 0, 6:]),
                        host(trajectory.base_position[:, 0]), host(trajectory.base_rotation[:, 0]), host(error),
                        limit_excess(icub, s))
    report = dict(frames=len(result.time), rate_hz=rate, duration_s=float(result.time[-1] - result.time[0]),
                  mnte=summary(error[known], trajectory.time[known], transient) if bool(known.any()) else None,
                  limit_excess=result.limit_excess, max_joint_rate=float(np.abs(result.joint_velocities).max()),
                  qp_fallbacks=int((~trajectory.diagnostics["solved"]).sum()))
    return result, report


def save(result: Retargeted, path: str | Path, meta: dict | None = None) -> Path:
    """Write `result` as .npz (see the module docstring), replacing `path` only once complete."""
    path = Path(path)
    arrays: dict[str, Any] = dict(time=result.time, joint_names=np.array(result.joint_names, dtype=str),
                  joint_positions=result.joint_positions, joint_velocities=result.joint_velocities,
                  base_position=result.base_position, base_rotation=result.base_rotation, mnte=result.mnte,
                  rate_hz=np.array(1.0 / np.median(np.diff(result.time))),
                  source=np.array(str((meta or {}).get("source", ""))))
    with replacing(path) as part, open(part, "wb") as f:
        np.savez(f, **arrays)
    return path

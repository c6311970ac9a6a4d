"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from ..errors import InputError
from ..io.plausible import Plausibility, drop_implausible
from ..io.recording import Recording
from ..io.targets import recording_targets
from ..method.kinematics import KinematicModel
from ..method.settings import TrackerSettings
from ..method.state import Trajectory
from ..method.tracker import DynamicalIK
from .evaluation import position_errors, summary, tracking_errors, tracking_statistics


def track_recording(model: KinematicModel, recording: Recording, links, settings: TrackerSettings | None = None,
                    progress: bool = False, transient: float = 2.0, position_links=None,
                    plausibility: Plausibility | None = None) -> tuple[Trajectory, dict]:
    """Track `recording` (link names already the model's) with `settings` (default TrackerSettings(),
    dt the recording's median frame interval) and return the trajectory and a report (metrics
    after `transient` seconds, step times, failures). Samples beyond `plausibility` (default Plausibility()) are dropped
    as missing ones (`drop_implausible`) and counted.

    The trajectory's diagnostics mnte and rmse [T,1] are the paper's metrics (`tracking_errors`:
    the estimate at t_k against the targets at t_k). Ctrl-C stops the tracking early: the
    trajectory and report then cover the frames done and report["interrupted"] is True.
    position_links: the links with position targets (default the base; others need the recording's
    `position`); with any, the report's position_error_m gives their distance to the estimate."""
    links = tuple(links)
    recording, implausible = drop_implausible(recording, plausibility or Plausibility())
    sequence = recording_targets(recording, links, position_links, dtype=model.dtype, device=model.device)
    if links and not bool(torch.isfinite(sequence.rotation).flatten(-2).all(-1).any()):
        # the pose would only be integrated from the base's velocity: no figure of it could be checked
        raise InputError(f"no orientation of the tracked links ({len(links)}) is measured in any of the "
                         f"{len(recording.time)} frames (all missing, non-finite or implausible): nothing to track")
    settings = settings or TrackerSettings()
    dt = nominal_dt(recording, settings)
    settings = dataclasses.replace(settings, dt=dt)
    trajectory = DynamicalIK(model, links, position_links, settings=settings).run(sequence, progress=progress,
                                                                                  interruptible=True)
    done = len(trajectory.time)
    trajectory.diagnostics.update(tracking_errors(model, trajectory, sequence, links, settings.scheme))
    time = trajectory.time
    d = trajectory.diagnostics
    report = dict(
        model=model.name, links=len(links), frames=done, duration_s=float(time[-1] - time[0]),
        rate_hz=1.0 / dt, scheme=settings.scheme, backend=settings.backend,
        gains=dict(position=settings.position_gain, orientation=settings.orientation_gain),
        transient_s=transient,
        **tracking_statistics(trajectory, sequence, recording, model, transient),
        step_time_ms={k: v * 1e3 for k, v in summary(d["step_time"], time, 0.0).items()},
        qp_fallbacks=int((~d["solved"]).sum()), dropped_targets=int(d["dropped"].sum()),
        projected_targets=int(d["projected"].sum()), implausible_samples=implausible,
        failed_steps=int(d["failed"].sum()), failed_subjects=d["failed"].any(0).nonzero()[:, 0].tolist(),
        segments=segments(time, d["new_segment"][:, 0]),
        active_constraints_mean=float(d["active_constraints"].double().mean()), interrupted=trajectory.interrupted,
    )
    if settings.compile:  # the steps replayed compiled (their kinematics are not timed apart: NaN)
        report["compiled_steps"] = int(torch.isnan(d["kinematics_time"]).sum())
    if position_links is not None:
        error = position_errors(model, trajectory, sequence, position_links)[:, 0]  # [T,P]
        report["position_error_m"] = {link: summary(e[torch.isfinite(e)], time[torch.isfinite(e)], transient)
                                      for link, e in zip(position_links, error.unbind(-1)) if bool(torch.isfinite(e).any())}
    return trajectory, report


def nominal_dt(recording: Recording, settings: TrackerSettings) -> float:
    """The time step `track_recording` tracks at: the median frame interval (settings.dt for one frame)."""
    return float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else settings.dt


def segments(time: torch.Tensor, new_segment: torch.Tensor) -> list[list[float]]:
    """[start, end] s of the stretches between gaps: time [T], new_segment [T] bool (True where a gap
    ended and the tracker restarted)."""
    starts = [0] + new_segment[1:].nonzero()[:, 0].add(1).tolist()
    ends = [k - 1 for k in starts[1:]] + [len(time) - 1]
    return [[float(time[a]), float(time[b])] for a, b in zip(starts, ends)]


def output_fault(trajectory: Trajectory, report: dict, max_failed: float) -> str | None:
    """Why a tracked run must not be trusted (a line), or None: a non-finite value in the trajectory
    or the report's figures, or steps failed (the invariant broken, the subject restarted) on more
    than `max_failed` (a fraction) of some subject's steps."""
    d = trajectory.diagnostics
    for name in ("base_position", "base_rotation", "joint_positions", "velocity"):
        bad = ~torch.isfinite(getattr(trajectory, name)).flatten(2).all(-1)  # [T,B]
        if bool(bad.any()):
            return (f"non-finite {name} at {int(bad.any(1).sum())} steps (subjects {_listed(bad.any(0))}); "
                    "no output written")
    if not _finite_numbers(report):
        return "a non-finite figure in the report; no output written"
    failed = d["failed"]  # [T,B]
    fraction = failed.double().mean(0)  # [B]
    if bool((fraction > max_failed).any()):
        return (f"{int(failed.sum())} steps failed (a non-finite state, a rotation not orthonormal or joints beyond their "
                f"limits: the subject restarted) for subjects {_listed(failed.any(0))}, over --max-failed "
                f"{max_failed:g} of the steps; no output written")
    return None


def _listed(subjects: torch.Tensor) -> str:
    return ", ".join(str(b) for b in subjects.nonzero()[:, 0].tolist())


def _finite_numbers(value) -> bool:
    if isinstance(value, dict):
        return all(_finite_numbers(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_finite_numbers(v) for v in value)
    return not isinstance(value, float) or math.isfinite(value)

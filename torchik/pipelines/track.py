"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..io.recording import Recording
from ..io.targets import recording_targets
from ..method.kinematics import KinematicModel
from ..method.settings import TrackerSettings
from ..method.state import Trajectory
from ..method.tracker import DynamicalIK
from .evaluation import position_errors, summary, tracking_errors, tracking_statistics


def track_recording(model: KinematicModel, recording: Recording, links, settings: TrackerSettings | None = None,
                    progress: bool = False, transient: float = 2.0, position_links=None) -> tuple[Trajectory, dict]:
    """Track `recording` (link names already the model's) with `settings` (default TrackerSettings(),
    dt the recording's median frame interval) and return the trajectory and a report (metrics
    after `transient` seconds, step times, failures).

    The trajectory's diagnostics mnte and rmse [T,1] are the paper's metrics (`tracking_errors`:
    the estimate at t_k against the targets at t_k). Ctrl-C stops the tracking early: the
    trajectory and report then cover the frames done and report["interrupted"] is True.
    position_links: the links with position targets (default the base; others need the recording's
    `position`); with any, the report's position_error_m gives their distance to the estimate."""
    links = tuple(links)
    sequence = recording_targets(recording, links, position_links, dtype=model.dtype, device=model.device)
    settings = settings or TrackerSettings()
    dt = float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else settings.dt
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
        active_constraints_mean=float(d["active_constraints"].double().mean()), interrupted=trajectory.interrupted,
    )
    if position_links is not None:
        error = position_errors(model, trajectory, sequence, position_links)[:, 0]  # [T,P]
        report["position_error_m"] = {link: summary(e[torch.isfinite(e)], time[torch.isfinite(e)], transient)
                                      for link, e in zip(position_links, error.unbind(-1)) if bool(torch.isfinite(e).any())}
    return trajectory, report

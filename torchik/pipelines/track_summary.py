"""What `torchik track` reports of a run, and why its outputs must not be trusted, gathered a part
of the run at a time: a few numbers a step (the metrics and step times that the report's
statistics are taken of), counts and sums of the rest. An hour's run needs a few MB for it."""

from __future__ import annotations

import math

import torch

from ..io.recording import Recording
from ..method.kinematics import KinematicModel
from ..method.settings import TrackerSettings
from ..method.state import TargetSequence, Trajectory
from .evaluation import Series, TrackingStatistics, position_errors, summary

STATES = ("base_position", "base_rotation", "joint_positions", "velocity")
COUNTS = ("qp_fallbacks", "dropped_targets", "projected_targets", "failed_steps")


class TrackSummary:
    """A tracked run's report and faults: `add` each part of the trajectory (with its mnte and rmse
    diagnostics, `tracking_errors`) with its targets and recording, in order; then `report` and
    `fault`. position_links: the links whose distance to their position targets is reported
    (None: none); frames: the most samples the run can have (its recording's); settle: the seconds
    the run settled on its first frame before it started (0: it started from the zero posture)."""

    def __init__(self, model: KinematicModel, links: tuple[str, ...], position_links: tuple[str, ...] | None,
                 transient: float, frames: int, settle: float = 0.0):
        self.model, self.links, self.position_links, self.transient = model, links, position_links, transient
        self.settle = settle
        self.statistics = TrackingStatistics(model, transient, frames)
        self.step_time = Series(frames)
        self.new_segment = Series(frames)  # subject 0's [T] bool
        self.position_error = Series(frames)  # subject 0's [T,P]
        self.counts = dict.fromkeys(COUNTS, 0)
        self.active = [0.0, 0]  # sum and number of the active constraints' counts
        self.compiled_steps = 0  # replayed compiled: their kinematics are not timed apart (NaN)
        self.failed: torch.Tensor | None = None  # [B] steps failed per subject
        # per state: the steps with a non-finite value, and [B] which subjects had one
        self.non_finite: dict[str, tuple[int, torch.Tensor | None]] = dict.fromkeys(STATES, (0, None))

    @property
    def frames(self) -> int:
        return self.statistics.time.done

    def add(self, trajectory: Trajectory, sequence: TargetSequence, recording: Recording) -> None:
        """A part of the run: trajectory [t,B,...] and the targets and recording from its first sample."""
        d = trajectory.diagnostics
        self.statistics.add(trajectory, sequence, recording)
        self.step_time.append(d["step_time"])
        self.new_segment.append(d["new_segment"][:, 0])
        for name, value in zip(COUNTS, (~d["solved"], d["dropped"], d["projected"], d["failed"])):
            self.counts[name] += int(value.sum())
        self.active = [self.active[0] + float(d["active_constraints"].double().sum()),
                       self.active[1] + d["active_constraints"].numel()]
        self.compiled_steps += int(torch.isnan(d["kinematics_time"]).sum())
        failed = d["failed"].sum(0)
        self.failed = failed if self.failed is None else self.failed + failed
        for name in STATES:
            bad = ~torch.isfinite(getattr(trajectory, name)).flatten(2).all(-1)  # [t,B]
            steps, subjects = self.non_finite[name]
            self.non_finite[name] = (steps + int(bad.any(1).sum()),
                                     bad.any(0) if subjects is None else subjects | bad.any(0))
        if self.position_links:  # () when nothing measures a position (an IMU set's base left free)
            self.position_error.append(position_errors(self.model, trajectory, sequence, self.position_links)[:, 0])

    def report(self, settings: TrackerSettings, implausible: int, interrupted: bool) -> dict:
        """The report `torchik track` writes (settings: those tracked with, dt the nominal step;
        implausible: the samples dropped as implausible)."""
        time = self.statistics.time.values()
        assert self.failed is not None  # a part was added
        report = dict(
            model=self.model.name, links=len(self.links), frames=len(time), duration_s=float(time[-1] - time[0]),
            rate_hz=1.0 / settings.dt, scheme=settings.scheme, backend=settings.backend,
            gains=dict(position=settings.position_gain, orientation=settings.orientation_gain),
            transient_s=self.transient, settled_s=self.settle,
            **self.statistics.result(),
            step_time_ms={k: v * 1e3 for k, v in summary(self.step_time.values(), time, 0.0).items()},
            qp_fallbacks=self.counts["qp_fallbacks"], dropped_targets=self.counts["dropped_targets"],
            projected_targets=self.counts["projected_targets"], implausible_samples=implausible,
            failed_steps=self.counts["failed_steps"], failed_subjects=self.failed.nonzero()[:, 0].tolist(),
            segments=segments(time, self.new_segment.values()),
            active_constraints_mean=self.active[0] / self.active[1], interrupted=interrupted,
        )
        if settings.compile:
            report["compiled_steps"] = self.compiled_steps
        if self.position_links:
            error, t = self.position_error.values().cpu(), time.cpu()  # [T,P], [T]
            window = t >= t[0] + report["statistics_from_s"]  # the other statistics' window
            report["position_error_m"] = {}
            for link, e in zip(self.position_links, error.unbind(-1)):
                keep = window & torch.isfinite(e)
                if bool(keep.any()):
                    report["position_error_m"][link] = summary(e[keep], t[keep], 0.0)
        return report

    def fault(self, report: dict, max_failed: float) -> str | None:
        """Why the run's outputs must not be trusted (a line), or None: a non-finite value in the
        trajectory or in the report's figures, or steps failed (the invariant broken, the subject
        restarted) on more than `max_failed` (a fraction) of some subject's steps."""
        for name, (steps, subjects) in self.non_finite.items():
            if steps and subjects is not None:
                return f"non-finite {name} at {steps} steps (subjects {_listed(subjects)}); no output written"
        if not _finite_numbers(report):
            return "a non-finite figure in the report; no output written"
        assert self.failed is not None  # a part was added
        if bool((self.failed.double() / self.frames > max_failed).any()):
            return (f"{int(self.failed.sum())} steps failed (a non-finite state, a rotation not orthonormal or joints "
                    f"beyond their limits: the subject restarted) for subjects {_listed(self.failed > 0)}, over "
                    f"--max-failed {max_failed:g} of the steps; no output written")
        return None


def segments(time: torch.Tensor, new_segment: torch.Tensor) -> list[list[float]]:
    """[start, end] s of the stretches between gaps: time [T], new_segment [T] bool (True where a gap
    ended and the tracker restarted)."""
    starts = [0] + new_segment[1:].nonzero()[:, 0].add(1).tolist()
    ends = [k - 1 for k in starts[1:]] + [len(time) - 1]
    return [[float(time[a]), float(time[b])] for a, b in zip(starts, ends)]


def _listed(subjects: torch.Tensor) -> str:
    return ", ".join(str(b) for b in subjects.nonzero()[:, 0].tolist())


def _finite_numbers(value) -> bool:
    if isinstance(value, dict):
        return all(_finite_numbers(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_finite_numbers(v) for v in value)
    return not isinstance(value, float) or math.isfinite(value)

"""Track a recording with a model and report how well it went: the pipeline behind `torchik track`.

A recording is tracked a chunk of frames at a time (`track_chunks`): read (from a RecordingFile
or a Recording in memory), implausible samples dropped, made targets, tracked with the state
carried over, measured, and handed to the outputs (the report's figures, the trajectory file, the
rerun recording) as the next chunks are read. Memory is a few chunks', whatever the length; the
trajectory, the report and the outputs are those of tracking the whole recording at once.

`torchik track` and the cohort start the tracker at rest in the first frame's posture (`settle`
= SETTLE seconds on the first targets held still, `settled_state`), not from the zero posture: a
clinical trial of 1.5 to 4 s would otherwise be mostly the quarter second or so the tracker takes
to converge. The functions here take it as `settle` (default 0: from the zero posture, where the
live loop starts too).
"""

from __future__ import annotations

import dataclasses
from collections import deque
from typing import Iterable, Iterator, Protocol, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..io.plausible import ImplausibleFilter, Plausibility
from ..io.recording import Recording
from ..io.targets import target_chunks
from ..method.constraints import Limit
from ..method.kinematics import KinematicModel
from ..method.settings import TrackerSettings
from ..method.state import TargetSequence, Trajectory
from ..method.tasks import Task
from ..method.tracker import DynamicalIK
from .evaluation import tracking_errors
from .interrupts import deferred_interrupts
from .track_summary import TrackSummary

# frames read, tracked and written at a time: 41 s at 100 Hz, a few tens of MB for Human66; as many as
# the metrics' kinematics take per call (evaluation.py), so that they too are those of a run in one piece
CHUNK = 4096
# seconds the tracker holds still on the first frame's targets before the run (as the diagnosis does):
# at the default K = 20/s a small error decays to e^-10 of itself in 0.5 s; a real trial's first frame
# (MNTE 0.67 from the zero posture) is at its floor after 0.25 s
SETTLE = 0.5


class Source(Protocol):
    """A recording to track: a Recording in memory or a RecordingFile read a chunk at a time."""

    time: np.ndarray
    links: tuple[str, ...]

    def chunks(self, size: int) -> Iterator[Recording]: ...


class Output(Protocol):
    """Where each tracked part goes as the run goes (a file writer, a collector)."""

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None: ...


def track_recording(model: KinematicModel, recording: Recording, links, settings: TrackerSettings | None = None,
                    progress: bool = False, transient: float = 2.0, position_links=None,
                    plausibility: Plausibility | None = None, settle: float = 0.0) -> tuple[Trajectory, dict]:
    """Track `recording` (link names already the model's) with `settings` (default TrackerSettings(),
    dt the recording's median frame interval), from the zero posture or, with `settle` > 0 (s),
    from rest in the first frame's posture (as `torchik track`: SETTLE), and return the trajectory
    and a report (metrics after `transient` seconds, or over the whole run when it is shorter,
    step times, failures). Samples beyond `plausibility` (default Plausibility()) are dropped as
    missing ones (`drop_implausible`) and counted.

    The trajectory's diagnostics mnte and rmse [T,1] are the paper's metrics (`tracking_errors`:
    the estimate at t_k against the targets at t_k). Ctrl-C stops the tracking early: the
    trajectory and report then cover the frames done and report["interrupted"] is True.
    position_links: the links with position targets (default the base; others need the recording's
    `position`); with any, the report's position_error_m gives their distance to the estimate."""
    collected, settings = Collected(), settings or TrackerSettings()
    settings = dataclasses.replace(settings, dt=nominal_dt(recording, settings))
    summary, implausible, interrupted = track_chunks(model, recording, links, settings, [collected], progress=progress,
                                                     transient=transient, position_links=position_links,
                                                     plausibility=plausibility, settle=settle)
    return Trajectory.concatenate(collected.parts), summary.report(settings, implausible, interrupted)


class Collected:
    """An output that keeps every part (what `track_recording` returns, concatenated)."""

    def __init__(self) -> None:
        self.parts: list[Trajectory] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None:
        self.parts.append(trajectory)


def track_chunks(model: KinematicModel, source: Source, links, settings: TrackerSettings, outputs: Iterable[Output] = (),
                 *, progress: bool = False, transient: float = 2.0, position_links=None,
                 plausibility: Plausibility | None = None, chunk: int = CHUNK,
                 settle: float = 0.0, tasks: Sequence[Task] = (),
                 constraints: Sequence[Limit] = ()) -> tuple[TrackSummary, int, bool]:
    """Track `source` a chunk of `chunk` frames at a time with `settings` (dt: the nominal step),
    from the zero posture or, with `settle` > 0 (s), from rest in the first frame's posture
    (`settled_state`), each part of the trajectory, with its mnte and rmse diagnostics
    (`tracking_errors`), written to every output as it is done. Returns the run's TrackSummary, the
    number of samples dropped as implausible, and whether Ctrl-C (or SIGTERM) stopped the run (the
    outputs then hold the frames done). The recording is read once before the tracking: what is
    wrong with it (a frame that is not valid, nothing measured) is said before any work. tasks: the
    step's tasks beyond the paper's targets (a contact, a centre of mass, a posture: tasks.py), constraints:
    its limits beyond the model's (a contact held exactly: constraints.py)."""
    links, bounds = tuple(links), plausibility or Plausibility()
    position_links = tuple(position_links) if position_links is not None else None
    targets = lambda counted: target_chunks(_plausible(source.chunks(chunk), bounds, counted), links,  # noqa: E731
                                            position_links, dtype=model.dtype, device=model.device)
    implausible = _check_measured(targets, links, len(source.time))
    summary = TrackSummary(model, links, position_links, transient, len(source.time), settle)
    pending: deque[tuple[Recording, TargetSequence]] = deque()  # given to the tracker, their parts not yet back

    def parts() -> Iterator[TargetSequence]:
        for recording, sequence in targets([0]):
            pending.append((recording, sequence))
            yield sequence

    def deliver(part: Trajectory, recording: Recording, sequence: TargetSequence, following: torch.Tensor | None):
        """A part measured and written; following: the next part's first velocity, None after the last."""
        part.diagnostics.update(tracking_errors(model, part, sequence, links, settings.scheme, following))
        summary.add(part, sequence, recording)
        for output in outputs:
            output.write(part, sequence)

    time = torch.as_tensor(source.time, dtype=model.dtype, device=model.device)
    run = DynamicalIK(model, links, position_links, settings=settings, tasks=tasks, constraints=constraints).run_parts(
        parts(), time, progress=progress, interruptible=True, settle=settle)
    held = None  # a part waits for the next one's first velocity: its last estimate averages the two steps
    interrupted = False
    try:
        for part in run:
            recording, sequence = pending.popleft()
            interrupted = part.interrupted
            with deferred_interrupts():  # every output gets a part, or none does
                if held is not None:
                    deliver(*held, part.velocity[0] if len(part.time) else None)
                held = (part, recording, sequence) if len(part.time) else None
    except KeyboardInterrupt:  # while a part was handed over: the outputs hold the parts before it
        if held is None and not summary.frames:
            raise
        interrupted = True
    finally:
        run.close()
    if held is not None:
        with deferred_interrupts():
            deliver(*held, None)
    return summary, implausible, interrupted


def _plausible(chunks: Iterable[Recording], bounds: Plausibility, counted: list[int]) -> Iterator[Recording]:
    """The chunks with their implausible samples dropped (`ImplausibleFilter`), counted in counted[0]."""
    drop = ImplausibleFilter(bounds)
    for chunk in chunks:
        chunk, count = drop(chunk)
        counted[0] += count
        yield chunk


def _check_measured(targets, links: tuple[str, ...], frames: int) -> int:
    """Every chunk of `targets(counted)` made once (the reader validates each as it reads it);
    InputError when no orientation target is measured in any frame. Returns the number of samples
    dropped as implausible."""
    counted, measured = [0], not links
    for _, sequence in targets(counted):
        measured = measured or bool(torch.isfinite(sequence.rotation).flatten(-2).all(-1).any())
    if not measured:
        # the pose would only be integrated from the base's velocity: no figure of it could be checked
        raise InputError(f"no orientation of the tracked links ({len(links)}) is measured in any of the "
                         f"{frames} frames (all missing, non-finite or implausible): nothing to track")
    return counted[0]


def nominal_dt(recording: Source, settings: TrackerSettings) -> float:
    """The time step `track_recording` tracks at: the median frame interval (settings.dt for one frame)."""
    return float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else settings.dt

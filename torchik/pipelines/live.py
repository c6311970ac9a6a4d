"""The live loop behind `torchik live`: samples from a source (torchik/live/) tracked as they come,
every character one row of a batch, the estimates published as they are made.

A receiver thread reads the source and leaves each complete sample in a `Mailbox`: per character
at most `backlog` samples (default 1: the newest), an older one is stepped over and counted as
skipped when a newer arrives, so the queue never grows. The tracking loop takes one sample per
character per step (waiting up to `gather_s` for the characters of a frame to be all there), so
neither blocks the other. A step's dt is the frame counter's difference over the stream's rate:
lost frames give a longer step, as they would offline. A character without a sample in a step has
its targets dropped for it (it stands still); one silent for `stall_s` leaves the batch, is reported,
and joins again, from the pose of its new targets, when it comes back.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import torch

from ..io.maps import LinkMap
from ..live.mvn import rotations
from ..live.sample import Sample, Source
from ..method import so3
from ..method.kinematics import KinematicModel
from ..method.settings import TrackerSettings
from ..method.state import PER_SUBJECT, State, Trajectory
from ..method.targets import Targets
from ..method.tracker import DynamicalIK
from .evaluation import summary


class Mailbox:
    """Complete samples from the receiver thread to the tracking loop: per character a deque of at
    most `backlog`; putting into a full one steps over its oldest sample (counted in `skipped`)."""

    def __init__(self, backlog: int = 1):
        self.backlog = backlog
        self.queues: dict[int, deque] = {}
        self.skipped: dict[int, int] = {}
        self.last_put: dict[int, float] = {}  # per character, when its newest sample came in
        self.condition = threading.Condition()
        self.finished = False  # the source ended

    def put(self, sample: Sample) -> None:
        with self.condition:
            queue = self.queues.setdefault(sample.character, deque())
            if len(queue) >= self.backlog:
                queue.popleft()
                self.skipped[sample.character] = self.skipped.get(sample.character, 0) + 1
            queue.append(sample)
            self.last_put[sample.character] = time.perf_counter()
            self.condition.notify()

    def finish(self) -> None:
        with self.condition:
            self.finished = True
            self.condition.notify()

    def take(self, active, timeout: float, gather: float) -> dict[int, Sample]:
        """The oldest queued sample of each character that has one: waits up to `timeout` for the
        first, then up to `gather` for every `active` character to have one."""
        with self.condition:
            self.condition.wait_for(lambda: self.finished or any(self.queues.values()), timeout)
            deadline = time.perf_counter() + gather
            while not self.finished and not all(self.queues.get(c) for c in active):
                remaining = deadline - time.perf_counter()
                if remaining <= 0 or not self.condition.wait(remaining):
                    break
            return {c: q.popleft() for c, q in self.queues.items() if q}


@dataclass(frozen=True)
class Selection:
    """Which of a source's segments are the tracked links, in the model's frames: source rows
    `rows` [n_o] turned by `offsets` [n_o,3,3] (R_link = R_segment C); the base segment's row."""

    links: tuple[str, ...]
    rows: np.ndarray
    offsets: np.ndarray | None
    base_row: int

    @classmethod
    def build(cls, source_links, links, link_map: LinkMap | None = None) -> "Selection":
        """From a map (its offsets calibrated), or, without one, the source's segments named as `links`."""
        from ..errors import InputError

        index = {name: i for i, name in enumerate(source_links)}
        if link_map is None:
            missing = [name for name in links if name not in index]
            if missing:
                raise InputError(f"the stream has no segments {missing} (it has {list(source_links)}); give --map")
            return cls(tuple(links), np.array([index[n] for n in links]), None, index[links[0]])
        missing = sorted({e.segment for e in link_map.entries} - set(index))
        if missing:
            raise InputError(f"map {link_map.name!r} needs segments {missing} that the stream lacks; "
                             f"it has {list(source_links)}")
        offsets = [e.offset for e in link_map.entries if e.offset is not None]
        if len(offsets) < len(link_map.entries):
            raise InputError(f"map {link_map.name!r} calibrates its offsets: give --calibration STATIC_TRIAL")
        return cls(link_map.links, np.array([index[e.segment] for e in link_map.entries]),
                   np.stack(offsets), index[link_map.base_segment])


def sample_targets(samples: list[Sample | None], selection: Selection, dtype=torch.float64) -> Targets:
    """Tracker targets [B,...] from one sample per character (None: all its targets dropped), the
    same arithmetic as `apply_map` and `recording_targets` offline."""
    n = len(selection.rows)
    R = np.full((len(samples), n, 3, 3), np.nan)
    w = np.full((len(samples), n, 3), np.nan)
    p = np.full((len(samples), 1, 3), np.nan)
    v = np.full((len(samples), 1, 3), np.nan)
    for b, s in enumerate(samples):
        if s is None:
            continue
        R[b] = rotations(s.quaternion[selection.rows])
        if s.angular_velocity is not None:
            w[b] = s.angular_velocity[selection.rows]
        if s.position is not None:
            p[b, 0] = s.position[selection.base_row]
        if s.velocity is not None:
            v[b, 0] = s.velocity[selection.base_row]
    if selection.offsets is not None:
        R = R @ selection.offsets
        known = ~np.isnan(R).any(axis=(-1, -2))
        if known.any():
            R[known] = so3.project(torch.from_numpy(R[known])).numpy()
    as_tensor = lambda a: torch.from_numpy(a).to(dtype)  # noqa: E731
    return Targets(as_tensor(p), as_tensor(v), as_tensor(R), as_tensor(w))


@dataclass
class LiveOptions:
    """backlog: samples queued per character (1: always the newest); stall_s: silence after which a
    character leaves the batch and the source is reported stalled; gather_s: how long a step waits
    for the rest of a frame's characters; duration_s: stop after this long; stop_when_idle_s: stop
    once the source has been silent this long (replays, tests); None: run until Ctrl-C."""

    backlog: int = 1
    stall_s: float = 1.0
    gather_s: float = 0.002
    duration_s: float | None = None
    stop_when_idle_s: float | None = None


@dataclass
class _Track:
    """One character's history: its steps' times, states and diagnostics, and the targets (for a
    rerun recording)."""

    time: list = field(default_factory=list)
    states: list = field(default_factory=list)
    diagnostics: dict[str, list] = field(default_factory=lambda: {name: [] for name in PER_SUBJECT})
    targets: list = field(default_factory=list)
    last_frame: int | None = None

    def trajectory(self, interrupted: bool) -> Trajectory:
        stack = lambda name: torch.stack([getattr(s, name) for s in self.states])[:, None]  # noqa: E731
        return Trajectory(torch.tensor(self.time, dtype=torch.float64), stack("base_position"), stack("base_rotation"),
                          stack("joint_positions"), stack("velocity"),
                          {name: torch.stack(v)[:, None] for name, v in self.diagnostics.items()}, interrupted)


@dataclass
class LiveResult:
    """What a session did: per character its trajectory (B = 1) and targets; the source's counters,
    samples skipped per character, events (joins, stalls), latency (s, datagram arrival to published
    estimate) and step times (s) of every step, and the report (`report()`)."""

    trajectories: dict[int, Trajectory]
    targets: dict[int, list[Targets]]
    source_stats: dict[str, int]
    skipped: dict[int, int]
    events: list[str]
    latency: np.ndarray
    step_time: np.ndarray
    rate: float
    interrupted: bool

    def report(self, transient: float = 2.0) -> dict:
        ms = lambda a: {k: v * 1e3 for k, v in _summary(a).items()} if len(a) else None  # noqa: E731
        characters = {}
        for c, t in self.trajectories.items():
            characters[str(c)] = dict(
                frames=len(t.time), duration_s=float(t.time[-1] - t.time[0]) if len(t.time) else 0.0,
                skipped=self.skipped.get(c, 0), dropped_targets=int(t.diagnostics["dropped"].sum()),
                mnte=summary(t.diagnostics["mnte"], t.time, transient) if len(t.time) else None)
        return dict(rate_hz=self.rate, characters=characters, source=self.source_stats,
                    skipped=sum(self.skipped.values()), events=self.events, latency_ms=ms(self.latency),
                    step_time_ms=ms(self.step_time), transient_s=transient, interrupted=self.interrupted)


def _summary(values: np.ndarray) -> dict[str, float]:
    return dict(median=float(np.median(values)), p99=float(np.quantile(values, 0.99)), max=float(values.max()))


class Publisher:
    """Where each step's estimates go as they are made: one LSL outlet per character."""

    def __init__(self, name: str, model: KinematicModel, base: bool = False, velocities: bool = False,
                 rate: float | None = None):
        self.name, self.model, self.base, self.velocities = name, model, base, velocities
        self.rate = rate  # the stream's, set by the live loop when it knows it
        self.outlets: dict = {}

    def outlet(self, character: int):
        """The character's outlet (NAME for character 0, NAME-c for others), opened on first use:
        open one ahead to let a recorder connect before the first estimate."""
        from ..live.lsl import JointOutlet

        if character not in self.outlets:
            self.outlets[character] = JointOutlet(f"{self.name}-{character}" if character else self.name,
                                                  self.model.joint_names, self.rate or 0.0, character, self.base,
                                                  self.velocities)
        return self.outlets[character]

    def publish(self, character: int, state: State, row: int, stamp: float) -> None:
        parts = [state.joint_positions[row]]
        if self.base:
            parts += [state.base_position[row], _quaternion(state.base_rotation[row])]
        if self.velocities:
            parts.append(state.velocity[row, 6:])
        self.outlet(character).push(torch.cat(parts).numpy(), stamp)


def _quaternion(R: torch.Tensor) -> torch.Tensor:
    w = torch.sqrt(torch.clamp(1 + R.trace(), min=1e-12)) / 2
    return torch.stack((w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)))


def track_live(source: Source, model: KinematicModel, selection_for, settings: TrackerSettings | None = None,
               options: LiveOptions | None = None, publisher: Publisher | None = None, progress=None,
               keep_targets: bool = False) -> LiveResult:
    """Track `source` until it ends, `options` stop it, or Ctrl-C (then `interrupted`).

    selection_for: a function of the source's segment names giving the `Selection` (build once,
    at the first sample); progress: called with (LiveResult so far, now) about once a second."""
    options = options or LiveOptions()
    mailbox = Mailbox(options.backlog)
    receiver = threading.Thread(target=_receive, args=(source, mailbox), daemon=True, name="torchik-live-receiver")
    receiver.start()
    loop = _Loop(model, settings or TrackerSettings(), selection_for, publisher, keep_targets,
                 getattr(source, "lsl_clock", False))
    start = last_progress = time.perf_counter()
    interrupted = False
    try:
        while True:
            got = mailbox.take(loop.active, timeout=0.05, gather=options.gather_s)
            now = time.perf_counter()
            if got:
                # a source knows its rate before it yields its first sample (MVN estimates it from
                # the first time codes, LSL reads the stream's nominal rate)
                assert source.rate is not None
                loop.step(got, source.rate)
            elif mailbox.finished:
                break
            loop.check_stalls(now, options.stall_s, mailbox)
            if options.duration_s is not None and now - start >= options.duration_s:
                break
            idle = now - max(mailbox.last_put.values()) if mailbox.last_put and not got else 0.0
            if options.stop_when_idle_s is not None and idle >= options.stop_when_idle_s:
                break
            if progress is not None and now - last_progress >= 1.0:
                last_progress = now
                progress(loop.result(source, mailbox, False), now - start)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        source.close()
        receiver.join(timeout=2.0)
    return loop.result(source, mailbox, interrupted)


def _receive(source: Source, mailbox: Mailbox) -> None:
    try:
        for sample in source:
            mailbox.put(sample)
    finally:
        mailbox.finish()


class _Loop:
    """The tracking side: the batch of active characters, the tracker, the histories."""

    def __init__(self, model: KinematicModel, settings: TrackerSettings, selection_for, publisher: Publisher | None,
                 keep_targets: bool, lsl_clock: bool):
        self.model, self.settings, self.selection_for = model, settings, selection_for
        self.lsl_clock = lsl_clock  # the source's time stamps are LSL's: carried over as they are
        self.publisher, self.keep_targets = publisher, keep_targets
        self.selection: Selection | None = None
        self.tracker: DynamicalIK | None = None
        self.active: list[int] = []
        self.tracks: dict[int, _Track] = {}
        self.events: list[str] = []
        self.latency: list[float] = []
        self.step_time: list[float] = []
        self.rate = float("nan")
        self.clock_offset = 0.0

    def step(self, got: dict[int, Sample], rate: float) -> None:
        if self.tracker is None:
            first = next(iter(got.values()))
            self.selection = self.selection_for(first.links)
            self.rate = rate
            settings = dataclasses.replace(self.settings, dt=1.0 / rate)
            self.tracker = DynamicalIK(self.model, self.selection.links, settings=settings)
            if self.publisher is not None:
                from ..live.lsl import pylsl

                self.publisher.rate = self.publisher.rate or rate
                self.clock_offset = pylsl().local_clock() - time.perf_counter()
        joining = [c for c in got if c not in self.active]
        samples = [got.get(c) for c in self.active] + [got[c] for c in joining]
        assert self.selection is not None  # built at the first sample, above
        targets = sample_targets(samples, self.selection)
        if joining:
            self._join(joining, targets)
        dt = self._time_steps(got)
        state, diagnostics = self.tracker.step(targets, dt)
        self.step_time.append(diagnostics.step_time)
        for row, c in enumerate(self.active):
            sample = got.get(c)
            if sample is None:
                continue
            track = self.tracks[c]
            track.last_frame = sample.frame
            if self.publisher is not None:
                stamp = sample.time if self.lsl_clock else sample.arrival + self.clock_offset
                self.publisher.publish(c, state, row, stamp)
                self.latency.append(time.perf_counter() - sample.arrival)
            track.time.append(sample.frame / self.rate)
            track.states.append(State(state.base_position[row], state.base_rotation[row], state.joint_positions[row],
                                      state.velocity[row]))
            for name, values in track.diagnostics.items():
                values.append(getattr(diagnostics, name)[row])
            if self.keep_targets:
                track.targets.append(Targets(*(t[row:row + 1] for t in vars(targets).values())))

    def _time_steps(self, got: dict[int, Sample]):
        """None (the nominal dt) when every character moved on by one frame, else dt [B] from the
        frame counters (a character without a sample: the nominal dt; it stands still)."""
        last = {c: self.tracks[c].last_frame for c in self.active}
        gaps = [got[c].frame - previous if c in got and (previous := last[c]) is not None else 1 for c in self.active]
        if all(g == 1 for g in gaps):
            return None
        return torch.tensor(gaps, dtype=self.model.dtype) / self.rate

    def _join(self, joining: list[int], targets: Targets) -> None:
        """New characters become rows of the batch, from the pose of their first targets."""
        assert self.tracker is not None
        B = len(self.active)
        new = self.tracker.initial_state(Targets(*(t[B:] for t in vars(targets).values())))
        if B:
            s = self.tracker.state
            new = State(*(torch.cat((a, b)) for a, b in zip(vars(s).values(), vars(new).values())))
        self.tracker.reset(new, batch=B + len(joining))
        for c in joining:
            self.events.append(f"character {c} joined" if c not in self.tracks else f"character {c} came back")
            self.tracks.setdefault(c, _Track()).last_frame = None
        self.active += joining

    def check_stalls(self, now: float, stall_s: float, mailbox: Mailbox) -> None:
        """Characters silent for stall_s (nothing received, nothing left queued) leave the batch."""
        stalled = [c for c in self.active if now - mailbox.last_put[c] > stall_s and not mailbox.queues[c]]
        if not stalled or self.tracker is None:
            return
        keep = [row for row, c in enumerate(self.active) if c not in stalled]
        for c in stalled:
            self.events.append(f"character {c} stalled (no data for {stall_s:g} s) and left the batch")
        self.active = [self.active[row] for row in keep]
        if keep:
            s, rows = self.tracker.state, torch.tensor(keep)
            self.tracker.reset(State(*(t.index_select(0, rows) for t in vars(s).values())), batch=len(keep))

    def result(self, source, mailbox: Mailbox, interrupted: bool) -> LiveResult:
        trajectories = {c: t.trajectory(interrupted) for c, t in self.tracks.items() if t.states}
        return LiveResult(trajectories, {c: t.targets for c, t in self.tracks.items()}, source.stats.as_dict(),
                          dict(mailbox.skipped), list(self.events), np.array(self.latency), np.array(self.step_time),
                          self.rate, interrupted)

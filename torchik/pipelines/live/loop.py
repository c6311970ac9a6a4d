"""The live loop: a receiver thread (or process) reads the source and leaves each complete sample in
a `Mailbox`: per character at most `backlog` samples; an older one is stepped over and counted as
skipped when a newer arrives, so the queue never grows. The tracking loop takes one sample per
character per step (waiting up to `gather_s` for the characters of a frame to be all there), so
neither blocks the other: the oldest queued while its steps are short enough to catch up a burst
of frames, else the newest (`CatchUp`).

A step's dt is the frame counter's difference over the stream's rate: lost frames give a longer
step, as they would offline. A character without a sample in a step has its targets dropped for it
(it stands still); one silent for `stall_s` leaves the batch, is reported, and joins again, from
the pose of its new targets, when it comes back. The per-step work is batched: targets, dt, the
published values and the history are array operations over the characters; only the LSL push is
one call per character (one outlet each). Python's garbage collector runs between samples, after a
step is published (`IdleCollector`), not inside a step.

Before the first sample the tracker is built and stepped for the links the session expects and
its expected characters (`_Loop.warm_up`), and a receiver process is waited for: the set-up's
imports (the QP solvers' take a second or more), torch's first calls and, where the stream's rate
is known, the compiled step's capture are paid before the stream, not while its first samples
wait (they were skipped: half a second of a 100 Hz stream)."""

from __future__ import annotations

import dataclasses
import gc
import threading
import time
import warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from ...live.sample import Sample, Source
from ...method.kinematics import KinematicModel
from ...method.models import TRACKED_LINKS
from ...method.settings import TrackerSettings
from ...method.tracker import DynamicalIK
from ...synthetic.motion import periodic_motion, targets_from_motion
from .batch import BatchTracker, LiveRetarget, rows_from
from .collect import IdleCollector
from .history import History, LiveResult, milliseconds
from .mailbox import BACKLOG, CatchUp, Mailbox
from .publish import Publisher
from .targets import Selection, sample_targets
from .viewer import LiveViewer


@dataclass
class LiveOptions:
    """backlog: samples per character tracked in order when they come at once; beyond, the loop steps
    to the newest (1: always the newest); None: `BACKLOG`, and the newest only while the loop's
    cost of a sample is over half a frame (`CatchUp`). stall_s: silence after which a character
    leaves the batch and the source is reported stalled; gather_s: how long a step waits for the
    rest of a frame's characters (None: half a frame); duration_s: stop after this long;
    stop_when_idle_s: stop once the source has been silent this long (replays, tests); None:
    run until Ctrl-C. keep_states: keep every step's states for the trajectories (`--out`); without,
    only what the report needs. characters: how many the stream is expected to bring: the tracker
    is warmed up for that batch (and for one, as a batch starts) before the first sample."""

    backlog: int | None = None
    stall_s: float = 1.0
    gather_s: float | None = None
    duration_s: float | None = None
    stop_when_idle_s: float | None = None
    keep_states: bool = True
    characters: int = 1


@dataclass
class Outputs:
    """Where a session's estimates go as they are made, any of them: LSL outlets (of the tracked
    model's joints, or the robot's when retargeting), the live viewer (`LiveViewer`), the robot."""

    publisher: Publisher | None = None
    viewer: LiveViewer | None = None
    retarget: LiveRetarget | None = None


def track_live(source: Source, model: KinematicModel, selection_for, settings: TrackerSettings | None = None,
               options: LiveOptions | None = None, publisher: Publisher | None = None, progress=None,
               viewer: LiveViewer | None = None, retarget: LiveRetarget | None = None,
               links: Sequence[str] | None = None, on_ready: Callable[[], None] | None = None) -> LiveResult:
    """Track `source` until it ends, `options` stop it, or Ctrl-C (then `interrupted`).

    selection_for: a function of the source's segment names giving the `Selection` (built once,
    at the first sample); progress: called with (counters, seconds since the start) about once a
    second; viewer: a LiveViewer; retarget: a LiveRetarget (the publisher then carries the robot's
    joints); links: those `selection_for` is expected to give (None: the model's `TRACKED_LINKS`,
    where it has them), for which the tracker is warmed up before the first sample; on_ready:
    called once it is, and the source's receiver with it: from then on no sample waits for the
    set-up."""
    options = options or LiveOptions()
    mailbox = Mailbox(options.backlog or BACKLOG)
    # a source that receives in a process of its own is polled from this thread: no second thread
    # of this process then competes with the step for the GIL
    deliver = getattr(source, "deliver", None)
    receiver = None
    if deliver is None:
        receiver = threading.Thread(target=_receive, args=(source, mailbox), daemon=True, name="torchik-live-receiver")
        receiver.start()
    loop = _Loop(model, settings or TrackerSettings(), selection_for, Outputs(publisher, viewer, retarget),
                 options.keep_states, getattr(source, "lsl_clock", False))
    start = last_progress = last_check = time.perf_counter()
    interrupted = False
    collector = IdleCollector().start()  # garbage collected between samples, not in a step
    catch_up = CatchUp(options.backlog)
    try:
        expected = links if links is not None else TRACKED_LINKS.get((model.name or "").lower())
        if expected is not None:
            loop.warm_up(expected, source.rate, options.characters)
        wait_ready = getattr(source, "wait_ready", None)  # a receiver process starts in seconds
        if wait_ready is not None:
            wait_ready(READY_TIMEOUT_S)
        if on_ready is not None:
            on_ready()
        while True:
            # a source knows its rate before it yields its first sample (MVN estimates it from the
            # first time codes, LSL reads the stream's nominal rate)
            rate = source.rate or 100.0
            gather = options.gather_s if options.gather_s is not None else 0.5 / rate
            if deliver is None:
                got = mailbox.take(loop.active, timeout=0.05, gather=gather, keep=catch_up.keep(rate))
            else:
                got = _take_delivered(deliver, mailbox, loop.active, 0.05, gather, catch_up.keep(rate))
            now = time.perf_counter()
            if got:
                assert source.rate is not None
                loop.step(got, source.rate, lambda: _counters(source, mailbox, loop), mailbox.last_skips)
            elif mailbox.finished:
                break
            collector.collect()  # after the step's push: the next sample is the furthest off
            if got:
                catch_up.record(got, now, time.perf_counter())
            if now - last_check >= min(0.05, options.stall_s / 4):  # not every step: a look at every character
                last_check = now
                loop.check_stalls(now, options.stall_s, mailbox)
            if options.duration_s is not None and now - start >= options.duration_s:
                break
            idle = now - max(mailbox.last_put.values()) if mailbox.last_put and not got else 0.0
            if options.stop_when_idle_s is not None and idle >= options.stop_when_idle_s:
                break
            if progress is not None and now - last_progress >= 1.0:
                last_progress = now
                progress(_counters(source, mailbox, loop), now - start)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        collector.stop()
        source.close()
        if receiver is not None:
            receiver.join(timeout=2.0)
        if viewer is not None:
            viewer.close(_counters(source, mailbox, loop))
    return loop.result(source, mailbox, interrupted)


READY_TIMEOUT_S = 60.0  # at most this long for a receiver process to start (seconds on a loaded machine)
WARM_UP_STEPS = 5  # past the third, where a compiled step is captured
WARM_UP_RATE = 100.0  # Hz, the warm-up's while the stream's rate is not known


def _receive(source: Source, mailbox: Mailbox) -> None:
    try:
        for sample in source:
            mailbox.put(sample)
    finally:
        mailbox.finish()


def _take_delivered(deliver, mailbox: Mailbox, active, timeout: float, gather: float, keep: int) -> dict[int, Sample]:
    """`Mailbox.take` for a source that delivers into the mailbox when asked (`ReceiverProcess`):
    what has come is taken in first, then it waits as `take` does."""
    deliver(mailbox, 0.0 if any(mailbox.queues.values()) else timeout)
    if any(mailbox.queues.values()):
        deadline = time.perf_counter() + gather
        while not mailbox.finished and not all(mailbox.queues.get(c) for c in active):
            remaining = deadline - time.perf_counter()
            if remaining <= 0 or not deliver(mailbox, remaining):
                break
    return mailbox.take(active, timeout=0.0, gather=0.0, keep=keep)


def _counters(source: Source, mailbox: Mailbox, loop: "_Loop") -> dict:
    """The live counters: the source's (datagrams received, samples, lost, late, duplicates,
    malformed, ...), samples skipped, stalls, active characters, and the latency of the samples
    published in the last 200 steps (ms, or None)."""
    recent = np.concatenate(loop.latency[-200:]) if loop.latency else np.empty(0)
    return dict(source.stats.as_dict(), skipped=sum(mailbox.skipped.values()), stalls=loop.stalls,
                characters=len(loop.active), latency_ms=milliseconds(recent))


class _Loop:
    """The tracking side: the batch of active characters, the trackers, the history."""

    def __init__(self, model: KinematicModel, settings: TrackerSettings, selection_for, outputs: Outputs,
                 keep_states: bool, lsl_clock: bool):
        self.model, self.settings, self.selection_for, self.outputs = model, settings, selection_for, outputs
        self.lsl_clock = lsl_clock  # the source's time stamps are LSL's: carried over as they are
        self.selection: Selection | None = None
        self.human: BatchTracker | None = None
        self.active: list[int] = []  # the characters, by batch row
        self.characters = np.empty(0, dtype=np.int64)  # the same, as an array
        self.last_frame = np.empty(0, dtype=np.int64)  # per row, the last frame stepped to (-1: none yet)
        self._index: dict[int, int] = {}  # character -> row
        self._seen: set[int] = set()
        self.history = History(keep_states)
        self.robot_history = History(keep_states) if outputs.retarget is not None else None
        self.events: list[str] = []
        self.latency: list[np.ndarray] = []
        self.step_time: list[float] = []
        self.stalls = 0
        self.rate = float("nan")
        self.clock_offset = 0.0
        self._batch_size, self._steps_at_size = 0, 0
        self._warm: DynamicalIK | None = None  # the tracker warmed up for the expected links and rate

    def warm_up(self, links: Sequence[str], rate: float | None, characters: int = 1) -> None:
        """The tracker for `links` at `rate` (None: not yet known) built and stepped, a few steps of
        a walking-like motion, for `characters` rows and for one: its imports, backends and torch's
        first calls are then paid, and, with a known rate, its compiled step captured (settings.compile).
        With a known rate it is kept for the session, whose first sample then finds it ready, when that
        sample brings these links; else it only warms the process (a tracker is built in milliseconds
        after that, and captures at its third step)."""
        known = rate is not None
        settings = dataclasses.replace(self.settings, dt=1.0 / (rate or WARM_UP_RATE),
                                       compile=self.settings.compile and known)
        with warnings.catch_warnings():
            if not known:  # a guessed rate's warnings (K dt) are not the session's
                warnings.simplefilter("ignore")
            tracker = DynamicalIK(self.model, links, settings=settings)
        motion = periodic_motion(self.model, WARM_UP_STEPS * tracker.dt, 1.0 / tracker.dt, batch=max(1, characters),
                                 dtype=self.model.dtype)
        sequence = targets_from_motion(self.model, motion, tracker.orientation_links, tracker.position_links)
        rows = lambda x, size: type(x)(*(t[:size] for t in vars(x).values()))  # noqa: E731
        for size in sorted({1, max(1, characters)}):
            tracker.reset(rows(motion.state(0), size), batch=size)
            for k in range(WARM_UP_STEPS):
                tracker.step(rows(sequence[k], size))
        self._warm = tracker if known else None
        gc.freeze()  # what the set-up made, out of the collector's reach (`_freeze_after_set_up`)

    def _tracker(self, links: Sequence[str], rate: float) -> DynamicalIK:
        """The session's tracker: the one warmed up, for these links at this rate, or a new one."""
        warm, self._warm = self._warm, None
        if warm is not None and warm.orientation_links == tuple(links) and warm.dt == 1.0 / rate:
            return warm
        return DynamicalIK(self.model, links, settings=dataclasses.replace(self.settings, dt=1.0 / rate))

    def _start(self, first: Sample, rate: float) -> None:
        selection: Selection = self.selection_for(first.links)
        self.selection, self.rate = selection, rate
        self.human = BatchTracker(self._tracker(selection.links, rate))
        out = self.outputs
        if out.retarget is not None:
            out.retarget.start(selection.links, self.model.base_link, rate)
        if out.publisher is not None:
            from ...live.lsl import pylsl

            out.publisher.rate = out.publisher.rate or rate
            self.clock_offset = pylsl().local_clock() - time.perf_counter()

    def step(self, got: dict[int, Sample], rate: float, counters, skips: dict[int, int] | None = None) -> None:
        """One step of every active character towards its sample in `got` (characters not yet in the
        batch join it). counters: a function giving the live counters (for the viewer); skips: per
        character, the samples stepped over since its last step."""
        if self.human is None:
            self._start(next(iter(got.values())), rate)
        assert self.human is not None and self.selection is not None  # started
        joining = [c for c in got if c not in self._index]
        samples = [got.get(c) for c in self.active] + [got[c] for c in joining]
        targets = sample_targets(samples, self.selection, self.model.dtype, self.model.device)
        retarget = self.outputs.retarget
        robot_targets = retarget.targets(targets) if retarget is not None else None
        if joining:
            self._join(joining, targets, robot_targets)
        present = np.fromiter((s is not None for s in samples), bool, len(samples))
        given = [s for s in samples if s is not None]
        frames = np.fromiter((s.frame for s in given), np.int64, len(given))
        skipped = np.fromiter(((skips or {}).get(c, 0) for c in self.active + joining), np.int64, len(samples))
        dt = self._time_steps(present, frames, skipped[present])
        rows = None if len(given) == len(samples) else torch.from_numpy(np.flatnonzero(present))
        characters = self.characters[present]
        if retarget is None or robot_targets is None or self.robot_history is None:
            state, diagnostics = self.human.step(targets, dt)
            self._publish(state, present, None, characters, given)
        else:  # what is published first: the robot's
            robot, robot_diagnostics, within = retarget.step(robot_targets, dt)
            self._publish(robot, present, within.cpu().numpy()[present], characters, given)
            state, diagnostics = self.human.step(targets, dt)
            self.robot_history.add(characters, frames, rows, robot, robot_diagnostics)
        self.step_time.append(diagnostics.step_time)
        self._freeze_after_set_up()
        self.last_frame[present] = frames
        self.history.add(characters, frames, rows, state, diagnostics)
        if self.outputs.viewer is not None and self.outputs.viewer.due():
            self.outputs.viewer.offer(dict(time=float(frames.max()) / self.rate, characters=self.characters.copy(),
                                           state=state, diagnostics=diagnostics, targets=targets, counters=counters))

    def _freeze_after_set_up(self) -> None:
        """Moves what the set-up made (the model, torch's and TorchInductor's modules, a captured
        step: millions of objects) out of the garbage collector's reach, after the first steps of each
        batch size (the capture is made at the third). Otherwise every full collection walks them all:
        with the compiled step a collection stalled tens of frames at 240 Hz (experiments/live_latency.md);
        frozen, a collection walks only what the session made since."""
        assert self.human is not None
        if self.human.size != self._batch_size:
            self._batch_size, self._steps_at_size = self.human.size, 0
        self._steps_at_size += 1
        if self._steps_at_size in (1, 3, 10):
            gc.freeze()

    def _publish(self, state, present: np.ndarray, publishable: np.ndarray | None, characters: np.ndarray,
                 given: list[Sample]) -> None:
        """The values of the rows with a sample (and `publishable` [m] of those, or all) on their
        outlets, stamped with the samples' LSL times (or their arrival, on LSL's clock); each one's
        latency from its datagram's arrival to the push's return."""
        publisher = self.outputs.publisher
        if publisher is None:
            return
        arrival = np.fromiter((s.arrival for s in given), np.float64, len(given))
        stamps = np.fromiter((s.time for s in given), np.float64, len(given)) if self.lsl_clock else \
            arrival + self.clock_offset
        if publishable is None:
            publishable = np.ones(len(given), dtype=bool)
        rows_present = np.flatnonzero(present)[publishable]
        rows = None if len(rows_present) == len(present) else torch.from_numpy(rows_present)
        done = publisher.publish(characters[publishable].tolist(), publisher.values(state, rows), stamps[publishable])
        self.latency.append(done - arrival[publishable])

    def _time_steps(self, present: np.ndarray, frames: np.ndarray, skipped: np.ndarray):
        """None (the nominal dt) when every character moved on by one frame, else dt [B] from the
        frame counters (a character without a sample, or at its first: the nominal dt). Frames the
        loop stepped over (`skipped` [m] per character with a sample) are no gap in the stream: a
        character that fell behind moves on less than max_gap nominal steps at once, from where it
        is, instead of restarting from the zero pose (which made a slow loop slower: a batch of
        restarts every step). Gaps in the stream itself longer than max_gap still restart it."""
        previous = self.last_frame[present]
        gaps = np.ones(len(present))
        gaps[present] = np.where(previous >= 0, frames - previous, 1)
        if (gaps == 1).all():
            return None
        own = gaps.copy()
        own[present] -= skipped
        max_gap = self.settings.max_gap
        within = max(1.0, np.ceil(max_gap) - 1)  # whole frames, clear of the tracker's own gap test
        gaps = np.where(own > max_gap, gaps, np.minimum(gaps, within))
        return torch.from_numpy(gaps / self.rate).to(self.model.dtype)

    def _join(self, joining: list[int], targets, robot_targets) -> None:
        """New characters become rows of the batch, from the pose of their first targets."""
        assert self.human is not None
        first = len(self.active)
        self.human.join(rows_from(targets, first))
        if self.outputs.retarget is not None:
            assert self.outputs.retarget.batch is not None  # started with the human's
            self.outputs.retarget.batch.join(rows_from(robot_targets, first))
        for c in joining:
            self.events.append(f"character {c} joined" if c not in self._seen else f"character {c} came back")
            self._seen.add(c)
        self._set_active(self.active + joining, np.concatenate((self.last_frame, np.full(len(joining), -1))))

    def _set_active(self, active: list[int], last_frame: np.ndarray) -> None:
        self.active, self.last_frame = active, last_frame
        self.characters = np.array(active, dtype=np.int64)
        self._index = {c: row for row, c in enumerate(active)}

    def check_stalls(self, now: float, stall_s: float, mailbox: Mailbox) -> None:
        """Characters silent for stall_s (nothing received, nothing left queued) leave the batch."""
        stalled = [c for c in self.active if now - mailbox.last_put[c] > stall_s and not mailbox.queues[c]]
        if not stalled or self.human is None:
            return
        self.stalls += len(stalled)
        keep = [row for row, c in enumerate(self.active) if c not in stalled]
        for c in stalled:
            self.events.append(f"character {c} stalled (no data for {stall_s:g} s) and left the batch")
        if keep:
            rows = torch.tensor(keep)
            self.human.keep(rows)
            if self.outputs.retarget is not None and self.outputs.retarget.batch is not None:
                self.outputs.retarget.batch.keep(rows)
        else:  # nobody left: the next to come starts a fresh batch
            self.human.size = 0
            if self.outputs.retarget is not None and self.outputs.retarget.batch is not None:
                self.outputs.retarget.batch.size = 0
        self._set_active([self.active[row] for row in keep], self.last_frame[keep])

    def result(self, source, mailbox: Mailbox, interrupted: bool) -> LiveResult:
        retarget = self.outputs.retarget
        robot = self.robot_history.trajectories(self.rate, interrupted) if self.robot_history is not None else {}
        return LiveResult(self.history.per_character(self.rate), self.history.trajectories(self.rate, interrupted),
                          robot, source.stats.as_dict(), dict(mailbox.skipped), list(self.events),
                          np.concatenate(self.latency) if self.latency else np.empty(0), np.array(self.step_time),
                          self.rate, interrupted, retarget.report() if retarget is not None else None)

"""Samples between the receiver and the tracking loop (`Mailbox`), and how many of a character's
queued samples the loop tracks (`CatchUp`).

Samples come in bursts even from a steady stream: a sender, a receiver or a tracker that loses its
core for some milliseconds (tens on a loaded 2-core machine) leaves a few frames waiting at once. A
loop whose step is far shorter than the frame period tracks all of them in order, each with its
own dt, and is soon back at the newest; a loop further behind than `BACKLOG` frames, or not as
fast, steps to the newest and counts the rest as skipped, so that it never stays behind.
"""

from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from ...live.sample import BACKLOG, Sample, keep_newest

RECENT = 32  # steps whose median tells how long the loop takes a sample
EVIDENCE = 5  # before this many steps the loop is taken to be fast: the first steps carry its set-up


class CatchUp:
    """How many queued samples per character the loop tracks in order (`keep`). A backlog given is
    kept, however slow the loop (1: always the newest). Without one (None), `BACKLOG` while the
    loop's median cost of a sample over its last `RECENT` steps is at most half the frame period,
    otherwise 1: tracking q queued samples at c <= T/2 each, while new ones come every T, takes
    q c / (1 - c/T) <= q T, so the loop is back at the newest no later than the burst took to
    build up, and a loop too slow for that does not fall behind."""

    def __init__(self, backlog: int | None = None):
        self.backlog, self.adaptive = backlog or BACKLOG, backlog is None
        self.recent: deque[float] = deque(maxlen=RECENT)
        self.last_end: float | None = None

    def record(self, got: dict[int, Sample], started: float, ended: float) -> None:
        """A step of the loop over the samples `got`, from the take's return (`started`) to the end
        of what follows its push (`ended`). When they had all come before the previous step ended,
        the loop was behind them, and a sample cost it the whole time since that end: the take, the
        pipe, the collector and any time it lost its core, which the step's own time leaves out
        (on a loaded machine the loop then caught up slower than its steps said)."""
        behind = self.last_end is not None and max(s.arrival for s in got.values()) <= self.last_end
        since = self.last_end if behind and self.last_end is not None else started
        self.recent.append(ended - since)
        self.last_end = ended

    def keep(self, rate: float) -> int:
        """Samples per character to track in order at a stream of `rate` Hz (see the class)."""
        if not self.adaptive or len(self.recent) < EVIDENCE or float(np.median(self.recent)) <= 0.5 / rate:
            return self.backlog
        return 1


class Mailbox:
    """Complete samples from the receiver to the tracking loop: per character a deque of at most
    `backlog`; putting into a full one steps over its oldest sample (counted in `skipped`), and a
    take after that, or one that keeps fewer than are queued, steps to the newest. `keep`: how
    many the loop last asked to keep (a receiver process queues no more than that)."""

    def __init__(self, backlog: int = BACKLOG):
        self.backlog = self.keep = backlog
        self.queues: dict[int, deque] = {}
        self.skipped: dict[int, int] = {}
        self.last_put: dict[int, float] = {}  # per character, when its newest sample came in
        self.unstepped: dict[int, int] = {}  # per character, samples stepped over since its last take
        self.last_skips: dict[int, int] = {}  # of the characters the last take gave, those samples
        self.condition = threading.Condition()
        self.finished = False  # the source ended

    def put(self, sample: Sample) -> None:
        with self.condition:
            if keep_newest(self.queues, sample, self.backlog):
                self.count_skipped(sample.character, 1)
            self.last_put[sample.character] = time.perf_counter()
            self.condition.notify()

    def count_skipped(self, character: int, count: int) -> None:
        """`count` samples of the character stepped over before they reached the mailbox (or in it)."""
        self.skipped[character] = self.skipped.get(character, 0) + count
        self.unstepped[character] = self.unstepped.get(character, 0) + count

    def finish(self) -> None:
        with self.condition:
            self.finished = True
            self.condition.notify()

    def take(self, active, timeout: float, gather: float, keep: int | None = None) -> dict[int, Sample]:
        """Of each character that has a sample queued, the oldest while it has at most `keep` (None:
        the backlog) and none was stepped over since its last take, else the newest (the others
        stepped over): waits up to `timeout` for the first, then up to `gather` for every
        `active` character to have one."""
        with self.condition:
            self.condition.wait_for(lambda: self.finished or any(self.queues.values()), timeout)
            deadline = time.perf_counter() + gather
            while not self.finished and not all(self.queues.get(c) for c in active):
                remaining = deadline - time.perf_counter()
                if remaining <= 0 or not self.condition.wait(remaining):
                    break
            self.keep = self.backlog if keep is None else min(keep, self.backlog)
            for c, queue in self.queues.items():
                # behind by more than it keeps (samples already stepped over, here or in the
                # receiver): on to the newest, rather than staying that far behind
                if (self.unstepped.get(c, 0) or len(queue) > self.keep) and len(queue) > 1:
                    self.count_skipped(c, len(queue) - 1)
                    while len(queue) > 1:
                        queue.popleft()
            got = {c: q.popleft() for c, q in self.queues.items() if q}
            self.last_skips = {c: self.unstepped.pop(c, 0) for c in got}
            return got

"""An MVN stream received in a process of its own (`ReceiverProcess`): the socket, the parsing and
the assembly of samples run beside the tracker, not in its process, so that neither waits for the
other's GIL (at 64 characters the receiver reads some 13,000 datagrams a second; in a thread of
the tracker's process it held the GIL for much of the step's time).

The receiver (spawned) reads every datagram waiting on the socket as one batch, and keeps per
character its newest samples not yet handed on, as many as the tracker's last credit asked (at
most `backlog`: all of them while the tracker catches up bursts, 1 while it steps to the newest);
an older one is stepped over and counted as skipped, as the live loop's `Mailbox` does. The
tracker asks for samples with a credit: the receiver sends what it holds, all characters in one
message of stacked arrays, when the tracker has a credit, and the tracker gives the next credit as
it takes a message. So at most one message is in flight, and what waits while the tracker steps
is only ever the newest few. Each message carries the source's counters, and the last one, at the
end, their final values and the receiver's CPU time. The first, before any samples, says that the
receiver reads the socket (`wait_ready`): what comes before it waits in the socket's buffer and
reaches the tracker at once, a burst it would step over.

Ctrl-C is the tracker's: the receiver ignores SIGINT and ends when the tracker closes the source,
or when the tracker's end of the pipe closes (the tracker died): no receiver outlives its tracker.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import select
import signal
import socket
import time
from collections import deque
from multiprocessing.connection import Connection
from typing import Iterator

import numpy as np

from ..errors import InputError
from .sample import BACKLOG, Sample, SourceStats, Url, keep_newest

PIPE_BYTES = 1 << 20  # a message of 64 characters' samples is some 150 kB: one fits without blocking
STOP = "stop"
# up to this many samples a message carries them as Samples: pickled as they are they cross the
# pipe faster than as arrays (experiments/live_latency.md); from 4 the arrays do
FEW = 3


class ReceiverProcess:
    """An MVN stream over UDP (`MvnSource`'s arguments) received in a spawned process. A `Source`:
    iterate for samples, or, in the live loop, `deliver` them into its mailbox; `stats` and `rate`
    as the receiver last reported them; `skipped` (per character) the samples the receiver stepped
    over while the tracker was busy; `close()` ends the receiver and waits for it."""

    def __init__(self, url: Url, rate: float | None = None, position_scale: float = 1.0, backlog: int = BACKLOG):
        from .mvn_source import MvnSource

        if url.scheme != "udp":
            raise InputError(f"{url}: a receiver process reads udp:// streams")
        # bound here, before the receiver starts (seconds of imports): what comes meanwhile waits
        # in the socket's buffer, and a port in use is refused at once
        listening = MvnSource(url, rate, position_scale=position_scale)
        self.address: tuple[str, int] = listening.address
        context = multiprocessing.get_context("spawn")
        self._messages, messages = context.Pipe(duplex=False)
        credits, self._credits = context.Pipe(duplex=False)
        _widen(messages)
        self.process = context.Process(target=_serve, args=(url, rate, position_scale, backlog, listening.socket,
                                                            messages, credits), daemon=True, name="torchik-receiver")
        self.process.start()
        for end in (messages, credits, listening.socket):
            end.close()
        self.stats, self.rate = SourceStats(), rate
        self.skipped: dict[int, int] = {}
        self._skipped_now: dict[int, int] = {}  # what the last message adds to `skipped`
        self.finished = False
        self.ready = False  # the receiver reads the socket (its first message said so)
        self.serving_cpu_s: float | None = None  # the receiver's CPU seconds from its first datagram to its end

    def wait_ready(self, timeout: float) -> bool:
        """Wait up to `timeout` for the receiver to be reading the socket (its process starts in
        seconds); True once it is. Its first message says so, before any samples: none is taken here."""
        if not self.ready and not self.finished and self._messages.poll(timeout):
            self._take()
        return self.ready

    def deliver(self, mailbox, timeout: float) -> bool:
        """Wait up to `timeout` for the receiver's next message and put its samples into `mailbox`
        (its `skipped` counts what the receiver stepped over); False when none came. At the end of
        the stream the mailbox is finished."""
        if self.finished or not self._messages.poll(timeout):
            return False
        samples = self._take(mailbox.keep)
        if self.finished:
            mailbox.finish()
        for character, count in self._skipped_now.items():
            mailbox.count_skipped(character, count)
        for sample in samples:
            mailbox.put(sample)
        return True

    def _take(self, keep: int | None = None) -> list[Sample]:
        """The next message's samples (counters and rate taken over); the next credit given, with
        how many samples per character the receiver is to keep until then (None: its backlog)."""
        try:
            kind, rate, stats, skipped, packed = self._messages.recv()
        except EOFError:  # the receiver died: what it had counted so far stays
            kind, rate, stats, skipped, packed = "end", self.rate, dataclasses.astuple(self.stats), {}, []
        self.rate, self.stats = rate, SourceStats(*stats)
        if kind == "ready":  # the receiver's first message: no samples, no credit taken
            self.ready = True
            return []
        self._skipped_now = skipped
        for character, count in skipped.items():
            self.skipped[character] = self.skipped.get(character, 0) + count
        if kind == "end":
            self.finished, self.serving_cpu_s, packed = True, packed, []
        else:
            self._credits.send(keep)
        return unpack(packed)

    def __iter__(self) -> Iterator[Sample]:
        while not self.finished:
            if self._messages.poll(0.2):
                yield from self._take()

    def close(self) -> None:
        """End the receiver; its last counters are taken over."""
        if self.process.is_alive():
            try:
                self._credits.send(STOP)
                # a receiver still starting (seconds on a loaded machine) reads the STOP once it runs
                while not self.finished and self._messages.poll(2.0 if self.ready else 20.0):
                    self._take()
            except (BrokenPipeError, EOFError, OSError):
                pass
        # its interpreter's exit (torch's teardown) takes seconds on a loaded machine: terminated only if stuck
        self.process.join(timeout=10.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join()
        self.finished = True


def _widen(connection: Connection) -> None:
    """A pipe that holds a whole message: the receiver then never blocks on a send it could not finish."""
    import fcntl

    try:
        fcntl.fcntl(connection.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except (AttributeError, OSError):  # not Linux, or beyond the system's limit: a smaller pipe still works
        pass


def _serve(url: Url, rate: float | None, position_scale: float, backlog: int, bound: socket.socket,
           messages: Connection, credits: Connection) -> None:
    """The receiver process: the socket read into per-character queues, handed on on credit."""
    from .mvn_source import MvnSource

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the tracker's, which then closes the source
    start: float | None = None  # CPU time at the first datagram: the imports before it are not the stream's
    source = MvnSource(url, rate, position_scale=position_scale, bound=bound)
    queues: dict[int, deque] = {}
    skipped: dict[int, int] = {}
    credit, running, keep = True, True, backlog
    poller = select.poll()  # made once: a selector per wait would cost more than a datagram's parsing
    for connection in (credits, source.socket):
        poller.register(connection.fileno(), select.POLLIN)
    try:
        messages.send(("ready", source.rate, dataclasses.astuple(source.stats), {}, []))
        while running:
            ready = {fd for fd, _ in poller.poll(1000)}
            if credits.fileno() in ready:
                try:
                    given = credits.recv()
                    running, credit = given != STOP, True
                    keep = min(given, backlog) if isinstance(given, int) else backlog
                except EOFError:  # the tracker is gone
                    return
            if source.socket.fileno() in ready:
                start = time.process_time() if start is None else start
                for sample in source.receive(0.0):
                    if keep_newest(queues, sample, keep):
                        skipped[sample.character] = skipped.get(sample.character, 0) + 1
            if credit and any(queues.values()):
                given = [s for queue in queues.values() for s in queue]
                messages.send(("samples", source.rate, dataclasses.astuple(source.stats), skipped, pack(given)))
                queues, skipped, credit = {}, {}, False
        messages.send(("end", source.rate, dataclasses.astuple(source.stats), skipped,
                       None if start is None else time.process_time() - start))
    except BrokenPipeError:  # the tracker is gone
        pass
    finally:
        source.socket.close()


def pack(samples: list[Sample]) -> list:
    """Samples as few arrays: per group of the same segments and fields, (links, characters [m],
    frames [m], times [m], arrivals [m], quaternion [m,n,4], angular_velocity, position, velocity
    [m,n,3] or None); up to `FEW` samples, the samples as they are."""
    if len(samples) <= FEW:
        return list(samples)
    groups: dict[tuple, list[Sample]] = {}
    for s in samples:
        key = (s.links, s.angular_velocity is None, s.position is None, s.velocity is None)
        groups.setdefault(key, []).append(s)
    return [(links, *(np.array([getattr(s, name) for s in group]) for name in ("character", "frame", "time", "arrival")),
             *(_stacked(group, name) for name in ("quaternion", "angular_velocity", "position", "velocity")))
            for (links, *_), group in groups.items()]


def _stacked(group: list[Sample], name: str) -> np.ndarray | None:
    """The field `name` of the samples [m,...] (None when they do not carry it)."""
    return None if getattr(group[0], name) is None else np.stack([getattr(s, name) for s in group])


def unpack(packed: list) -> list[Sample]:
    """The samples `pack` packed, in the same groups' order."""
    if len(packed) <= FEW and all(isinstance(s, Sample) for s in packed):
        return packed
    out = []
    for links, characters, frames, times, arrivals, quaternion, angular_velocity, position, velocity in packed:
        row = lambda a, k: None if a is None else a[k]  # noqa: E731
        out += [Sample(int(characters[k]), int(frames[k]), float(times[k]), float(arrivals[k]), links, quaternion[k],
                       row(angular_velocity, k), row(position, k), row(velocity, k)) for k in range(len(characters))]
    return out

"""What every live source yields, and the URLs that name sources and destinations.

A source is an iterable of `Sample`s (one per character and frame, complete) with `stats` (its
fault counters), `rate` (frames per second) and `close()`. URLs: `udp://HOST:PORT` (HOST empty:
every interface), `tcp://HOST:PORT`, `lsl://NAME` (a Lab Streaming Layer stream by name) or
`lsl://?source_id=ID`.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass
from typing import Iterator, Protocol
from urllib.parse import parse_qs, urlsplit

import numpy as np

from ..errors import InputError

MVN_PORT = 9763  # MVN's default streaming port
# samples a live loop catches up per character, 33 ms at 240 Hz: a loop further behind steps to the
# newest (on a loaded machine, catching up 32 kept it behind for seconds at a time:
# experiments/live_latency.md)
BACKLOG = 8


@dataclass(frozen=True)
class Sample:
    """One character's measurement at one frame, in the source's segment names.

    character: the character (subject) id; frame: the frame index at the stream's rate (MVN's
    sample counter); time: the source's own time stamp, s; arrival: time.perf_counter() when the
    sample was complete; links: segment names [n]; quaternion [n,4] (w, x, y, z, segment to
    world); angular_velocity [n,3] rad/s world; position, velocity [n,3] m, m/s world. A field the
    stream does not carry is None; a segment missing from the sample is NaN.
    """

    character: int
    frame: int
    time: float
    arrival: float
    links: tuple[str, ...]
    quaternion: np.ndarray
    angular_velocity: np.ndarray | None
    position: np.ndarray | None
    velocity: np.ndarray | None


@dataclass
class SourceStats:
    """A source's counters. datagrams: received; malformed: refused by the parser (short, wrong
    header, counts that do not add up, non-finite values) and skipped; ignored: message types
    torchik does not read; duplicates: datagrams already received; late: datagrams of a frame older
    than one already delivered (reordered), dropped; incomplete: frames of which some datagrams
    never came, dropped; lost: frames never delivered (the gaps in the frame counter, incomplete
    and late frames included); samples: delivered."""

    datagrams: int = 0
    malformed: int = 0
    ignored: int = 0
    duplicates: int = 0
    late: int = 0
    incomplete: int = 0
    lost: int = 0
    samples: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class Source(Protocol):
    @property
    def stats(self) -> SourceStats: ...

    @property
    def rate(self) -> float | None: ...

    def __iter__(self) -> Iterator[Sample]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Url:
    """A parsed stream URL: scheme udp, tcp or lsl; host and port (udp, tcp); name or source_id (lsl)."""

    scheme: str
    host: str = ""
    port: int = MVN_PORT
    name: str | None = None
    source_id: str | None = None

    def __str__(self) -> str:
        if self.scheme == "lsl":
            return f"lsl://{self.name}" if self.name else f"lsl://?source_id={self.source_id}"
        return f"{self.scheme}://{self.host}:{self.port}"


def parse_url(text: str, listening: bool = True) -> Url:
    """A stream URL (module docstring); InputError saying what a valid one looks like.
    listening: an empty host means every interface (a receiver), else it is required (a sender)."""
    examples = "udp://:9763, udp://192.168.1.20:9763, tcp://HOST:PORT or lsl://NAME"
    parts = urlsplit(text)
    if parts.scheme not in ("udp", "tcp", "lsl"):
        raise InputError(f"{text!r}: not a stream URL; expected {examples}")
    if parts.scheme == "lsl":
        source_id = parse_qs(parts.query).get("source_id", [None])[0]
        name = parts.netloc + parts.path or None
        if not name and not source_id:
            raise InputError(f"{text!r}: name the LSL stream: lsl://NAME or lsl://?source_id=ID")
        return Url("lsl", name=name, source_id=source_id)
    try:
        port = parts.port if parts.port is not None else MVN_PORT
    except ValueError:
        raise InputError(f"{text!r}: the port must be a number from 0 to 65535") from None
    host = parts.hostname or ""
    if not listening and not host:
        raise InputError(f"{text!r}: name the host to send to, e.g. udp://127.0.0.1:{port}")
    if parts.path not in ("", "/"):
        raise InputError(f"{text!r}: unexpected path {parts.path!r}; expected {examples}")
    return Url(parts.scheme, host, port)


def snap_rate(estimate: float) -> float:
    """A frame rate estimated from millisecond time codes, snapped to the capture rate it rounds
    (MVN captures at 60, 100, 120 or 240 Hz; others within 3 % of these are kept as estimated)."""
    for rate in (24.0, 25.0, 30.0, 40.0, 50.0, 60.0, 100.0, 120.0, 200.0, 240.0):
        if abs(estimate - rate) <= 0.03 * rate:
            return rate
    return estimate


def keep_newest(queues: dict[int, deque], sample: Sample, backlog: int) -> bool:
    """Queue `sample` in its character's deque of `queues`, which holds at most `backlog`: when full,
    its oldest sample is stepped over. Returns whether one was (the caller counts it)."""
    queue = queues.setdefault(sample.character, deque())
    full = len(queue) >= backlog
    if full:
        queue.popleft()
    queue.append(sample)
    return full

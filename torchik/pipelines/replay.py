"""`torchik replay`: a recording played as a live stream (MVN over UDP or TCP, or LSL Mocap), at its
rate or `speed` times it, several characters at once, with injected faults: how users try
`torchik live` without a suit and how its tests run end to end.

What the wire carries is float32 and frame counters: `wire_recording` is the recording as a
receiver sees it, the offline reference a live session's estimates must equal.

Faults, decided per character and frame with a seeded generator (never on the first two frames or
the last two, whose gaps a receiver could not see): a frame is lost (probability `loss`: none of
its datagrams is sent), sent after the next one (`reorder`), or has one datagram sent twice
(`duplicate`), one of these at most; `jitter_ms` delays each frame's sending by up to that;
`stall_s` pauses the stream halfway. The `ReplayLog` says what was done.
"""

from __future__ import annotations

import math
import socket
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording
from ..live.mvn import MVN_SEGMENTS, encode_payloads, framed, rotations
from ..live.sample import Url, snap_rate
from .visuals import quaternion_xyzw


@dataclass
class Faults:
    loss: float = 0.0
    reorder: float = 0.0
    duplicate: float = 0.0
    jitter_ms: float = 0.0
    stall_s: float = 0.0
    seed: int = 0

    def check(self, url: Url) -> None:
        for name in ("loss", "reorder", "duplicate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InputError(f"--{name} {getattr(self, name)}: a probability from 0 to 1")
        if self.loss + self.reorder + self.duplicate > 1.0:
            raise InputError("--loss, --reorder and --duplicate add up to more than 1")
        if self.jitter_ms < 0 or self.stall_s < 0:
            raise InputError("--jitter and --stall are durations: not negative")
        if url.scheme != "udp" and (self.reorder or self.duplicate):
            raise InputError(f"{url.scheme}:// delivers in order and once: --reorder and --duplicate apply to udp://")


@dataclass
class ReplayLog:
    """What a replay sent: frames per character, datagrams; frames lost, frames reordered and their
    datagrams, datagrams duplicated; seconds stalled."""

    frames: int = 0
    datagrams: int = 0
    lost: int = 0
    reordered: int = 0
    reordered_datagrams: int = 0
    duplicated: int = 0
    stalled_s: float = 0.0
    events: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class WireFrames:
    """A recording as a stream carries it: frame counters [T] (from 0), time codes [T] ms,
    quaternions [T,n,4] (w, x, y, z) and angular velocities [T,n,3] as float32, the base position
    and velocity [T,3] float32, the rate; links and base link."""

    counter: np.ndarray
    time_code: np.ndarray
    quaternion: np.ndarray
    angular_velocity: np.ndarray
    base_position: np.ndarray
    base_velocity: np.ndarray
    rate: float
    links: tuple[str, ...]
    base_link: str


def wire_frames(recording: Recording) -> WireFrames:
    rate = snap_rate(recording.frame_rate)
    elapsed = recording.time - recording.time[0]
    R = torch.from_numpy(np.ascontiguousarray(recording.orientation))
    known = torch.isfinite(R).flatten(-2).all(-1)
    q = torch.full(R.shape[:-2] + (4,), torch.nan, dtype=R.dtype)
    q[known] = quaternion_xyzw(R[known])[..., [3, 0, 1, 2]]
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return WireFrames(np.round(elapsed * rate).astype(np.int64), np.round(elapsed * 1000).astype(np.int64),
                      f32(q.numpy()), f32(recording.angular_velocity), f32(recording.base_position),
                      f32(recording.base_linear_velocity), rate, recording.links, recording.base_link)


def wire_recording(recording: Recording) -> Recording:
    """The recording as a receiver sees it after the wire: float32 values, quaternions normalised
    as the live side does (`torchik.live.mvn.rotations`), times from the frame counters."""
    w = wire_frames(recording)
    f64 = lambda a: a.astype(np.float64)  # noqa: E731
    return Recording(time=w.counter / w.rate, links=w.links, orientation=rotations(w.quaternion),
                     angular_velocity=f64(w.angular_velocity), base_link=w.base_link,
                     base_position=f64(w.base_position), base_linear_velocity=f64(w.base_velocity),
                     meta=dict(recording.meta, wire=dict(rate=w.rate)))


class _MvnSender:
    def __init__(self, url: Url, frames: WireFrames, max_bytes: int):
        unknown = [name for name in frames.links if name not in MVN_SEGMENTS]
        if unknown:
            raise InputError(f"an MVN stream carries Xsens segments; the recording has {unknown} "
                             f"(give --map to turn its segments into a human model's links)")
        self.ids = np.array([MVN_SEGMENTS.index(name) + 1 for name in frames.links])
        self.base = frames.links.index(frames.base_link)
        self.frames, self.max_bytes = frames, max_bytes
        # per recording frame: types 21, 22, as tuples of bytes, which the garbage collector stops
        # tracking: as lists, the cache (some 65,000 of them in 90 s at 240 Hz) brought on a full
        # collection of the replaying process: a stall of the stream (experiments/live_latency.md)
        self.payloads: dict[int, tuple[tuple[bytes, ...], tuple[bytes, ...]]] = {}
        try:
            if url.scheme == "udp":
                self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self.socket.connect((url.host, url.port))
            else:
                self.socket = socket.create_connection((url.host, url.port), timeout=5.0)
        except OSError as exc:
            raise InputError(f"cannot send to {url}: {exc.strerror or exc}") from None

    def datagrams(self, data: int, k: int, character: int) -> list[bytes]:
        """The recording's frame `data` as the stream's frame k of a character: type 21 (the base
        segment's position and velocity) and type 22 (every segment seen in the frame: quaternion
        and angular velocity). Each recording frame's items are encoded once: a replay of 64
        characters sends some 13,000 datagrams a second."""
        f = self.frames
        if data not in self.payloads:
            seen = np.isfinite(f.quaternion[data]).all(-1)
            self.payloads[data] = (
                tuple(encode_payloads("21", self.ids[[self.base]], dict(position=f.base_position[data][None],
                                                                        velocity=f.base_velocity[data][None]),
                                      self.max_bytes)),
                tuple(encode_payloads("22", self.ids[seen], dict(quaternion=f.quaternion[data][seen],
                                                                 angular_velocity=f.angular_velocity[data][seen]),
                                      self.max_bytes)))
        linear, angular = self.payloads[data]
        counter, time_code = int(f.counter[k]), int(f.time_code[k])
        return framed("21", linear, counter, time_code, character) + framed("22", angular, counter, time_code, character)

    def send(self, data: bytes) -> None:
        try:
            self.socket.send(data) if self.socket.type == socket.SOCK_DGRAM else self.socket.sendall(data)
        except ConnectionRefusedError:  # nobody listening (yet) on loopback: lost, as UDP would lose it
            pass

    def close(self) -> None:
        self.socket.close()


class _LslSender:
    def __init__(self, url: Url, frames: WireFrames, characters: int):
        from ..live.lsl import MocapOutlet, pylsl

        self.frames = frames
        self.outlets = [MocapOutlet(url.name or "torchik", frames.links, frames.base_link, frames.rate, c)
                        for c in range(characters)]
        self.start = pylsl().local_clock()


    def datagrams(self, data: int, k: int, character: int) -> list:
        return [(character, data, k)]

    def send(self, item) -> None:
        character, data, k = item
        f = self.frames
        # stamped with the frame counter's time, as a suit stamps its frames: the receiver's frame
        # numbers (and so its dt) then come out the same at any --speed and under any jitter
        stamp = self.start + f.counter[k] / f.rate
        self.outlets[character].push(f.quaternion[data], f.angular_velocity[data], f.base_position[data],
                                     f.base_velocity[data], stamp)

    def close(self) -> None:
        # an outlet that closes drops what it has not yet sent: the last samples get time to go out
        time.sleep(0.5)
        self.outlets = []


def replay(recording: Recording, to: Url, speed: float = 1.0, characters: int = 1, faults: Faults | None = None,
           max_bytes: int = 1472, stop=None, on_frame=None, lead_in_s: float = 0.0) -> ReplayLog:
    """Play `recording` (links: Xsens segment names for MVN) to `to`. speed: times real time (inf:
    as fast as the socket takes it); characters: that many, character c offset by c/characters of
    the recording; stop: a threading.Event that ends it early; on_frame(k): called after each frame;
    lead_in_s: a wait between opening the stream and its first frame (for LSL receivers to connect)."""
    faults = faults or Faults()
    faults.check(to)
    if not speed > 0:
        raise InputError(f"--speed {speed}: must be positive")
    frames = wire_frames(recording)
    sender = _LslSender(to, frames, characters) if to.scheme == "lsl" else _MvnSender(to, frames, max_bytes)
    T = len(frames.counter)
    offsets = [c * T // characters for c in range(characters)]
    rng = np.random.default_rng(faults.seed)
    log = ReplayLog()
    held: dict[int, list] = {}  # a reordered frame's datagrams, per character, sent after the next frame
    period = 1.0 / (frames.rate * speed) if math.isfinite(speed) else 0.0
    time.sleep(lead_in_s)
    start = time.perf_counter()
    try:
        for k in range(T):
            if stop is not None and stop.is_set():
                break
            if faults.stall_s and k == T // 2:
                log.events.append(f"stalled {faults.stall_s:g} s at frame {k}")
                log.stalled_s += faults.stall_s
                start += faults.stall_s
            due = start + k * period + (rng.uniform(0, faults.jitter_ms) * 1e-3 if faults.jitter_ms else 0.0)
            while (wait := due - time.perf_counter()) > 0:
                time.sleep(min(wait, 0.05))
            for c in range(characters):
                # character c shows frame k + offset of the recording, under the stream's counter k
                items = sender.datagrams((k + offsets[c]) % T, k, c)
                items = _inject(items, k, T, c, rng, faults, log, held)
                for item in items:
                    sender.send(item)
                log.datagrams += len(items)
            log.frames += 1
            if on_frame is not None:
                on_frame(k)
    finally:
        sender.close()
    return log


def _inject(items: list, k: int, T: int, character: int, rng, faults: Faults, log: ReplayLog, held: dict) -> list:
    """Frame k's datagrams after the faults drawn for it; a frame held back (reordered) follows."""
    before = held.pop(character, None)
    u = rng.random()
    out = items
    if 2 <= k < T - 2 and before is None:
        if u < faults.loss:
            log.lost += 1
            out = []
        elif u < faults.loss + faults.reorder:
            log.reordered += 1
            log.reordered_datagrams += len(items)
            held[character] = items
            out = []
        elif u < faults.loss + faults.reorder + faults.duplicate:
            i = int(rng.integers(len(items)))
            log.duplicated += 1
            out = items[:i + 1] + [items[i]] + items[i + 1:]
    return out + (before or [])

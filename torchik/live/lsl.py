"""Lab Streaming Layer: Mocap streams in (`LslSource`), Mocap streams out for `torchik replay`
(`MocapOutlet`), and the joint states `torchik live` publishes (`JointOutlet`).

A Mocap stream (type "Mocap", float32, one stream per character) has 7 channels per segment, in
the order of its `links`: quaternion w, x, y, z (segment to world), angular velocity x, y, z
(rad/s, world); then the base segment's position x, y, z (m, world) and velocity x, y, z (m/s).
The channel labels are `SEGMENT_qw`, ..., `SEGMENT_wz`, `base_x`, ..., `base_vz`, and the
stream's description names the base segment (`<base_link>`) and the character (`<character>`).
pylsl is optional: `pip install 'torchik[live]'`.
"""

from __future__ import annotations

import time
from typing import Iterator

import numpy as np

from ..errors import InputError, optional
from .sample import Sample, SourceStats, Url

SEGMENT_CHANNELS = ("qw", "qx", "qy", "qz", "wx", "wy", "wz")
BASE_CHANNELS = ("base_x", "base_y", "base_z", "base_vx", "base_vy", "base_vz")


def pylsl():
    return optional("pylsl", "live", "a Lab Streaming Layer stream (lsl://)")


def mocap_labels(links) -> list[str]:
    return [f"{link}_{c}" for link in links for c in SEGMENT_CHANNELS] + list(BASE_CHANNELS)


def _stream_info(name: str, kind: str, labels, rate: float, source_id: str, extra: dict[str, str], double=False):
    lsl = pylsl()
    info = lsl.StreamInfo(name, kind, len(labels), rate, lsl.cf_double64 if double else lsl.cf_float32, source_id)
    desc = info.desc()
    for key, value in extra.items():
        desc.append_child_value(key, value)
    channels = desc.append_child("channels")
    for label in labels:
        channels.append_child("channel").append_child_value("label", label)
    return info


class MocapOutlet:
    """One character's Mocap stream (module docstring), for `torchik replay --to lsl://NAME`."""

    def __init__(self, name: str, links, base_link: str, rate: float, character: int = 0):
        self.links = tuple(links)
        self._base = self.links.index(base_link)
        info = _stream_info(name, "Mocap", mocap_labels(self.links), rate, f"torchik-replay-{name}-{character}",
                            dict(base_link=base_link, character=str(character)))
        self.outlet = pylsl().StreamOutlet(info)

    def push(self, quaternion: np.ndarray, angular_velocity: np.ndarray, position: np.ndarray,
             velocity: np.ndarray, stamp: float | None = None) -> None:
        """quaternion [n,4], angular_velocity [n,3], position and velocity of the base [3]."""
        values = np.concatenate((np.concatenate((quaternion, angular_velocity), axis=1).ravel(), position, velocity))
        self.outlet.push_sample(values.astype(np.float32), stamp if stamp is not None else 0.0)


class LslSource:
    """The Mocap streams with the URL's name (or source id), one character each, as samples.
    frame: the sample's index at the stream's nominal rate from its time stamps; time: the LSL
    time stamp (local clock). InputError when no such stream appears within `timeout` seconds."""

    lsl_clock = True

    def __init__(self, url: Url, rate: float | None = None, timeout: float = 5.0):
        lsl = pylsl()
        prop, value = ("name", url.name) if url.name else ("source_id", url.source_id)
        # minimum 1: return as soon as one appears (minimum 0 waits the whole timeout); a second,
        # short look collects the other characters' streams, which open together
        first = lsl.resolve_byprop(prop, value, 1, timeout)
        found = {i.uid(): i for i in first + (lsl.resolve_byprop(prop, value, 0, 0.3) if first else [])}
        infos = [i for i in found.values() if i.type().lower() == "mocap"]
        if not infos:
            seen = sorted({f"{i.name()} ({i.type()})" for i in lsl.resolve_streams(0.5)})
            raise InputError(f"no LSL Mocap stream with {prop} {value!r} appeared in {timeout:g} s; "
                             f"streams seen: {', '.join(seen) or 'none'}")
        infos.sort(key=lambda i: i.source_id())
        self.inlets = [lsl.StreamInlet(i, max_buflen=2, processing_flags=lsl.proc_clocksync | lsl.proc_dejitter)
                       for i in infos]
        try:
            full = [inlet.info(timeout) for inlet in self.inlets]
            for inlet in self.inlets:  # buffer from now on: an inlet otherwise connects at its first pull
                inlet.open_stream(timeout)
        except lsl.TimeoutError as exc:  # the stream closed between resolving and connecting
            raise InputError(f"LSL stream {value!r} went away before it could be read") from exc
        self.links, self.base = [], []
        for info in full:
            labels = _labels(info)
            links = tuple(dict.fromkeys(label.rsplit("_", 1)[0] for label in labels[:-len(BASE_CHANNELS)]))
            if labels != mocap_labels(links):
                raise InputError(f"LSL stream {info.name()!r}: its channels are not the Mocap layout "
                                 f"(7 per segment and 6 for the base; see torchik.live.lsl)")
            base_link = info.desc().child_value("base_link") or links[0]
            self.links.append(links)
            self.base.append(links.index(base_link))
        nominal = rate or infos[0].nominal_srate()
        if not nominal:
            raise InputError(f"LSL stream {infos[0].name()!r} has an irregular rate; give --rate")
        self.rate: float = nominal
        self.stats = SourceStats()
        self._start: list[float | None] = [None] * len(self.inlets)
        self._frame: list[int] = [-1] * len(self.inlets)
        self._closed = False

    def close(self) -> None:
        self._closed = True

    def __iter__(self) -> Iterator[Sample]:
        while not self._closed:
            got = False
            for character, inlet in enumerate(self.inlets):
                values, stamp = inlet.pull_sample(timeout=0.0)
                if values is None:
                    continue
                got = True
                self.stats.datagrams += 1
                yield self._sample(character, np.asarray(values, dtype=np.float64), stamp, time.perf_counter())
            if not got:
                time.sleep(2e-4)

    def _sample(self, character: int, values: np.ndarray, stamp: float, arrival: float) -> Sample:
        links = self.links[character]
        n = len(links)
        per = values[:7 * n].reshape(n, 7)
        start = self._start[character]
        if start is None:
            start = self._start[character] = stamp
        # time stamps jitter: a frame is at least the one after the previous (a gap: lost samples)
        frame = max(int(round((stamp - start) * self.rate)), self._frame[character] + 1)
        self._frame[character] = frame
        position = np.full((n, 3), np.nan)
        velocity = np.full((n, 3), np.nan)
        position[self.base[character]] = values[7 * n:7 * n + 3]
        velocity[self.base[character]] = values[7 * n + 3:]
        self.stats.samples += 1
        return Sample(character, frame, stamp, arrival, links, per[:, :4], per[:, 4:], position, velocity)


def _labels(info) -> list[str]:
    labels, channel = [], info.desc().child("channels").child("channel")
    while not channel.empty():
        labels.append(channel.child_value("label"))
        channel = channel.next_sibling()
    return labels


class JointOutlet:
    """One character's tracked joint state as an LSL stream (type "JointState"): the joint
    positions (rad), optionally the base pose (x, y, z, qw, qx, qy, qz) and the joint velocities,
    channel labels the joint names; time stamps the source's, so that LabRecorder aligns them."""

    def __init__(self, name: str, joint_names, rate: float, character: int, base: bool = False,
                 velocities: bool = False):
        labels = list(joint_names)
        if base:
            labels += ["base_x", "base_y", "base_z", "base_qw", "base_qx", "base_qy", "base_qz"]
        if velocities:
            labels += [f"{j}_velocity" for j in joint_names]
        self.labels = labels
        info = _stream_info(name, "JointState", labels, rate, f"torchik-live-{name}-{character}",
                            dict(character=str(character), units="rad, m, rad/s"), double=True)
        self.outlet = pylsl().StreamOutlet(info)

    def push(self, values: np.ndarray, stamp: float) -> None:
        """values [C] or [1,C] float64, stamped `stamp` (LSL's clock). As a chunk of one sample: pylsl
        hands a C-contiguous float64 array to liblsl as it is, where push_sample would build a
        ctypes array value by value."""
        self.outlet.push_chunk(np.ascontiguousarray(values, dtype=np.float64).reshape(1, -1), stamp)

"""An Xsens MVN stream received over UDP or TCP (`MvnSource`): datagrams read off the socket as
they come, each with its arrival time, and joined into samples by the `Assembler` (the format:
`mvn.py`)."""

from __future__ import annotations

import errno
import select
import socket
import time
from typing import Iterator

from ..errors import InputError
from .mvn import HEADER, ITEMS, MAGIC, Assembler, MalformedDatagram, parse_header
from .sample import Sample, SourceStats, Url, snap_rate


class MvnSource:
    """An MVN stream received over UDP or TCP (MVN connects to the receiver), listening on
    url.host:url.port.
    Iterate for samples; `rate` is the frame rate given or, else, estimated from the time codes of
    the first two samples (the first is held back until then). `close()` ends the iteration."""

    def __init__(self, url: Url, rate: float | None = None, receive_buffer: int = 1 << 22,
                 position_scale: float = 1.0, bound: socket.socket | None = None):
        """bound: a UDP socket this source's twin already bound to url (a receiver process reads
        the socket its tracker bound: see `receiver.py`)."""
        self.url, self.rate = url, rate
        self.assembler = Assembler(position_scale)
        self._closed = False
        self._held: list[Sample] = []  # samples held back until the rate is known
        if bound is not None:
            self.socket = bound
            self.socket.settimeout(0.0)  # as below: a socket handed over comes back blocking
            return
        try:
            if url.scheme == "udp":
                self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
            else:  # MVN connects to the receiver it is told to stream to
                self.socket = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.socket.bind((url.host, url.port))
            if url.scheme == "tcp":
                self.socket.listen(1)
        except OSError as exc:
            reason = "the port is in use" if exc.errno == errno.EADDRINUSE else exc.strerror or str(exc)
            raise InputError(f"cannot listen on {url}: {reason}") from None
        # UDP: read when select says so, until none is left; TCP: how soon close() is noticed
        self.socket.settimeout(0.0 if url.scheme == "udp" else 0.2)

    @property
    def stats(self) -> SourceStats:
        return self.assembler.stats

    @property
    def address(self) -> tuple[str, int]:
        """Where the source listens: the port when url.port was 0."""
        return self.socket.getsockname()

    def close(self) -> None:
        self._closed = True

    def receive(self, timeout: float, most: int = 1024) -> list[Sample]:
        """UDP: the samples completed by the datagrams waiting on the socket (at most `most`),
        waiting up to `timeout` for the first; parsed as one batch (`Assembler.add_batch`)."""
        datas: list[bytes] = []
        arrivals: list[float] = []
        if select.select([self.socket], [], [], timeout)[0]:
            while len(datas) < most:
                try:
                    datas.append(self.socket.recv(65536))
                except BlockingIOError:
                    break
                arrivals.append(time.perf_counter())
        return self._rated(self.assembler.add_batch(datas, arrivals)) if datas else []

    def _rated(self, samples: list[Sample]) -> list[Sample]:
        """The samples to hand on: none until the rate is known (held back until then)."""
        if self.rate is not None or not samples:
            return samples
        self._held += samples
        self.rate = _estimate_rate(self._held)
        if self.rate is None:
            return []
        held, self._held = self._held, []
        return held

    def _datagrams(self) -> Iterator[tuple[bytes, float]]:
        """TCP: the datagrams as they come off the connection, each with its arrival time."""
        connection = None
        while connection is None and not self._closed:
            try:
                connection, _ = self.socket.accept()
            except TimeoutError:
                continue
        if connection is None:
            return
        connection.settimeout(0.2)
        buffer = b""
        while not self._closed:  # TCP: datagrams back to back, each as long as its header says
            try:
                chunk = connection.recv(65536)
            except TimeoutError:
                continue
            if not chunk:
                return
            buffer += chunk
            while len(buffer) >= HEADER.size:
                try:
                    header = parse_header(buffer)
                    size = header.payload_size or header.items * ITEMS.get(header.message_type, ITEMS["02"]).itemsize
                except MalformedDatagram:  # lost framing: nothing after it can be trusted until resynchronised
                    start = buffer.find(MAGIC, 1)
                    self.assembler.stats.malformed += 1
                    buffer = buffer[start:] if start > 0 else b""
                    continue
                if len(buffer) < HEADER.size + size:
                    break
                yield buffer[:HEADER.size + size], time.perf_counter()
                buffer = buffer[HEADER.size + size:]
        connection.close()

    def __iter__(self) -> Iterator[Sample]:
        try:
            if self.url.scheme == "udp":
                while not self._closed:
                    yield from self.receive(0.2)
                return
            for data, arrival in self._datagrams():
                yield from self._rated(self.assembler.add(data, arrival))
        finally:
            self.socket.close()


def _estimate_rate(samples: list[Sample]) -> float | None:
    """The frame rate from the time codes of two samples of one character, or None before there are two."""
    first = samples[0]
    for s in samples[1:]:
        if s.character == first.character and s.time > first.time:
            return snap_rate((s.frame - first.frame) / (s.time - first.time))
    return None

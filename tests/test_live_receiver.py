"""The receiver process (torchik/live/receiver.py): while the tracker does not take, only each
character's newest sample waits and every one stepped over is counted; the source's counters reach
the tracker, the last ones at close; the process ends when closed, when its tracker's pipe closes
and when the live loop is interrupted (no orphan); samples cross the pipe unchanged."""

from __future__ import annotations

import pickle
import socket
import threading
import time

import numpy as np
import pytest
import torch

from torchik.errors import InputError
from torchik.live.mvn import MVN_SEGMENTS, encode_datagrams
from torchik.live.receiver import ReceiverProcess, pack, unpack
from torchik.live.sample import Sample, Url
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.live import LiveOptions, Mailbox, Selection, track_live
from torchik.pipelines.replay import replay
from torchik.synthetic.scenarios import scenario

IDS = np.arange(1, 24)


def frame(counter: int, character: int) -> list[bytes]:
    """One frame of a character at 100 Hz: the pelvis' position (type 21), every segment's rotation (22)."""
    q = np.tile([1.0, 0.0, 0.0, 0.0], (23, 1))
    linear = encode_datagrams("21", counter, counter * 10, character, IDS[:1],
                              dict(position=np.full((1, 3), 0.01 * counter), velocity=np.zeros((1, 3))))
    return linear + encode_datagrams("22", counter, counter * 10, character, IDS,
                                     dict(quaternion=q, angular_velocity=np.zeros((23, 3))))


def send(address, datagrams: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for d in datagrams:
            s.sendto(d, address)


def delivered_until(source: ReceiverProcess, mailbox: Mailbox, done, timeout: float = 20.0) -> None:
    deadline = time.perf_counter() + timeout
    while not done() and time.perf_counter() < deadline:
        source.deliver(mailbox, 0.1)


def test_while_the_tracker_does_not_take_only_the_newest_sample_waits_and_the_others_are_counted():
    source = ReceiverProcess(Url("udp", "127.0.0.1", 0), backlog=1)
    frames, characters = 30, (0, 3)
    try:
        send(source.address, [d for k in range(frames) for c in characters for d in frame(k, c)])
        time.sleep(1.0)  # every datagram received while the tracker took nothing
        mailbox = Mailbox(backlog=1)
        delivered_until(source, mailbox, lambda: source.stats.samples == frames * len(characters)
                        and all(q and q[-1].frame == frames - 1 for q in mailbox.queues.values()))
        got = mailbox.take(characters, timeout=0.0, gather=0.0)
    finally:
        source.close()
    assert {c: s.frame for c, s in got.items()} == {c: frames - 1 for c in characters}
    np.testing.assert_allclose(got[3].position[0], 0.01 * (frames - 1), rtol=1e-6)
    # all but the newest stepped over: by the receiver or by the mailbox, each counted once
    assert mailbox.skipped == {c: frames - 1 for c in characters}
    assert sum(source.skipped.values()) > 0  # the receiver held them back, not the pipe
    assert source.stats.lost == 0 and source.rate == 100.0


def test_the_source_counters_reach_the_tracker_and_their_last_values_come_at_close():
    source = ReceiverProcess(Url("udp", "127.0.0.1", 0), backlog=1000)
    stream = [d for k in range(10) for d in frame(k, 0)]
    malformed = [b"MXTP22 too short", b"XXTP" + stream[3][4:]]
    duplicates = [stream[7], stream[8]]  # frame 3's, the newest delivered; frame 4's first, while it waits
    send(source.address, stream[:9] + duplicates + malformed + stream[9:])
    mailbox = Mailbox(backlog=1000)
    delivered_until(source, mailbox, lambda: source.stats.samples == 10)
    source.close()
    stats = source.stats
    assert (stats.samples, stats.malformed, stats.duplicates, stats.lost) == (10, 2, 2, 0)
    assert stats.datagrams == len(stream) + 4
    assert [s.frame for s in mailbox.queues[0]] == list(range(10)) and not mailbox.skipped


def test_the_receiver_ends_when_closed_and_when_its_tracker_is_gone():
    closed = ReceiverProcess(Url("udp", "127.0.0.1", 0))
    closed.close()
    assert not closed.process.is_alive() and closed.process.exitcode == 0
    orphaned = ReceiverProcess(Url("udp", "127.0.0.1", 0))
    orphaned._credits.close()  # as when the tracker's process dies: its ends of the pipes close
    orphaned._messages.close()
    orphaned.process.join(timeout=10.0)
    assert not orphaned.process.is_alive() and orphaned.process.exitcode == 0


def test_a_port_in_use_is_refused_with_the_url():
    taken = ReceiverProcess(Url("udp", "127.0.0.1", 0))
    try:
        with pytest.raises(InputError, match="in use"):
            ReceiverProcess(Url("udp", "127.0.0.1", taken.address[1]))
    finally:
        taken.close()


def test_ctrl_c_in_the_live_loop_ends_the_session_and_its_receiver():
    torch.set_num_threads(1)
    model = load_model("human66")
    walk = scenario("walking", model, TRACKED_LINKS["human66"], duration=20.0, rate=100.0)
    source = ReceiverProcess(Url("udp", "127.0.0.1", 0))
    stop = threading.Event()
    sender = threading.Thread(target=replay, args=(walk, Url("udp", "127.0.0.1", source.address[1])),
                              kwargs=dict(stop=stop, lead_in_s=0.1))
    sender.start()

    def interrupt(counters, elapsed):  # Ctrl-C once the session tracks
        if counters["samples"]:
            raise KeyboardInterrupt

    try:
        result = track_live(source, model, lambda names: Selection.build(names, TRACKED_LINKS["human66"]),
                            progress=interrupt, options=LiveOptions(stop_when_idle_s=5.0))
    finally:
        stop.set()
        sender.join()
    assert result.interrupted and result.source_stats["samples"] > 0
    assert not source.process.is_alive() and source.process.exitcode == 0


@pytest.mark.parametrize("count", [1, 4], ids=["as samples", "as arrays"])
def test_samples_cross_the_pipe_unchanged_whatever_fields_they_carry(count):
    rng = np.random.default_rng(0)
    links = ("a", "b")

    def sample(character, frame, full):
        extra = (lambda: rng.normal(size=(2, 3))) if full else (lambda: None)
        return Sample(character, frame, frame / 100, rng.uniform(), links if full else MVN_SEGMENTS[:2],
                      rng.normal(size=(2, 4)), extra(), extra(), extra())

    samples = [sample(0, 1, True), sample(1, 1, False), sample(2, 1, True), sample(1, 2, False)][:count]
    back = sorted(unpack(pickle.loads(pickle.dumps(pack(samples)))), key=lambda s: (s.character, s.frame))
    for a, b in zip(sorted(samples, key=lambda s: (s.character, s.frame)), back, strict=True):
        assert (a.character, a.frame, a.time, a.arrival, a.links) == (b.character, b.frame, b.time, b.arrival, b.links)
        for name in ("quaternion", "angular_velocity", "position", "velocity"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None and y is None) or np.array_equal(x, y)

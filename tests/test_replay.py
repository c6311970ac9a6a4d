"""The replay (torchik/pipelines/replay.py) as a sender: what it keeps while streaming stays out of
the garbage collector's reach, so that the collector never stalls the stream."""

from __future__ import annotations

import gc

import torch

from torchik.live.sample import Url
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.replay import _MvnSender, wire_frames
from torchik.synthetic.scenarios import scenario


def test_the_cache_of_encoded_frames_is_not_walked_by_the_garbage_collector():
    """A full collection walks every object the collector tracks: were the cache of encoded frames
    (one entry per recording frame) among them, a 90 s replay at 240 Hz would bring on a full
    collection of some 200 ms in the middle of the stream (measured 185 ms: 44 frames owed and
    sent at once)."""
    torch.set_num_threads(1)
    walk = scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=0.5, rate=100.0)
    sender = _MvnSender(Url("udp", "127.0.0.1", 9), wire_frames(walk), 1472)
    try:
        for k in range(len(walk.time)):
            assert sender.datagrams(k, k, 0)
        for _ in range(2):  # a tuple is untracked once its items are: the pairs at the second pass
            gc.collect()
        tracked = [entry for entry in sender.payloads.values() if gc.is_tracked(entry)]
    finally:
        sender.close()
    assert len(sender.payloads) == len(walk.time) and not tracked

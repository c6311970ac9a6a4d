"""`torchik track --scenario`: the scenario is made a chunk at a time as it is tracked (issue 36), so a
run's memory does not grow with its duration; the hour's peak is experiments/long_run.py's to measure."""

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_leaves

import torchik.pipelines.track


class LargestTensor(TorchDispatchMode):
    """Within it, the most elements of any tensor an operation makes (factories, views and results)."""

    def __init__(self):
        super().__init__()
        self.numel = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        self.numel = max([self.numel] + [t.numel() for t in tree_leaves(out) if isinstance(t, torch.Tensor)])
        return out


class Tracked(Exception):
    """Every chunk was made: the tracking itself is not this test's."""


def test_the_largest_tensor_of_a_scenario_track_does_not_grow_with_its_duration(cli, monkeypatch):
    """The command line's scenario, from its start through every chunk the tracking reads, makes no
    larger tensor for twice the duration (a whole scenario's Jacobians grew with it: 1.3 GB at 180 s)."""
    def chunks_only(model, source, links, settings, outputs=(), *, chunk=torchik.pipelines.track.CHUNK, **kwargs):
        frames = 0
        for part in source.chunks(chunk):
            assert len(part.time) <= chunk
            frames += len(part.time)
        assert frames == len(source.time)
        raise Tracked

    monkeypatch.setattr(torchik.pipelines.track, "track_chunks", chunks_only)
    largest = {}
    for duration in (40, 80):  # 1001 and 2001 frames at 25 Hz
        with LargestTensor() as mode, pytest.raises(Tracked):
            cli("track", "--scenario", "walking", "--model", "human66", "--duration", duration, "--rate", 25, "--quiet")
        largest[duration] = mode.numel
    assert largest[80] == largest[40], largest

"""The live loop's warm-up (`_Loop.warm_up`): before the first sample, the tracker for the expected
links and characters is built and stepped, and where the stream's rate is known it is the session's,
its compiled step already captured for one character and for the expected batch."""

from __future__ import annotations

import torch

import torchik.method.captured as captured
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.settings import TrackerSettings
from torchik.pipelines.live.loop import Outputs, _Loop


def test_with_the_rate_known_the_warmed_tracker_is_the_sessions_its_step_already_captured(monkeypatch):
    monkeypatch.setattr(captured, "capture", lambda fn, inputs: fn)  # its plumbing, not TorchInductor's cost
    torch.set_num_threads(1)
    model, links = load_model("human66"), TRACKED_LINKS["human66"]
    loop = _Loop(model, TrackerSettings(compile=True), None, Outputs(), True, False)
    loop.warm_up(links, 120.0, characters=2)
    warm = loop._warm
    assert warm is not None and sorted(warm._captures) == [1, 2]
    assert all(c.compile_seconds is not None for c in warm._captures.values())  # captured before the stream
    assert loop._tracker(links, 120.0) is warm
    # the rate not known: the process is warmed, no tracker kept (nor a capture made at a guessed rate)
    loop.warm_up(links, None)
    assert loop._warm is None
    assert loop._tracker(links, 60.0).dt == 1 / 60

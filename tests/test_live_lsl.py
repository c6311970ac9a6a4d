"""Lab Streaming Layer in and out (torchik/live/lsl.py): a Mocap stream replayed to LSL is tracked,
and the joint states published on the outlet read back with a pylsl inlet equal the estimates,
labelled with the joint names, stamped with the Mocap samples' time stamps."""

from __future__ import annotations

import threading
import uuid

import numpy as np
import pytest
import torch

from torchik.live.lsl import LslSource
from torchik.live.sample import Url
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.live import LiveOptions, Publisher, Selection, track_live
from torchik.pipelines.replay import replay
from torchik.synthetic.scenarios import scenario

pylsl = pytest.importorskip("pylsl")


def test_a_mocap_stream_in_and_the_joint_states_out_round_trip_through_lsl():
    torch.set_num_threads(1)
    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    walk = scenario("walking", model, links, duration=1.0, rate=100.0)
    name = f"torchik-test-{uuid.uuid4().hex[:8]}"
    publisher = Publisher(f"{name}-out", model, rate=100.0)
    publisher.outlet(0)  # open before the first estimate, so the inlet below misses none
    info = pylsl.resolve_byprop("name", f"{name}-out", 1, 5.0)[0]
    inlet = pylsl.StreamInlet(info)
    inlet.open_stream(5.0)
    sender = threading.Thread(target=replay, args=(walk, Url("lsl", name=name)), kwargs=dict(lead_in_s=1.0))
    sender.start()
    source = LslSource(Url("lsl", name=name), timeout=5.0)
    result = track_live(source, model, lambda names: Selection.build(names, links), publisher=publisher,
                        options=LiveOptions(backlog=1000, stop_when_idle_s=0.5))
    sender.join()
    values, stamps = inlet.pull_chunk(timeout=1.0, max_samples=1000)
    estimated = result.trajectories[0].joint_positions[:, 0].numpy()
    assert len(estimated) == len(walk.time) == len(values)
    np.testing.assert_allclose(np.array(values), estimated, rtol=0, atol=1e-12)
    labels = _labels(inlet.info())
    assert labels == list(model.joint_names)
    assert np.all(np.diff(stamps) > 0) and result.report()["characters"]["0"]["mnte"]["median"] < 1e-3


def _labels(info) -> list[str]:
    out, channel = [], info.desc().child("channels").child("channel")
    while not channel.empty():
        out.append(channel.child_value("label"))
        channel = channel.next_sibling()
    return out

"""Retargeting as a live session goes (torchik/pipelines/live/batch.py, `torchik live --retarget
icub`): a walk replayed over loopback UDP is retargeted to iCub and published on LSL; every
published sample, read back with a pylsl inlet, is within iCub's joint limits and its coupled
limits (A s <= b, the model's own matrices) and equals `torchik retarget` offline on the data as
the wire carried it."""

from __future__ import annotations

import threading
import uuid

import numpy as np
import pytest
import torch

from torchik.live.mvn_source import MvnSource
from torchik.live.sample import Url
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.live import LiveOptions, LiveRetarget, Publisher, Selection, track_live
from torchik.pipelines.replay import Faults, replay, wire_recording
from torchik.pipelines.retarget import LIMIT_TOLERANCE, retarget
from torchik.synthetic.scenarios import scenario

pylsl = pytest.importorskip("pylsl")
LINKS = TRACKED_LINKS["human66"]


@pytest.fixture(scope="module")
def walk():
    torch.set_num_threads(1)
    return scenario("walking", load_model("human66"), LINKS, duration=1.0, rate=100.0)


def retargeted_live(walk, faults=None, publisher_name=None):
    """Replay `walk` to a live session retargeting to iCub; its result, the robot stage, and what the
    LSL outlet published (values [T,n], labels)."""
    model = load_model("human66")
    robot = LiveRetarget()
    publisher = inlet = None
    if publisher_name is not None:
        publisher = Publisher(publisher_name, robot.model, rate=100.0)
        publisher.outlet(0)  # open before the first estimate, so the inlet below misses none
        inlet = pylsl.StreamInlet(pylsl.resolve_byprop("name", publisher_name, 1, 5.0)[0])
        inlet.open_stream(5.0)
    source = MvnSource(Url("udp", "127.0.0.1", 0))
    sender = threading.Thread(target=replay, args=(walk, Url("udp", "127.0.0.1", source.address[1]), 3.0, 1, faults),
                              kwargs=dict(lead_in_s=0.1))
    sender.start()
    result = track_live(source, model, lambda names: Selection.build(names, LINKS), publisher=publisher,
                        options=LiveOptions(backlog=100000, stop_when_idle_s=0.4), retarget=robot)
    sender.join()
    published = inlet.pull_chunk(timeout=1.0, max_samples=10000)[0] if inlet is not None else None
    return result, robot, np.array(published) if published is not None else None


def test_published_icub_joints_are_within_every_limit_and_equal_offline_retargeting(walk):
    name = f"torchik-test-icub-{uuid.uuid4().hex[:8]}"
    result, robot, published = retargeted_live(walk, publisher_name=name)
    icub = robot.model
    offline, _ = retarget(wire_recording(walk), rate=100.0)
    assert published.shape == (len(walk.time), icub.n_dof) == offline.joint_positions.shape
    s = torch.from_numpy(published)
    assert bool((s >= icub.lower - LIMIT_TOLERANCE).all() and (s <= icub.upper + LIMIT_TOLERANCE).all())
    A, b = icub.linear_limits.A, icub.linear_limits.b
    assert float((s @ A.T - b).max()) <= LIMIT_TOLERANCE
    np.testing.assert_allclose(published, offline.joint_positions, rtol=0, atol=1e-9)
    assert result.retarget["refused_beyond_limits"] == 0
    live = result.retargeted[0]
    np.testing.assert_allclose(live.time.numpy(), offline.time - offline.time[0], rtol=0, atol=1e-12)


def test_over_long_gaps_the_robot_stays_within_its_limits_and_moves_on_without_restarting(walk):
    result, robot, _ = retargeted_live(walk, Faults(loss=0.6, seed=5))
    trajectory = result.retargeted[0]
    assert float(np.diff(trajectory.time.numpy()).max()) > 5 / 100  # gaps past the tracker's max_gap
    assert result.retarget["limit_excess"] <= LIMIT_TOLERANCE and result.retarget["refused_beyond_limits"] == 0
    assert not bool(trajectory.diagnostics["new_segment"].any())  # gaps integrated, not restarted from a fit

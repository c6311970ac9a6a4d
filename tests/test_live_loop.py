"""The live loop over loopback UDP (torchik/pipelines/live.py with torchik/pipelines/replay.py): a
fault-free replay tracks to the same estimates as `track` on the data as the wire carried it;
with faults it finishes, stays as accurate and counts exactly what was injected, whether received
in a thread or in a process of its own; two characters are tracked as one batch."""

from __future__ import annotations

import threading
import time

import pytest
import torch
from conftest import shared_file

from torchik.io import read
from torchik.io.maps import load_map, map_recording
from torchik.live.mvn_source import MvnSource
from torchik.live.receiver import ReceiverProcess
from torchik.live.sample import Url
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.live import LiveOptions, Selection, track_live
from torchik.pipelines.replay import Faults, replay, wire_recording
from torchik.pipelines.track import track_recording
from torchik.synthetic.scenarios import scenario


@pytest.fixture(scope="module")
def model():
    torch.set_num_threads(1)
    return load_model("human66")


@pytest.fixture(scope="module")
def walking(model):
    """A walk measured with noise (0.01 rad, 0.05 rad/s): what faults add is then judged against
    errors a sensor has, not against rounding."""
    return scenario("walking", model, TRACKED_LINKS["human66"], duration=3.0, rate=100.0, orientation_noise=0.01,
                    gyro_noise=0.05)


@pytest.fixture(scope="module")
def clean_walk(model, walking):
    return live_run(model, walking)[0]


def live_run(model, recording, link_map=None, faults=None, characters=1, speed=3.0, receiver_process=False):
    """Replay `recording` to a live session on an ephemeral loopback port (received in a thread, or
    in a process of its own); the session's result and the replay's log. Every sample is queued
    (backlog) so that the run is deterministic."""
    backlog = 100000
    source = ReceiverProcess(Url("udp", "127.0.0.1", 0), backlog=backlog) if receiver_process else \
        MvnSource(Url("udp", "127.0.0.1", 0))
    port = source.address[1]
    logs = []
    sender = threading.Thread(target=lambda: logs.append(
        replay(recording, Url("udp", "127.0.0.1", port), speed, characters, faults, lead_in_s=0.1)))
    sender.start()
    links = TRACKED_LINKS["human66"]
    result = track_live(source, model, lambda names: Selection.build(names, links, link_map),
                        options=LiveOptions(backlog=backlog, stop_when_idle_s=0.4))
    sender.join()
    return result, logs[0]


@pytest.fixture(params=["written", "shared"])
def mvnx(request):
    """An MVNX file: the MVN export the tests write (conftest's mvn_export), or the real one in ../shared/data."""
    if request.param == "written":
        return request.getfixturevalue("mvn_export").path
    return shared_file("mvnx/test_mocap.mvnx")


def test_a_fault_free_replay_of_the_mvnx_recording_tracks_as_track_does_on_what_the_wire_carried(model, mvnx):
    recording = read(mvnx)
    result, log = live_run(model, recording, load_map("xsens_to_human"))
    offline, _ = track_recording(model, *_mapped(wire_recording(recording), model))
    live = result.trajectories[0]
    assert result.source_stats["samples"] == log.frames == len(recording.time) and not result.skipped
    torch.testing.assert_close(live.time, offline.time, rtol=0, atol=1e-12)
    torch.testing.assert_close(live.joint_positions, offline.joint_positions, rtol=0, atol=1e-9)


def _mapped(recording, model):
    mapped, link_map = map_recording(recording, "xsens_to_human", model)
    return mapped, mapped.links


def test_a_fault_free_replay_of_a_generated_walk_tracks_as_track_does(model, walking, clean_walk):
    result = clean_walk
    offline, _ = track_recording(model, wire_recording(walking), TRACKED_LINKS["human66"])
    torch.testing.assert_close(result.trajectories[0].joint_positions, offline.joint_positions, rtol=0, atol=1e-9)


@pytest.mark.parametrize("receiver_process", [False, True], ids=["thread", "process"])
def test_with_loss_reordering_and_duplicates_it_finishes_as_accurate_and_counts_what_was_injected(
        model, walking, clean_walk, receiver_process):
    clean = clean_walk
    faulty, log = live_run(model, walking, faults=Faults(loss=0.05, reorder=0.02, duplicate=0.02, seed=3),
                           receiver_process=receiver_process)
    assert log.lost and log.reordered and log.duplicated
    stats = faulty.source_stats
    assert stats["lost"] == log.lost + log.reordered
    assert stats["late"] == log.reordered_datagrams
    assert stats["duplicates"] == log.duplicated
    assert stats["samples"] == log.frames - log.lost - log.reordered
    after = lambda r: r.report(transient=1.0)["characters"]["0"]["mnte"]["median"]  # noqa: E731
    assert after(faulty) <= 2 * after(clean)


def test_two_characters_stream_at_once_and_are_tracked_as_one_batch(model, walking):
    short = scenario("walking", model, TRACKED_LINKS["human66"], duration=1.0, rate=100.0)
    result, log = live_run(model, short, characters=2)
    assert set(result.trajectories) == {0, 1}
    assert all(len(t.time) == log.frames for t in result.trajectories.values())
    # one step per frame for both (a batch of two); the second joins one step late at most
    assert len(result.step_time) <= log.frames + 1
    first, second = (result.trajectories[c].joint_positions[:, 0] for c in (0, 1))
    assert not torch.allclose(first, second)  # each its own phase of the walk
    assert all(r["mnte"]["median"] < 1e-2 for r in result.report(transient=0.5)["characters"].values())


def test_frames_the_loop_steps_over_do_not_restart_a_character_from_the_zero_pose(model, walking):
    source = MvnSource(Url("udp", "127.0.0.1", 0))
    # as fast as the socket takes it: the loop steps over most frames, many more than max_gap at once
    sender = threading.Thread(target=replay, args=(walking, Url("udp", "127.0.0.1", source.address[1]), float("inf")),
                              kwargs=dict(lead_in_s=0.1))
    sender.start()
    result = track_live(source, model, lambda names: Selection.build(names, TRACKED_LINKS["human66"]),
                        options=LiveOptions(backlog=1, stop_when_idle_s=0.4))
    sender.join()
    frames = torch.round(result.trajectories[0].time * 100.0)
    assert result.skipped[0] > 0 and float(frames.diff().max()) > 5  # steps over more than max_gap frames
    assert not result.trajectories[0].diagnostics["new_segment"].any()


@pytest.mark.parametrize("backlog", [1, None], ids=["newest only", "default"])
def test_a_burst_after_the_sender_stalled_is_tracked_frame_by_frame_as_track_does(model, backlog):
    """A sender that loses its core for 0.1 s then sends the 5 frames it owes at once, as a suit's
    software does after a stall. With the default backlog the loop, whose steps are far shorter
    than a 50 Hz frame, tracks every one of them in order, each with its own dt (the estimates are
    `track`'s on the same frames) and skips none; stepping to the newest (backlog 1) skips some."""
    walk = scenario("walking", model, TRACKED_LINKS["human66"], duration=2.0, rate=50.0)
    source = MvnSource(Url("udp", "127.0.0.1", 0))
    stall = lambda k: time.sleep(0.1) if k == 40 else None  # noqa: E731
    sender = threading.Thread(target=replay, args=(walk, Url("udp", "127.0.0.1", source.address[1])),
                              kwargs=dict(lead_in_s=0.1, on_frame=stall))
    sender.start()
    options = LiveOptions(stop_when_idle_s=0.4) if backlog is None else LiveOptions(backlog=1, stop_when_idle_s=0.4)
    result = track_live(source, model, lambda names: Selection.build(names, TRACKED_LINKS["human66"]), options=options)
    sender.join()
    assert result.source_stats["samples"] == len(walk.time)
    if backlog == 1:
        assert sum(result.skipped.values()) > 0  # the burst is there
        return
    offline, _ = track_recording(model, wire_recording(walk), TRACKED_LINKS["human66"])
    live = result.trajectories[0]
    assert sum(result.skipped.values()) == 0
    torch.testing.assert_close(live.time, offline.time, rtol=0, atol=1e-12)
    torch.testing.assert_close(live.joint_positions, offline.joint_positions, rtol=0, atol=1e-9)


def test_what_the_set_up_made_is_out_of_the_garbage_collectors_reach_once_tracking(model):
    """A full collection must not walk torch's modules and the model at every pass (150-180 ms a
    collection with the compiled step): the live loop freezes them after its first steps."""
    import gc

    gc.unfreeze()
    short = scenario("walking", model, TRACKED_LINKS["human66"], duration=0.3, rate=100.0)
    try:
        live_run(model, short)
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_garbage_is_collected_between_samples_never_during_a_step(model, monkeypatch):
    """A collection in a step delays that sample's estimate by its pause (a gen-1 collection some
    1 ms at 240 Hz): the loop runs the collections that come due after a step, not in one."""
    import gc

    import torchik.pipelines.live.loop as live_loop

    stepping, starts = [False], []
    step = live_loop._Loop.step

    def timed_step(self, *args, **kwargs):
        stepping[0] = True
        try:
            step(self, *args, **kwargs)
        finally:
            stepping[0] = False

    def seen(phase, info):
        if phase == "start":
            starts.append(stepping[0])

    monkeypatch.setattr(live_loop._Loop, "step", timed_step)
    short = scenario("walking", model, TRACKED_LINKS["human66"], duration=0.3, rate=100.0)
    saved = gc.get_threshold()
    gc.set_threshold(100, 2, 2)  # collections due within every step, each generation's among them
    gc.callbacks.append(seen)
    try:
        live_run(model, short)
    finally:
        gc.callbacks.remove(seen)
        gc.set_threshold(*saved)
    assert starts and not any(starts)

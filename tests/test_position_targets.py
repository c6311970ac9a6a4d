"""Position targets off the base: io.targets takes them from a recording's segment origins (with
central-difference velocities), the recording format keeps them, and a tracker given a subject's
consistent targets follows them; `torchik track --position-targets` reports their errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import shared_file

from torchik.cli import main
from torchik.errors import InputError
from torchik.io import load_recording, read, save_recording
from torchik.io.recording import Recording
from torchik.io.targets import recording_targets
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.track import track_recording
from torchik.synthetic.scenarios import scenario

ENDS = ("RightHand", "LeftHand", "RightFoot", "LeftFoot")


def with_link_origins(recording: Recording, model) -> Recording:
    """A scenario recording with every link's origin, from the model at its ground-truth configuration."""
    T = len(recording.time)
    s = torch.from_numpy(recording.joint_positions)
    p = torch.from_numpy(recording.base_position)
    R = torch.from_numpy(recording.orientation[:, recording.links.index(recording.base_link)])
    position = model(p, R, s, recording.links, jacobian=False).position.numpy()
    assert position.shape == (T, len(recording.links), 3)
    return Recording(**{**vars(recording), "position": position})


def test_a_scenario_with_consistent_position_targets_is_tracked_to_them(tmp_path):
    model = load_model("human48")
    links = TRACKED_LINKS["human48"]
    recording = with_link_origins(scenario("walking", model, links, duration=2.0, rate=50.0), model)
    save_recording(recording, tmp_path / "walk.npz")
    recording = load_recording(tmp_path / "walk.npz")  # the format keeps the positions
    sequence = recording_targets(recording, links, ("Pelvis", *ENDS))
    assert sequence.position.shape[-2] == 5
    np.testing.assert_allclose(sequence.position[:, 0, 1].numpy(), recording.position[:, links.index("RightHand")])
    _, report = track_recording(model, recording, links, position_links=("Pelvis", *ENDS), transient=1.0)
    assert max(report["position_error_m"][link]["p99"] for link in ENDS) < 5e-3


def test_position_targets_need_the_recordings_positions():
    model = load_model("human48")
    recording = scenario("walking", model, TRACKED_LINKS["human48"], duration=0.2, rate=50.0)
    with pytest.raises(InputError, match="base link 'Pelvis' only"):
        recording_targets(recording, recording.links, ("Pelvis", "RightHand"))


@pytest.mark.parametrize("source", ["written", "shared"])
def test_track_reports_the_position_error_of_each_target(tmp_path, monkeypatch, source, request):
    """A Plug-in Gait walk calibrated on its static trial: the session the tests write (conftest's
    pig_session; the subject's segment origins are its joint centres, so with the subject's own model,
    from the static trial, the hands and feet are followed to a millimetre) or the real HC002 one."""
    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)
    if source == "written":
        static, walk = request.getfixturevalue("pig_session").static, request.getfixturevalue("pig_session").walk
    else:
        static, walk = shared_file("c3d/HC002D02.c3d"), shared_file("c3d/HC002D25.c3d")
    assert read(walk).position is not None
    assert main(["track", "--input", str(walk), "--calibration", str(static), "--subject-from", str(static),
                 "--model", "human48", "--position-targets", *ENDS, "--quiet", "--report", str(tmp_path / "r.json")]) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert set(report["position_error_m"]) == {"Pelvis", *ENDS}
    if source == "written":
        assert max(error["max"] for error in report["position_error_m"].values()) < 1e-3

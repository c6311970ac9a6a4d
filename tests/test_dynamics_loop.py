"""The loop on forces in `torchik dynamics` (pipelines/dynamics_loop.py).

The command runs on a walk the test writes (.npz, the walking scenario on Human48 with every tracked
link's orientation and origin, 4 s at 100 Hz) whose feet's ground reactions are the base wrench that
a model with a trunk 10 % heavier needs for the motion (torchik's `trajectory_dynamics` on the true
trajectory), shared between the feet and read by the plates 20 ms late. The loop finds the trunk's
mass and the lag, and the residual after it is a fraction of the one before.
"""

import json
import math

import numpy as np
import pytest
import torch

import torchik as tk
from torchik.io.recording import Recording, save_recording
from torchik.method.dynamics import trajectory_dynamics
from torchik.pipelines.dynamics_effects import HUMAN_SEGMENTS
from torchik.synthetic.scenarios import scenario_motion

SECONDS, RATE, LATE = 4.0, 100.0, 2  # the plates 2 frames (20 ms) late


def heavier(model, links, factor: float):
    """The model with each of `links`' masses times `factor` (centres and inertias kept)."""
    mass = model._tensors.geometry.link_mass[:, 0].clone()
    for link in links:
        mass[model.link_names.index(link)] *= factor
    return model.with_inertial(mass=mass)


@pytest.fixture(scope="module")
def walk_with_plates(tmp_path_factory):
    """(path of the .npz, the model): the walk of the module docstring."""
    from written import walk

    model = tk.load_model("human48")
    recording = walk(model, "walking", seconds=SECONDS, rate=RATE)
    motion = scenario_motion("walking", model, duration=SECONDS, rate=RATE)
    base = trajectory_dynamics(heavier(model, HUMAN_SEGMENTS["trunk"], 1.10), motion, cutoff=6.0).base_wrench[:, 0]
    p = motion.base_position[:, 0]
    total = torch.cat((base[:, :3], base[:, 3:] + torch.linalg.cross(p, base[:, :3])), -1).numpy()  # about the origin
    total = np.concatenate((np.repeat(total[:1], LATE, 0), total[:-LATE]))  # read late
    share = (0.5 + 0.4 * np.sin(2 * math.pi * 0.7 * recording.time))[:, None]
    wrench = np.zeros((len(recording.time), len(recording.links), 6))
    wrench[:, recording.links.index("RightFoot")] = share * total
    wrench[:, recording.links.index("LeftFoot")] = (1 - share) * total
    recording = Recording(**{**vars(recording), "external_wrench": wrench})
    return save_recording(recording, tmp_path_factory.mktemp("loop") / "walk.npz"), model


def test_the_loop_finds_a_heavier_trunk_and_the_plates_lag_and_shrinks_the_residual(walk_with_plates, cli, tmp_path):
    path, model = walk_with_plates
    out = tmp_path / "report"
    code, stdout, err = cli("dynamics", "--input", path, "--model", "human48", "--report", out)
    assert code == 0, err
    assert "loop on forces over the" in stdout and "kept trunk mass" in stdout
    loop = json.loads((out / "summary.json").read_text())["loop"]
    kept = {e["name"]: e for e in loop["kept"]}
    assert {"trunk mass", "plates' lag"} <= set(kept), loop
    assert kept["trunk mass"]["relative"] == pytest.approx(0.10, abs=0.02)
    assert kept["plates' lag"]["value"][0] == pytest.approx(LATE / RATE, abs=3e-3)
    before, after = loop["before"], loop["after"]
    assert before["force_rms_per_weight"] > 0.01
    assert after["force_rms_per_weight"] < 0.5 * before["force_rms_per_weight"]  # the tracker's first frames left
    assert after["moment_rms_n_m_per_kg"] < 0.2 * before["moment_rms_n_m_per_kg"]
    assert (out / "residual_loop.png").stat().st_size > 0
    report = (out / "report.md").read_text()
    assert "## The loop on forces" in report and "| trunk mass |" in report and "residual_loop.png" in report
    # the report's torques are the corrected model's: the trunk heavier by what was found
    torques = np.genfromtxt(out / "joint_torques.csv", delimiter=",", names=True)
    assert np.isfinite(torques["jL5S1_roty"]).all()


def test_no_fit_skips_the_loop(walk_with_plates, cli, tmp_path):
    path, _ = walk_with_plates
    out = tmp_path / "report"
    code, stdout, err = cli("dynamics", "--input", path, "--model", "human48", "--report", out, "--no-fit")
    assert code == 0, err
    assert "loop on forces" not in stdout and not (out / "residual_loop.png").exists()
    assert json.loads((out / "summary.json").read_text())["loop"] is None

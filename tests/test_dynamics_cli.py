"""`torchik dynamics` (cli/dynamics.py) and what it runs (pipelines/dynamics.py, dynamics_report.py).

The command runs on Plug-in Gait trials the tests write (tests/written.py) with two force plates
added, one under each foot, whose ground reactions are known: a subject standing still in the N-pose,
each plate carrying half the weight at a centre of pressure level with the body's centre of mass.
Then the plates explain the whole motion (the base's residual vanishes), and each ankle holds the
moment of its plate's force about it, less its foot's own weight."""

import json

import numpy as np
import pytest
import torch
from test_force_plates import ANALOG_RATE, DOWN, Plate, add_plates, constant

import torchik as tk
from torchik.io.opensim_table import read_table
from torchik.method.models.human import TEMPLATE, TEMPLATE_MASS, HumanSubject

ezc3d = pytest.importorskip("ezc3d")

FRAMES, RATE = 60, 100.0
SUBJECT = HumanSubject(height=1.45, mass=32.1)
GRAVITY = 9.81


@pytest.fixture(scope="module")
def standing(tmp_path_factory):
    """A Plug-in Gait trial of a 1.45 m, 32.1 kg subject standing still in the N-pose on two plates
    (each 0.3 m by 0.12 m, under one foot), each pushing up half the weight, the two centres of
    pressure symmetric about the centre of mass (the right 3 cm ahead of it, the left 3 cm behind):
    (path, model, the still recording, the centres of pressure [2,3] m, right foot first)."""
    from written import plug_in_gait_c3d, standing

    model = tk.load_model("human48", SUBJECT)
    still = standing(model, "npose", frames=FRAMES, rate=RATE)
    path = plug_in_gait_c3d(tmp_path_factory.mktemp("dynamics") / "HC000S01.c3d", model, still, SUBJECT)
    base = still.links.index("Pelvis")
    com = tk.centre_of_mass(model, torch.from_numpy(still.base_position[:1]), torch.from_numpy(still.orientation[:1, base]),
                            torch.from_numpy(still.joint_positions[:1]))[0][0].numpy()
    feet = [still.position[0, still.links.index(link)] for link in ("RightFoot", "LeftFoot")]
    half = 0.5 * (feet[1][1] - feet[0][1])  # the feet's half distance across
    # the right one 3 cm ahead of the centre of mass, the left 3 cm behind: no moment about it
    cops = np.array([[com[0] + 0.03, com[1] - half, 0.0], [com[0] - 0.03, com[1] + half, 0.0]])
    S = int(FRAMES * ANALOG_RATE / RATE)
    plates, signals = [], []
    for cop, foot in zip(cops, feet):
        plate = Plate(DOWN, (1000.0 * (foot[0] + 0.05), 1000.0 * foot[1], 0.0), half=(150.0, 60.0))
        plates.append(plate)
        signals.append(plate.channels(constant([0.0, 0.0, SUBJECT.mass * GRAVITY / 2], S), constant(1000.0 * cop, S),
                                      constant(0.0, S)))
    c3d = ezc3d.c3d(str(path))
    add_plates(c3d, plates, signals)
    c3d.write(str(path))
    return path, model, still, cops


def test_a_subject_standing_on_two_plates_leaves_no_residual_and_each_ankle_holds_its_plates_moment(standing, cli,
                                                                                                      tmp_path):
    """Outputs exist and parse; the residual over the frames the plates carry every foot is below 0.5 % of
    the weight and 0.01 N m/kg; each ankle's flexion torque is its plate's force times its lever arm about
    the ankle, less its foot's and toe's weights' moments."""
    path, model, still, cops = standing
    out = tmp_path / "report"
    code, stdout, err = cli("dynamics", "--input", path, "--map", "plugin_gait_to_human", "--calibration", path,
                            "--model", "human48", "--report", out, "--rrd", tmp_path / "standing.rrd")
    assert code == 0, err
    assert "subject from" in stdout and "32.10 kg (the static trial's plates: 60 still frames" in stdout
    assert "on the plates (frames): RightFoot 0-59" in stdout
    for name in ("joint_torques.csv", "joint_powers.csv", "residual.csv", "ground_reactions.csv", "sagittal.png",
                 "residual.png", "report.md", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    from test_rrd import entity_paths, read_rrd

    assert {"/subject/0/dynamics/ground_reaction/RightFoot", "/subject/0/dynamics/residual_force_per_weight",
            "/subject/0/dynamics/ankle_power_per_kg"} <= entity_paths(tmp_path / "standing.rrd")
    arrows = read_rrd(tmp_path / "standing.rrd", "/subject/0/dynamics/ground_reaction/LeftFoot")
    vectors = np.stack(arrows["/subject/0/dynamics/ground_reaction/LeftFoot:Arrows3D:vectors"].iloc[5])
    np.testing.assert_allclose(vectors, [[0.0, 0.0, 0.5]], atol=1e-4)  # half the weight, 1 m per body weight
    torques = np.genfromtxt(out / "joint_torques.csv", delimiter=",", names=True)
    table = read_table(out / "joint_torques.sto")
    assert table.name == "Inverse Dynamics Generalized Forces" and len(table.time) == FRAMES
    assert table.labels == tuple(f"{j}_moment" for j in model.joint_names)
    np.testing.assert_allclose(table.column("jRightAnkle_roty_moment", 1)[:, 0], torques["jRightAnkle_roty"], rtol=1e-8)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mass_kg"] == pytest.approx(SUBJECT.mass) and summary["covered_loaded_frames"] == FRAMES
    assert summary["residual_force_per_weight"]["covered"]["max"] < 5e-3
    assert summary["residual_moment_n_m_per_kg"]["covered"]["max"] < 1e-2
    residual = np.genfromtxt(out / "residual.csv", delimiter=",", names=True)
    assert np.abs(residual["fz_per_weight"]).max() < 5e-3 and residual["plates_carry_every_foot"].all()
    weight, by_name = SUBJECT.mass * GRAVITY / 2, {s.name: s for s in TEMPLATE}
    for side, cop in zip(("Right", "Left"), cops):
        ankle = still.position[0, still.links.index(f"{side}Foot")]
        foot, toe = by_name[f"{side}Foot"], by_name[f"{side}Toe"]
        k = SUBJECT.scale(foot)  # the N-pose's feet lie flat, their frames the world's: levers along x
        levers = {foot: foot.center[0] * k, toe: toe.joint_origin[0] * k + toe.center[0] * SUBJECT.scale(toe)}
        # the foot still: the joint's torque about y cancels the plate force's, -(x_cop - x_ankle) W, and the
        # foot's and toe's weights', (x_c - x_ankle) m g
        expected = (cop[0] - ankle[0]) * weight - sum(s.mass * SUBJECT.mass / TEMPLATE_MASS * GRAVITY * lever
                                                        for s, lever in levers.items())
        assert abs(expected) > 2.0
        np.testing.assert_allclose(torques[f"j{side}Ankle_roty"], expected, atol=2e-3)
    report = (out / "report.md").read_text()
    assert "## Residual" in report and "![sagittal](sagittal.png)" in report and "Plug-in Gait" not in report


def test_a_file_without_plates_is_refused_unless_asked_to_compute_without(pig_session, cli, tmp_path):
    """No force plates: exit 2 naming the file and the way out; with --no-plates it runs and the residual
    carries the whole ground reaction (the weight, give or take the walk's accelerations)."""
    code, _, err = cli("dynamics", "--input", pig_session.walk, "--map", "plugin_gait_to_human", "--calibration",
                       pig_session.static, "--model", "human48", "--report", tmp_path / "r")
    assert code == 2 and "has no force plates" in err and "--no-plates" in err
    code, stdout, err = cli("dynamics", "--input", pig_session.walk, "--map", "plugin_gait_to_human", "--calibration",
                            pig_session.static, "--model", "human48", "--report", tmp_path / "r", "--no-plates", "--quiet")
    assert code == 0 and stdout == "", err
    residual = np.genfromtxt(tmp_path / "r" / "residual.csv", delimiter=",", names=True)
    assert 0.7 < np.median(residual["fz_per_weight"]) < 1.3
    code, _, err = cli("dynamics", "--input", pig_session.walk, "--map", "plugin_gait_to_human", "--model", "human48",
                       "--report", tmp_path / "r", "--no-plates")
    assert code == 2 and "already holds" in err and "--force" in err
    code, _, err = cli("dynamics", "--input", tmp_path / "none.c3d", "--model", "human48", "--report", tmp_path / "s")
    assert code == 2 and "no such file" in err


def test_the_calibration_trial_builds_the_subject_whose_masses_follow_its_bodymass(pig_session, cli, tmp_path):
    """`torchik track --calibration static.c3d` without --subject-from: the static trial states the body
    mass (PROCESSING:Bodymass), so the subject is built from it (32.1 kg, 1.45 m), as --subject-from would;
    it has no plates to weigh the subject on, which the line says."""
    code, stdout, err = cli("track", "--input", pig_session.walk, "--map", "plugin_gait_to_human", "--calibration",
                            pig_session.static, "--model", "human48")
    assert code == 0, err
    assert (f"subject from {pig_session.static}: height 1.450 m (the file), mass 32.1 kg (the file's "
            f"PROCESSING:Bodymass; the plates do not weigh the subject: the file has no force plates)") in stdout


def test_stance_from_gait_events_and_the_frames_the_plates_cover():
    """A foot is on the ground from its "Foot Strike" to its "Foot Off" (and before a first "Foot Off");
    a frame is covered when every foot on the ground stands on a plate."""
    from torchik.pipelines.dynamics import _stance_from_events

    events = [dict(label="Foot Off", context="Right", frame=3), dict(label="Foot Strike", context="Right", frame=7),
              dict(label="Foot Strike", context="Left", frame=5)]
    assert _stance_from_events(events, "Right", 10).tolist() == [True] * 3 + [False] * 4 + [True] * 3
    assert _stance_from_events(events, "Left", 10).tolist() == [False] * 5 + [True] * 5
    assert _stance_from_events([], "Left", 10) is None

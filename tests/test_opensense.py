"""io.opensense and io.opensim_out: OpenSense quaternion tables read (any subset of IMUs, missing
cells, any rate, another world, a gyroscope table beside), calibrated to the human models by
`--map auto`, tracked without a base position, and torchik's outputs for OpenSim (.mot joint
angles, .sto orientation errors) read back, by torchik and, when it is installed, by OpenSim.

The tables are written here from Human48's own kinematics: a subject standing in the N-pose for
half a second (the calibration frames), then moving hips, knees and ankles, IMUs strapped on at
random rotations, the pelvis IMU with its z axis backwards (OpenSense's -z heading axis)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from torchik.io import RecordingError, read
from torchik.io.maps import choose_map, map_recording, reference_configuration
from torchik.io.opensense import read_opensense, write_opensense
from torchik.io.opensim_out import read_motion
from torchik.io.opensim_table import read_table, write_table
from torchik.method import so3
from torchik.method.models import load_model

pytestmark = pytest.mark.usefixtures("one_thread")
LEGS = {"pelvis_imu": "Pelvis", "torso_imu": "T8", "femur_r_imu": "RightUpperLeg", "tibia_r_imu": "RightLowerLeg",
        "calcn_r_imu": "RightFoot", "femur_l_imu": "LeftUpperLeg", "tibia_l_imu": "LeftLowerLeg",
        "calcn_l_imu": "LeftFoot"}
MOVES = {"jRightHip_roty": -0.6, "jRightKnee_roty": 0.9, "jRightAnkle_roty": 0.3, "jLeftHip_roty": -0.4,
         "jLeftKnee_roty": 0.7, "jRightHip_rotx": -0.15}  # rad, within Human48's limits
BACKWARDS_Z = torch.tensor([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)


@pytest.fixture(scope="module")
def human48():
    return load_model("human48")


def imu_walk(model, frames=250, rate=100.0, imus=tuple(LEGS), heading=0.7, seed=0):
    """(time [T], IMU orientations [T,n,3,3] to a z-up world, true joint positions [T,dof]): N-pose
    for 0.5 s, then MOVES at 0.8 Hz."""
    t = np.arange(frames) / rate
    s = reference_configuration(model, "npose").repeat(frames, 1)
    ramp = np.clip((t - 0.5) / 0.5, 0.0, 1.0)
    for joint, amplitude in MOVES.items():
        s[:, model.joint_names.index(joint)] = torch.from_numpy(amplitude * ramp * (1 - np.cos(2 * math.pi * 0.8 * t)) / 2)
    p, _, _ = model.zero_configuration(frames)
    facing = so3.rpy_to_matrix(torch.tensor([0.0, 0.0, heading], dtype=torch.float64)).expand(frames, 3, 3)
    with torch.no_grad():
        R = model(p, facing, s, tuple(LEGS[name] for name in imus), jacobian=False).rotation
    mount = so3.random_rotation((len(imus),), torch.Generator().manual_seed(seed))
    if "pelvis_imu" in imus:
        mount[imus.index("pelvis_imu")] = BACKWARDS_Z
    return t, (R @ mount).numpy(), s.numpy()


def test_a_table_reads_with_its_rate_subset_and_missing_cells(tmp_path, human48):
    t, R, _ = imu_walk(human48, frames=40, rate=60.0, imus=("pelvis_imu", "tibia_l_imu", "calcn_r_imu"))
    path = write_opensense(tmp_path / "walk.sto", t, ("pelvis_imu", "tibia_l_imu", "calcn_r_imu"), R)
    lines = path.read_text().splitlines()
    body = lines.index("endheader") + 2
    cells = lines[body + 5].split("\t")
    cells[2] = ""  # an empty cell
    lines[body + 5] = "\t".join(cells)
    cells = lines[body + 6].split("\t")
    cells[3] = "nan,nan,nan,nan"
    lines[body + 6] = "\t".join(cells)
    cells = lines[body + 7].split("\t")
    cells[2] = "0,0,0,0"  # how some exporters mark a dropped sample
    lines[body + 7] = "\t".join(cells)
    path.write_text("\n".join(lines) + "\n")
    rec = read(path)
    assert rec.links == ("pelvis_imu", "tibia_l_imu", "calcn_r_imu") and rec.base_link == "pelvis_imu"
    assert rec.meta["frame_rate"] == 60.0 and rec.frame_rate == pytest.approx(60.0)
    assert rec.gaps() == {"tibia_l_imu": 2, "calcn_r_imu": 1}
    assert np.isnan(rec.orientation[5, 1]).all() and np.isnan(rec.orientation[6, 2]).all()
    known = ~np.isnan(rec.orientation).any(axis=(-1, -2))
    assert np.allclose(rec.orientation[known], R[known], atol=1e-8)
    # no positions: NaN and said, never zeros
    assert np.isnan(rec.base_position).all() and rec.meta["base_position"] == "not measured"
    assert rec.meta["angular_velocity"] == "derived" and np.isnan(rec.angular_velocity[4:8, 1]).any()


def test_a_gyroscope_table_beside_gives_the_rates_in_the_world(tmp_path, human48):
    t, R, _ = imu_walk(human48, frames=30, imus=("pelvis_imu", "femur_r_imu"))
    write_opensense(tmp_path / "trial_orientations.sto", t, ("pelvis_imu", "femur_r_imu"), R)
    body_rate = np.tile([0.1, -0.2, 0.3], (len(t), 2, 1))  # rad/s, each IMU's axes
    write_table(tmp_path / "trial_angular_velocity.sto", t, ("pelvis_imu", "femur_r_imu"), body_rate,
                dict(DataRate="100", DataType="Vec3"))
    rec = read(tmp_path / "trial_orientations.sto")
    assert rec.meta["angular_velocity"] == "gyroscope"
    assert np.allclose(rec.angular_velocity, (R @ body_rate[..., None])[..., 0], atol=1e-8)


def test_a_declared_world_is_turned_to_z_up(tmp_path, human48):
    t, R, _ = imu_walk(human48, frames=10, imus=("pelvis_imu",))
    y_up = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # z up -> y up: Rx(-pi/2)
    write_opensense(tmp_path / "y_up.sto", t, ("pelvis_imu",), y_up @ R, header={"sensor_to_opensim_rotations": "0 0 0"})
    assert np.allclose(read(tmp_path / "y_up.sto").orientation, R, atol=1e-8)
    assert np.allclose(read_opensense(tmp_path / "y_up.sto", sensor_to_opensim=(0.0, 0.0, 0.0)).orientation, R, atol=1e-8)


@pytest.mark.parametrize("edit, message", [
    (lambda text: text.replace("endheader\n", ""), "no 'endheader'"),
    (lambda text: text.replace("DataType=Quaternion", "DataType=Vec3"), "DataType=Vec3"),
    (lambda text: text.replace("\t1,0,0,0", "\t2,0,0,0", 1), "norm 2.0000"),
    (lambda text: text.replace("\t1,0,0,0", "\t1,0,0", 1), "holds 3 numbers, expected 4"),
    (lambda text: text.replace("\n0.02\t", "\n0.01\t", 1), "times must increase"),
])
def test_a_malformed_table_names_the_file_and_the_line(tmp_path, edit, message):
    path = write_opensense(tmp_path / "bad.sto", np.arange(4) / 100, ("pelvis_imu", "femur_r_imu"),
                           np.tile(np.eye(3), (4, 2, 1, 1)))
    path.write_text(edit(path.read_text()))
    with pytest.raises(RecordingError, match=message) as error:
        read(path)
    assert "bad.sto" in str(error.value)


@pytest.mark.parametrize("imus", [tuple(LEGS), ("pelvis_imu", "femur_r_imu", "tibia_r_imu", "calcn_r_imu")])
def test_auto_map_calibrates_on_the_first_frame_and_recovers_the_joint_angles(tmp_path, human48, imus):
    from torchik.method.settings import TrackerSettings
    from torchik.pipelines.track import track_recording

    t, R, truth = imu_walk(human48, imus=imus, seed=len(imus))
    rec = read(write_opensense(tmp_path / "walk.sto", t, imus, R))
    assert choose_map(rec.links) == "opensense_to_human"
    mapped, _ = map_recording(rec, "auto", human48)
    assert set(mapped.meta["link_map"]["segments"].values()) == set(imus)
    trajectory, report = track_recording(human48, mapped, mapped.links, TrackerSettings(), position_links=(), settle=0.2)
    q = trajectory.joint_positions[:, 0].numpy()
    seen = [joint for joint in MOVES if "Right" in joint or "tibia_l_imu" in imus]  # both of its segments have an IMU
    for joint in seen:
        k = human48.joint_names.index(joint)
        assert np.degrees(np.abs(q[:, k] - truth[:, k]).max()) < 0.5, joint
    assert "position_error_m" not in report  # nothing measured a position


def test_track_reads_the_table_without_a_map_and_writes_opensim_outputs(tmp_path, human48, cli):
    t, R, truth = imu_walk(human48)
    source = write_opensense(tmp_path / "walk.sto", t, tuple(LEGS), R)
    code, out, err = cli("info", source)
    assert code == 0 and "base position: not measured" in out and "derived from the orientations" in out
    code, _, err = cli("convert", source, tmp_path / "walk.npz")
    assert code == 0, err
    outputs = [tmp_path / name for name in ("estimate.mot", "errors.sto", "estimate.npz")]
    code, out, err = cli("track", "--input", source, "--model", "human48", "--report", tmp_path / "report.json",
                         *(x for path in outputs for x in ("--out", path)))
    assert code == 0, err
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["base_position"].startswith("not measured: held at") and "through map 'opensense to human'" in out
    estimate = np.load(tmp_path / "estimate.npz")
    motion = read_motion(tmp_path / "estimate.mot")
    assert motion.header["inDegrees"] == "yes" and motion.joint_names == tuple(human48.joint_names)
    assert np.allclose(motion.joint_positions, estimate["joint_positions"], atol=1e-8)
    assert np.allclose(motion.base[:, :3], estimate["base_position"], atol=1e-8)
    turned = so3.rpy_to_matrix(torch.from_numpy(motion.base[:, 3:])).numpy()
    assert np.allclose(turned, estimate["base_rotation"], atol=1e-8)
    assert np.allclose(motion.base[:, 2], motion.base[0, 2]) and motion.base[0, 2] > 0.5  # held, standing
    legs = [human48.joint_names.index(j) for j in MOVES]
    assert np.degrees(np.abs(motion.joint_positions[:, legs] - truth[:, legs]).max()) < 0.5
    errors = read_table(tmp_path / "errors.sto")
    assert errors.labels == tuple(LEGS) and errors.header_value("DataType") == "double"
    angles = np.stack([errors.column(x, 1)[:, 0] for x in LEGS])  # rad
    assert np.nanmedian(angles) < 1e-4 and np.nanmax(angles) < 1e-2 and not np.isnan(angles).any()
    # the converted recording tracks the same; free: no position target
    code, out, err = cli("track", "--input", tmp_path / "walk.npz", "--model", "human48", "--base-position", "free",
                         "--report", "-", "--quiet")
    assert code == 0, err
    assert json.loads(out)["base_position"].startswith("not measured: free")


def test_an_unknown_or_repeated_output_is_refused_before_any_work(tmp_path, cli):
    code, _, err = cli("track", "--scenario", "walking", "--duration", "0.2", "--out", tmp_path / "x.csv")
    assert code == 2 and "--out" in err and ".mot" in err
    code, _, err = cli("track", "--scenario", "walking", "--duration", "0.2", "--out", tmp_path / "x.mot",
                       "--out", tmp_path / "x.mot")
    assert code == 2 and "given twice as an output" in err and not (tmp_path / "x.mot").exists()


def test_a_scenario_writes_the_opensim_outputs_under_its_link_names(tmp_path, cli):
    code, _, err = cli("track", "--scenario", "walking", "--duration", "0.3", "--model", "human48", "--quiet",
                       "--out", tmp_path / "walk.mot", "--out", tmp_path / "errors.sto")
    assert code == 0, err
    errors = read_table(tmp_path / "errors.sto")
    assert errors.labels[0] == "Pelvis" and len(errors.labels) == 23 and len(errors.time) == 31
    assert "base_position" not in read_motion(tmp_path / "walk.mot").header  # a scenario's base is measured


def test_opensim_reads_the_outputs(tmp_path, human48, cli):
    opensim = pytest.importorskip("opensim")
    t, R, _ = imu_walk(human48, frames=120)
    source = write_opensense(tmp_path / "walk.sto", t, tuple(LEGS), R)
    code, _, err = cli("track", "--input", source, "--model", "human48", "--quiet",
                       "--out", tmp_path / "estimate.mot", "--out", tmp_path / "errors.sto")
    assert code == 0, err
    motion = opensim.TimeSeriesTable(str(tmp_path / "estimate.mot"))
    assert motion.getNumRows() == 120 and motion.getNumColumns() == 6 + human48.n_dof
    assert motion.getTableMetaDataAsString("inDegrees") == "yes"
    errors = opensim.TimeSeriesTable(str(tmp_path / "errors.sto"))
    assert list(errors.getColumnLabels()) == list(LEGS) and errors.getNumRows() == 120
    quaternions = opensim.TimeSeriesTableQuaternion(str(source))  # what OpenSense's IMU IK reads
    assert list(quaternions.getColumnLabels()) == list(LEGS)


def test_diagnose_takes_the_table_with_no_map(tmp_path, human48, cli):
    t, R, _ = imu_walk(human48, frames=200)
    source = write_opensense(tmp_path / "walk.sto", t, tuple(LEGS), R)
    code, out, err = cli("diagnose", source, "--model", "human48", "--report", tmp_path / "diag", "--max-effects", "1",
                         "--no-rrd")
    assert code == 0, err
    assert "base position not measured: held at" in out and (tmp_path / "diag" / "report.md").is_file()


def test_the_heading_axis_and_a_separate_static_table(tmp_path, human48):
    """A pelvis IMU worn with its x axis forwards needs heading_axis "x"; the default (-z, OpenSense's)
    then turns the subject and the flexions come out wrong. A static table calibrates a walk that
    starts moving."""
    from torchik.method.settings import TrackerSettings
    from torchik.pipelines.track import track_recording

    t, R, truth = imu_walk(human48, seed=3)
    x_forward = BACKWARDS_Z.T.numpy()  # the IMU's axes as the pelvis's: x forwards
    R[:, 0] = R[:, 0] @ x_forward
    static = read(write_opensense(tmp_path / "static.sto", t[:10], tuple(LEGS), R[:10]))
    walk = read(write_opensense(tmp_path / "walk.sto", t[60:] - t[60], tuple(LEGS), R[60:]))  # moving from its start
    knee = human48.joint_names.index("jRightKnee_roty")
    error = {}
    for axis in ("x", None):
        mapped, link_map = map_recording(walk, "auto", human48, static=static, heading_axis=axis)
        assert link_map.calibration["heading_axis"] == (axis or "-z")
        trajectory, _ = track_recording(human48, mapped, mapped.links, TrackerSettings(), position_links=(), settle=0.2)
        settled = slice(50, None)  # the walk is moving at its first frame: the first half second converges
        estimate = trajectory.joint_positions[settled, 0, knee].numpy()
        error[axis] = np.degrees(np.abs(estimate - truth[60:][settled, knee]).max())
    assert error["x"] < 0.5 and error[None] > 10, error


def test_the_opensim_model_of_the_comparison_has_human48s_kinematics(tmp_path):
    """experiments/opensense_compare.py's OpenSim model: its bodies turn as torchik's Human48 links
    at a random posture (the comparison measures tools, not models)."""
    opensim = pytest.importorskip("opensim")
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
    import opensense_compare as compare

    from torchik.method.models import human_urdf

    urdf = human_urdf(48)
    compare.build_opensim_model(urdf, tmp_path / "model.osim")
    model = opensim.Model(str(tmp_path / "model.osim"))
    assert model.getCoordinateSet().getSize() == 31  # free base, trunk to T8, hips, knees, ankles
    assert compare.check_opensim_model(model, urdf, seed=1) < 1e-12

"""io.bvh: BVH hierarchies to world rotations (channel order honoured), units told apart, velocities from the data.

Small files written here check one thing each; a walk written through io.bvh_writer on a HumanIK
skeleton (as MotionBuilder or Mixamo export one) checks the reader on a whole body's file, and the
real files of ../shared/data check it again where they are beside the checkout."""

import itertools

import numpy as np
import pytest
import torch
from conftest import shared_file, skip_without_shared
from written import walk

from torchik.io import RecordingError
from torchik.io.bvh import Y_UP_TO_Z_UP, read_bvh
from torchik.method import so3
from torchik.method.models import load_model
from torchik.synthetic.skeletons import humanik_skeleton, write_scenario_bvh


def bvh_text(order=("Z", "X", "Y"), frames=40, dt=0.01, unit=1.0, rate_deg=90.0, arm_angles=(10.0, 20.0, 30.0)):
    """A 1.75-unit-per-cm-tall figure: Hips (6 channels) rising along Y and spinning about Y at rate_deg deg/s,
    a Leg down to the floor, and an Arm with constant Euler angles."""
    rotation = " ".join(f"{a}rotation" for a in order)
    lines = ["HIERARCHY", "ROOT Hips", "{", "  OFFSET 0 0 0", f"  CHANNELS 6 Xposition Yposition Zposition {rotation}",
             "  JOINT Leg", "  {", f"    OFFSET 0 {-85 * unit} 0", f"    CHANNELS 3 {rotation}",
             "    End Site", "    {", f"      OFFSET 0 {-5 * unit} 0", "    }", "  }",
             "  JOINT Spine", "  {", f"    OFFSET 0 {50 * unit} 0", f"    CHANNELS 3 {rotation}",
             "    JOINT Arm", "    {", f"      OFFSET {20 * unit} {40 * unit} 0", f"      CHANNELS 3 {rotation}",
             "      End Site", "      {", f"        OFFSET {60 * unit} 0 0", "      }", "    }", "  }", "}",
             "MOTION", f"Frames: {frames}", f"Frame Time: {dt}"]
    for k in range(frames):
        hips = {"X": 0.0, "Y": rate_deg * k * dt, "Z": 0.0}
        arm = dict(zip(order, arm_angles))
        row = ([0.0, 90 * unit + 10 * unit * k * dt, 0.0] + [hips[a] for a in order] + [0, 0, 0] + [0, 0, 0]
               + [arm[a] for a in order])
        lines.append(" ".join(f"{v:.10f}" for v in row))
    return "\n".join(lines) + "\n"


def euler(order, angles_deg):
    R = torch.eye(3, dtype=torch.float64)
    for axis, angle in zip(order, angles_deg):
        w = torch.zeros(3, dtype=torch.float64)
        w["XYZ".index(axis)] = np.radians(angle)
        R = R @ so3.exp(w)
    return R.numpy()


@pytest.mark.parametrize("order", list(itertools.permutations("XYZ")))
def test_every_channel_order_composes_rotations_in_the_listed_order(tmp_path, order):
    path = tmp_path / "a.bvh"
    path.write_text(bvh_text(order=order))
    rec = read_bvh(path, units="cm")
    hips_at_5 = euler(("Y",), (90.0 * 5 * 0.01,))
    expected_arm = Y_UP_TO_Z_UP @ hips_at_5 @ euler(order, (10.0, 20.0, 30.0))
    assert rec.links == ("Hips", "Leg", "Spine", "Arm")
    assert np.allclose(rec.orientation[5, 3], expected_arm, atol=1e-12)


def test_a_spin_about_the_vertical_gives_the_expected_angular_velocity_and_positions(tmp_path):
    path = tmp_path / "spin.bvh"
    path.write_text(bvh_text())
    rec = read_bvh(path)
    assert rec.meta["units"] == "cm" and rec.base_link == "Hips"
    # 90 deg/s about BVH's Y, which is torchik's z
    assert np.allclose(rec.angular_velocity[:, 0], [0.0, 0.0, np.pi / 2], atol=1e-9)
    assert np.allclose(rec.base_position[:, 2], 0.9 + 0.1 * rec.time)  # rising 10 cm/s, in metres
    assert np.allclose(rec.base_linear_velocity, [0.0, 0.0, 0.1])
    assert np.allclose(rec.time[1] - rec.time[0], 0.01)


@pytest.mark.parametrize("unit,name", [(1.0, "cm"), (0.01, "m"), (1 / 2.54, "inch")])
def test_units_are_told_apart_by_the_skeleton_height(tmp_path, unit, name):
    path = tmp_path / "u.bvh"
    path.write_text(bvh_text(unit=unit))
    rec = read_bvh(path)
    assert rec.meta["units"] == name and np.isclose(rec.base_position[0, 2], 0.9)


def test_undecidable_units_and_malformed_files_are_errors_that_say_why(tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(bvh_text(unit=0.057))  # 10 units tall: no unit makes that a person
    with pytest.raises(RecordingError, match="cannot tell the units.*give units="):
        read_bvh(path)
    assert read_bvh(path, scale=0.175).meta["metres_per_unit"] == 0.175
    path.write_text(bvh_text().replace("CHANNELS 3", "CHANNELS 4", 1))
    with pytest.raises(RecordingError, match=r"tiny.bvh: line \d+: CHANNELS 4 lists 3 channels"):
        read_bvh(path)
    text = bvh_text()
    path.write_text(text[: len(text) // 2])
    with pytest.raises(RecordingError, match="40 frames announced"):
        read_bvh(path)


@pytest.fixture(scope="module")
def humanik_walk(tmp_path_factory):
    """human66's walk (2 s at 60 Hz) written as a Mixamo-named HumanIK BVH: (model, recording, path)."""
    model = load_model("human66")
    recording = walk(model, seconds=2.0, rate=60.0)
    path = write_scenario_bvh(tmp_path_factory.mktemp("bvh") / "walk.bvh", recording, model, "mixamorig:")
    return model, recording, path


def test_a_written_humanik_walk_reads_as_the_walk_it_was_written_from(humanik_walk):
    """A whole body's file (22 joints, 6 decimals of centimetres and degrees, 60 Hz): the joints in the
    hierarchy's order, centimetres told from the skeleton's height, each joint's frame its link's (in the
    file's Y-up axes) and each leg joint at its link's origin, to the file's decimals; the walk's 4 km/h."""
    model, truth, path = humanik_walk
    rec = read_bvh(path)
    skeleton = humanik_skeleton(model, "mixamorig:")
    assert sorted(rec.links) == sorted(j.name for j in skeleton) and len(rec.links) == 22
    assert rec.links[:3] == ("mixamorig:Hips", "mixamorig:Spine", "mixamorig:Spine1") and rec.base_link == rec.links[0]
    skeleton = sorted(skeleton, key=lambda j: rec.links.index(j.name))  # depth first, as the file lists them
    assert rec.meta["units"] == "cm" and len(rec.time) == len(truth.time)
    assert abs(rec.frame_rate - 60.0) < 1e-5  # the frame time, 1/60 s, written to 9 decimals
    assert rec.meta["clock"] == "shared" and rec.meta["angular_velocity"] == "derived" and not rec.meta["missing_frames"]
    rows = [truth.links.index(j.link) for j in skeleton]
    R = truth.orientation[:, rows] @ Y_UP_TO_Z_UP  # the link's frame, its axes named as the file's
    angle = so3.log(torch.from_numpy(np.swapaxes(rec.orientation, -1, -2) @ R)).norm(dim=-1)
    assert float(angle.max()) < 1e-6
    # the legs hang from the hips bone by bone as in the model; above the Spine the model's L3, which
    # HumanIK has no joint for, bends between joints: those positions are the skeleton's, not the model's
    legs = [i for i, j in enumerate(skeleton) if j.name.endswith(("Hips", ":Spine", "UpLeg", "Leg", "Foot", "ToeBase"))]
    assert len(legs) == 10
    np.testing.assert_allclose(rec.position[:, legs], truth.position[:, [rows[i] for i in legs]], atol=1e-7, rtol=0)
    np.testing.assert_allclose(rec.base_position, truth.base_position, atol=1e-8, rtol=0)
    speed = np.linalg.norm(rec.base_linear_velocity[:, :2], axis=-1)
    assert abs(np.median(speed) - 4.0 / 3.6) < 0.01
    # central differences of the orientations: the links' angular velocities to O(dt^2) at 60 Hz
    assert np.abs(rec.angular_velocity - truth.angular_velocity[:, rows])[1:-1].max() < 0.02


def test_a_dropout_in_a_written_walk_marks_the_joint_and_those_it_carries(humanik_walk, tmp_path):
    """A NaN in the right forearm's channels at frame 30: the forearm and the hand are missing there and
    only there; every other joint, and the frames around, as read from the whole file."""
    _, _, path = humanik_walk
    lines = path.read_text().splitlines()
    motion = lines.index("MOTION") + 3  # MOTION, Frames:, Frame Time:
    whole = read_bvh(path)
    channel = 6 + 3 * (whole.links.index("mixamorig:RightForeArm") - 1)  # the root's 6, then 3 a joint
    row = lines[motion + 30].split()
    row[channel + 1] = "nan"
    lines[motion + 30] = " ".join(row)
    (tmp_path / "gap.bvh").write_text("\n".join(lines) + "\n")
    rec = read_bvh(tmp_path / "gap.bvh")
    missing = np.isnan(rec.orientation).any(axis=(-1, -2))
    assert rec.meta["missing_frames"] == {"mixamorig:RightForeArm": 1, "mixamorig:RightHand": 1}
    assert missing.nonzero()[0].tolist() == [30, 30]
    known = ~missing
    np.testing.assert_array_equal(rec.orientation[known], whole.orientation[known])


def test_a_cut_written_walk_is_refused_with_the_frames_it_announced(humanik_walk, tmp_path):
    _, truth, path = humanik_walk
    text = path.read_text()
    (tmp_path / "cut.bvh").write_text(text[: int(len(text) * 0.9)])
    with pytest.raises(RecordingError, match=f"{len(truth.time)} frames announced"):
        read_bvh(tmp_path / "cut.bvh")


@skip_without_shared
@pytest.mark.parametrize("name", ["bandai_walk_normal_001.bvh", "bandai_run_normal_001.bvh", "cmu_131_01.bvh"])
def test_the_real_bvh_files_convert(name):
    rec = read_bvh(shared_file(f"bvh/{name}"))
    R = rec.orientation
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-9
    assert 0.6 < np.median(rec.base_position[:, 2]) < 1.1  # the hips about a metre above the floor
    speed = np.median(np.linalg.norm(rec.base_linear_velocity[:, :2], axis=-1))
    assert (1.0 < speed < 1.3) if "walk" in name else (3.0 < speed < 4.2) if "run" in name else speed < 1.5


def test_values_that_are_not_numbers_are_errors_naming_the_place(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text(bvh_text().replace("OFFSET 0 0 0", "OFFSET 0 x 0", 1))
    with pytest.raises(RecordingError, match=r"bad.bvh: line 4: OFFSET values must be numbers"):
        read_bvh(path)
    lines = bvh_text().splitlines()
    lines[-3] = lines[-3].replace("0.0000000000", "nope", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"line \d+ \(frame 37\): 'nope' is not a number \(Hips Xposition\)"):
        read_bvh(path)
    path.write_text(bvh_text().replace("Frames: 40", "Frames: 0"))
    with pytest.raises(RecordingError, match="announces 0 frames"):
        read_bvh(path)


@pytest.mark.parametrize("value", ["nan", "NaN", "inf", "-inf"])
def test_a_non_finite_motion_value_marks_the_joints_it_moves_missing_in_that_frame(tmp_path, value):
    lines = bvh_text().splitlines()
    spine_x = 6 + 3 + 1  # Hips' 6 channels, Leg's 3, then Spine's order Z X Y: its X rotation
    row = lines[-20].split()  # frame 20 of 40
    row[spine_x] = value
    lines[-20] = " ".join(row)
    (tmp_path / "gap.bvh").write_text("\n".join(lines) + "\n")
    rec = read_bvh(tmp_path / "gap.bvh")
    missing = np.isnan(rec.orientation).any(axis=(-1, -2))  # [T,n]
    assert missing.nonzero()[0].tolist() == [20, 20] and [rec.links[i] for i in missing.nonzero()[1]] == ["Spine", "Arm"]
    assert rec.meta["missing_frames"] == {"Spine": 1, "Arm": 1}
    assert np.isfinite(rec.base_position).all() and not np.isinf(rec.angular_velocity).any()
    known = rec.orientation[~missing]
    assert np.abs(np.swapaxes(known, -1, -2) @ known - np.eye(3)).max() < 1e-12

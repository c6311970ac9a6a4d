"""io.mvnx: Xsens MVNX files to recordings, with quaternions w,x,y,z segment-to-global and global angular velocity.

Small files written here check one thing each; an MVN export written from a scenario (conftest's
`mvn_export`, through io.mvnx_writer: segments and their points, sensors, joints, calibration frames,
every per-frame field) checks the reader on a file laid out as a real one is, and the real export of
../shared/data checks it again where it is beside the checkout."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
from conftest import shared_file, skip_without_shared
from written import XSENS_SENSORS, sensor_placements, xsens_skeleton

from torchik.io import RecordingError, angular_velocity_from_orientations, read_mvnx
from torchik.io.mvnx_writer import matrix_to_quaternion, write_mvnx
from torchik.io.subjects import subject_from_recording
from torchik.method import so3
from torchik.method.models.human import TEMPLATE


def mvnx_text(frames: int, rate: float = 100.0, spin: float = 1.0, segments=("Pelvis", "Head"), version: str = "4",
              broken_frame: int | None = None) -> str:
    """An MVNX file whose Head turns about the world z axis at `spin` rad/s; Pelvis at rest, moving along x."""
    head = [f'<segment label="{name}" id="{i + 1}"><points/></segment>' for i, name in enumerate(segments)]
    body = []
    calib = " ".join("1 0 0 0" for _ in segments)
    body.append(f'<frame time="0" tc="" ms="0" type="tpose"><orientation>{calib}</orientation>'
                f'<position>{" ".join("0 0 1" for _ in segments)}</position></frame>')
    for k in range(frames):
        t = k / rate
        q = f"{math.cos(spin * t / 2)} 0 0 {math.sin(spin * t / 2)}"
        orientation = " ".join(["1 0 0 0", q] + ["1 0 0 0"] * (len(segments) - 2))
        omega = " ".join(["0 0 0", f"0 0 {spin}"] + ["0 0 0"] * (len(segments) - 2))
        position = " ".join([f"{0.5 * t} 0 1"] + ["0 0 1.6"] * (len(segments) - 1))
        velocity = " ".join(["0.5 0 0"] + ["0 0 0"] * (len(segments) - 1))
        if k == broken_frame:
            orientation = "1 0 0"
        body.append(f'<frame time="{round(1000 * t)}" index="{k}" tc="" ms="0" type="normal">'
                    f"<orientation>{orientation}</orientation><position>{position}</position>"
                    f"<velocity>{velocity}</velocity><angularVelocity>{omega}</angularVelocity></frame>")
    return (f'<?xml version="1.0"?>\n<mvnx xmlns="http://www.xsens.com/mvn/mvnx" version="{version}">\n'
            f'<subject label="s" frameRate="{rate}" segmentCount="{len(segments)}"><segments>{"".join(head)}</segments>'
            f'<frames segmentCount="{len(segments)}">' + "\n".join(body) + "</frames></subject></mvnx>\n")


@pytest.mark.parametrize("version", ["3", "4"])
def test_a_known_spin_gives_the_expected_matrices_and_angular_velocity(tmp_path, version):
    path = tmp_path / "spin.mvnx"
    path.write_text(mvnx_text(50, spin=2.0, version=version))
    rec = read_mvnx(path)
    assert rec.links == ("Pelvis", "Head") and rec.base_link == "Pelvis"
    assert np.allclose(rec.time, np.arange(50) / 100.0)
    t = rec.time[10]
    c, s = math.cos(2.0 * t), math.sin(2.0 * t)
    assert np.allclose(rec.orientation[10, 1], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    assert np.allclose(rec.angular_velocity[:, 1], [0, 0, 2.0])
    assert np.allclose(rec.base_position[10], [0.05, 0, 1]) and np.allclose(rec.base_linear_velocity, [0.5, 0, 0])
    assert np.allclose(angular_velocity_from_orientations(rec.orientation, rec.time)[:, 1], [0, 0, 2.0], atol=1e-9)
    assert "tpose" in rec.meta["calibration"] and rec.meta["frame_rate"] == 100.0


def test_malformed_files_name_the_file_and_the_place(tmp_path):
    path = tmp_path / "cut.mvnx"
    path.write_text(mvnx_text(5)[:-200])
    with pytest.raises(RecordingError, match=r"cut.mvnx: malformed XML at line \d+"):
        read_mvnx(path)
    path = tmp_path / "short.mvnx"
    path.write_text(mvnx_text(5, broken_frame=3))
    with pytest.raises(RecordingError, match="short.mvnx: frame 3: orientation holds 3 numbers, expected 8"):
        read_mvnx(path)
    with pytest.raises(RecordingError, match="no such file"):
        read_mvnx(tmp_path / "none.mvnx")
    path = tmp_path / "nobase.mvnx"
    path.write_text(mvnx_text(5, segments=("Hips", "Head")))
    with pytest.raises(RecordingError, match=r"base link 'Pelvis' is not a segment; segments: \['Hips', 'Head'\]"):
        read_mvnx(path)


def angle(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The angles (rad) of the rotations between A and B [...,3,3]."""
    return so3.log(torch.from_numpy(np.swapaxes(A, -1, -2) @ B)).norm(dim=-1).numpy()


def test_a_written_mvn_export_reads_as_the_scenario_it_was_written_from(mvn_export):
    """The 23 segments in the file's order (not the 17 sensors, not the joints' or points' labels), each
    orientation the scenario's to the file's 6 decimals (2e-6 rad), angular velocities, positions and the
    base's velocity to 1e-6, times from the frame indices at the file's 60 Hz, exactly."""
    rec, truth = read_mvnx(mvn_export.path), mvn_export.walking
    assert rec.links == truth.links and len(rec.links) == 23 and rec.base_link == "Pelvis"
    assert rec.meta["mvnx_version"] == "4" and rec.meta["frame_rate"] == 60.0
    assert rec.meta["subject"]["segmentCount"] == "23" and rec.meta["subject"]["configuration"] == "FullBody"
    np.testing.assert_array_equal(rec.time, np.arange(len(truth.time)) / 60.0)
    assert angle(rec.orientation, truth.orientation).max() < 2e-6
    np.testing.assert_allclose(rec.angular_velocity, truth.angular_velocity, atol=1e-6, rtol=0)
    np.testing.assert_allclose(rec.position, truth.position, atol=1e-6, rtol=0)
    np.testing.assert_allclose(rec.base_position, truth.base_position, atol=1e-6, rtol=0)
    np.testing.assert_allclose(rec.base_linear_velocity, truth.base_linear_velocity, atol=1e-6, rtol=0)
    # MVN's convention checked as on the real file: the global angular velocity is the orientations' derivative
    error = np.linalg.norm(angular_velocity_from_orientations(rec.orientation, rec.time) - rec.angular_velocity, axis=-1)
    assert np.median(error[1:-1]) < 0.01


def test_a_written_mvn_exports_calibration_frames_and_points_are_the_models(mvn_export):
    """The identity, tpose and tpose-isb frames land in meta["calibration"] (T-pose: every segment frame
    the world's, the segments at the model's link origins); the segments' points hold every joint the
    subject's model needs, so the subject built from the file places every joint where the model has it."""
    rec, model = read_mvnx(mvn_export.path), mvn_export.model
    calibration = rec.meta["calibration"]
    assert set(calibration) == {"identity", "tpose", "tpose-isb"}
    tpose = np.array(calibration["tpose"]["orientation"]).reshape(-1, 4)
    np.testing.assert_allclose(tpose, np.tile([1.0, 0, 0, 0], (23, 1)), atol=1e-12)
    isb = np.array(calibration["tpose-isb"]["orientation"]).reshape(-1, 4)
    assert np.allclose(np.abs(isb[rec.links.index("RightUpperArm")]), [math.sqrt(0.5), math.sqrt(0.5), 0, 0], atol=1e-6)
    p0, R0, s0 = model.zero_configuration(1)
    origins = model(p0, R0, s0, rec.links, jacobian=False).position[0].numpy()
    position = np.array(calibration["tpose"]["position"]).reshape(-1, 3)
    np.testing.assert_allclose(position - position[0], origins - origins[0], atol=1e-6, rtol=0)
    built = subject_from_recording(rec)
    assert sorted(built.subject.joint_origins) == sorted(s.name for s in TEMPLATE[1:])
    for segment in TEMPLATE[1:]:
        np.testing.assert_allclose(built.subject.joint_origins[segment.name], segment.joint_origin, atol=1e-6,
                                   err_msg=segment.name)


def test_the_written_sensor_orientations_are_the_segments_times_their_placements(mvn_export):
    """io.mvnx_writer: each of the 17 sensors' orientation, frame by frame, is its segment's times the
    rotation it was strapped on at, to the file's 6 decimals; the sensors are declared, the reader
    leaves them out of the segments."""
    root = ET.parse(mvn_export.path).getroot()
    ns = {"m": "http://www.xsens.com/mvn/mvnx"}
    sensors = [e.get("label") for e in root.iterfind("m:subject/m:sensors/m:sensor", ns)]
    assert tuple(sensors) == XSENS_SENSORS
    frames = [f for f in root.iterfind("m:subject/m:frames/m:frame", ns) if f.get("type") == "normal"]
    q = np.array([f.find("m:sensorOrientation", ns).text.split() for f in frames], dtype=np.float64).reshape(
        len(frames), len(sensors), 4)
    R = so3.quaternion_to_matrix(torch.from_numpy(q / np.linalg.norm(q, axis=-1, keepdims=True))).numpy()
    truth = mvn_export.walking
    placement = np.stack([s.placement for s in sensor_placements()])
    expected = truth.orientation[:, [truth.links.index(s) for s in sensors]] @ placement
    assert angle(R, expected).max() < 2e-6


def test_the_writer_refuses_what_an_mvnx_file_cannot_hold(mvn_export, tmp_path):
    truth = mvn_export.walking
    points, joints = xsens_skeleton(mvn_export.model)
    with pytest.raises(RecordingError, match="gives every segment's position"):
        write_mvnx(tmp_path / "a.mvnx", type(truth)(**{**vars(truth), "position": None}), points)
    gap = truth.orientation.copy()
    gap[5, 3] = np.nan
    with pytest.raises(RecordingError, match="no gaps"):
        write_mvnx(tmp_path / "a.mvnx", type(truth)(**{**vars(truth), "orientation": gap}), points)
    with pytest.raises(RecordingError, match=r"lacks: \['Tail'\]"):
        write_mvnx(tmp_path / "a.mvnx", truth, {**points, "Tail": {}})
    assert not (tmp_path / "a.mvnx").exists()


def test_quaternions_of_rotations_round_trip_with_a_non_negative_w():
    R = so3.random_rotation((500,), torch.Generator().manual_seed(0)).numpy()
    R[0] = np.diag([1.0, -1.0, -1.0])  # half turns: w = 0
    R[1] = np.diag([-1.0, -1.0, 1.0])
    q = matrix_to_quaternion(R)
    assert (q[:, 0] >= 0).all() and np.allclose(np.linalg.norm(q, axis=-1), 1.0)
    np.testing.assert_allclose(so3.quaternion_to_matrix(torch.from_numpy(q)).numpy(), R, atol=1e-12)


@skip_without_shared
def test_the_real_mvnx_file_angular_velocity_agrees_with_its_orientations():
    rec = read_mvnx(shared_file("mvnx/test_mocap.mvnx"))
    assert rec.orientation.shape == (112, 23, 3, 3) and rec.meta["mvnx_version"] == "4"
    assert set(rec.meta["calibration"]) == {"identity", "tpose", "tpose-isb"}
    error = np.linalg.norm(angular_velocity_from_orientations(rec.orientation, rec.time) - rec.angular_velocity, axis=-1)
    assert np.nanmedian(error) < 0.2

"""io.mvnx: Xsens MVNX files to recordings, with quaternions w,x,y,z segment-to-global and global angular velocity."""

import math
from pathlib import Path

import numpy as np
import pytest

from torchik.io import RecordingError, angular_velocity_from_orientations, read_mvnx

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "mvnx"


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


@pytest.mark.skipif(not (SHARED / "test_mocap.mvnx").is_file(), reason="../shared/data absent")
def test_the_real_mvnx_file_angular_velocity_agrees_with_its_orientations():
    rec = read_mvnx(SHARED / "test_mocap.mvnx")
    assert rec.orientation.shape == (112, 23, 3, 3) and rec.meta["mvnx_version"] == "4"
    assert set(rec.meta["calibration"]) == {"identity", "tpose", "tpose-isb"}
    error = np.linalg.norm(angular_velocity_from_orientations(rec.orientation, rec.time) - rec.angular_velocity, axis=-1)
    assert np.nanmedian(error) < 0.2

"""io.c3d: Plug-in Gait bone triads to segment rotations; occlusions marked, never used as data."""

from pathlib import Path

import numpy as np
import pytest

from torchik.io import RecordingError
from torchik.io.c3d import read_c3d

ezc3d = pytest.importorskip("ezc3d")
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"


def write_c3d(path, frames=60, rate=100.0, spin=0.5, units="mm", occlude=(), zero=(), segments=("PEL", "LFE")):
    """Each segment's triad turns about the lab z axis at `spin` rad/s; PELO walks along x at 1 m/s (in mm)."""
    labels, columns = [], []
    t = np.arange(frames) / rate
    c, s = np.cos(spin * t), np.sin(spin * t)
    axes = {"A": np.stack((c, s, 0 * t), -1), "L": np.stack((-s, c, 0 * t), -1),
            "P": np.stack((0 * t, 0 * t, 1 + 0 * t), -1)}
    for k, segment in enumerate(segments):
        origin = np.stack((1000.0 * t, 200.0 * k + 0 * t, 900.0 + 0 * t), -1)
        for axis in "OALP":
            labels.append(segment + axis)
            columns.append(origin if axis == "O" else origin + 92.0 * axes[axis])
    points = np.ones((4, len(labels), frames))
    points[:3] = np.stack(columns, 1).transpose(2, 1, 0)
    for label, frame_range in occlude:
        points[:3, labels.index(label), frame_range] = np.nan
    for label, frame_range in zero:
        points[:3, labels.index(label), frame_range] = 0.0
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c3d.add_parameter("POINT", "UNITS", [units])
    c3d["data"]["points"] = points
    c3d.write(str(path))
    return t


def test_a_known_spin_gives_the_expected_rotation_and_angular_velocity(tmp_path):
    t = write_c3d(tmp_path / "spin.c3d")
    rec = read_c3d(tmp_path / "spin.c3d")
    assert rec.links == ("PEL", "LFE") and rec.base_link == "PEL"
    c, s = np.cos(0.5 * t[20]), np.sin(0.5 * t[20])
    # C3D stores float32 coordinates: about 1e-4 mm at 1 m, so 1e-6 rad on a 92 mm axis, 1e-4 rad/s differentiated
    assert np.allclose(rec.orientation[20, 0], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-6)
    assert np.allclose(rec.angular_velocity, [0, 0, 0.5], atol=1e-4)
    assert np.allclose(rec.base_position[:, 0], t, atol=1e-9) and np.allclose(rec.base_position[:, 2], 0.9)
    assert np.allclose(rec.base_linear_velocity, [1.0, 0, 0], atol=1e-9)


def test_occluded_and_zeroed_points_are_marked_missing_not_filled(tmp_path):
    write_c3d(tmp_path / "gap.c3d", occlude=[("LFEA", slice(10, 13))], zero=[("PELO", slice(30, 32))])
    rec = read_c3d(tmp_path / "gap.c3d")
    missing = np.isnan(rec.orientation).any(axis=(-1, -2))
    assert missing[:, 1].nonzero()[0].tolist() == [10, 11, 12]
    assert missing[:, 0].nonzero()[0].tolist() == [30, 31]
    assert np.isnan(rec.base_position[30:32]).all() and np.isfinite(rec.base_position[:30]).all()
    assert np.isnan(rec.angular_velocity[9:14, 1]).all() and np.isfinite(rec.angular_velocity[:9, 1]).all()
    assert rec.gaps() == {"PEL": 2, "LFE": 3} and rec.meta["missing_frames"] == {"PEL": 2, "LFE": 3}


def test_bad_files_and_missing_segments_are_errors_that_say_what_is_wrong(tmp_path):
    write_c3d(tmp_path / "nopel.c3d", segments=("LFE", "RFE"))
    with pytest.raises(RecordingError, match=r"no Plug-in Gait triad for 'PEL'.*segments found: \['LFE', 'RFE'\]"):
        read_c3d(tmp_path / "nopel.c3d")
    (tmp_path / "junk.c3d").write_bytes(b"\x00" * 100)
    with pytest.raises(RecordingError, match="junk.c3d: not a readable C3D file"):
        read_c3d(tmp_path / "junk.c3d")
    write_c3d(tmp_path / "inches.c3d", units="in")
    with pytest.raises(RecordingError, match="unknown units 'in'; give units="):
        read_c3d(tmp_path / "inches.c3d")
    assert np.isclose(read_c3d(tmp_path / "inches.c3d", units="m").base_position[0, 2], 900.0)


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data absent")
@pytest.mark.parametrize("name", ["HC002D02.c3d", "HC002D06.c3d", "HC002D25.c3d", "HC030A01.c3d", "HC030A05.c3d",
                                  "HC030A22.c3d"])
def test_every_real_c3d_converts_with_orthonormal_rotations(name):
    rec = read_c3d(SHARED / name)
    assert len(rec.links) == 19
    R = rec.orientation[~np.isnan(rec.orientation).any(axis=(-1, -2))]
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-6
    assert rec.meta["triad_max_deviation"] < 1e-5  # the file's own triads are nearly orthonormal


@pytest.mark.parametrize("kept", [0.5, 0.99])
def test_a_cut_file_is_refused_from_the_header_frame_count(tmp_path, kept):
    whole = (SHARED / "HC002D02.c3d").read_bytes()
    (tmp_path / "cut.c3d").write_bytes(whole[:int(len(whole) * kept)])
    with pytest.raises(RecordingError, match=r"cut.c3d: truncated: the header declares 51 frames, the file holds \d+"):
        read_c3d(tmp_path / "cut.c3d")

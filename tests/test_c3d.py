"""io.c3d: Plug-in Gait bone triads to segment rotations; occlusions marked, never used as data.

Small files written here check one thing each; a Plug-in Gait session written from a scenario
(conftest's `pig_session`: a static trial and a walk, as a Vicon session has them) checks the
reader on a file laid out as a real one is, and the real files of ../shared/data check it again
where they are beside the checkout."""

import numpy as np
import pytest
import torch
from conftest import shared_file
from written import MARKERS, PIG_LINK, pig_frames, plug_in_gait_c3d

from torchik.io import RecordingError, apply_map, calibrate, load_map
from torchik.io.c3d import PLUG_IN_GAIT, PROXIMAL_JOINT, read_c3d
from torchik.io.targets import recording_targets
from torchik.method.tracker import DynamicalIK

ezc3d = pytest.importorskip("ezc3d")


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


@pytest.mark.parametrize("name", ["HC002D02.c3d", "HC002D06.c3d", "HC002D25.c3d", "HC030A01.c3d", "HC030A05.c3d",
                                  "HC030A22.c3d"])
def test_every_real_c3d_converts_with_orthonormal_rotations(name):
    rec = read_c3d(shared_file(f"c3d/{name}"))
    assert len(rec.links) == 19
    R = rec.orientation[~np.isnan(rec.orientation).any(axis=(-1, -2))]
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-6
    assert rec.meta["triad_max_deviation"] < 1e-5  # the file's own triads are nearly orthonormal


def test_a_written_plug_in_gait_walk_reads_as_the_segments_it_was_written_from(pig_session):
    """A Vicon-like file (270 labels, LABELS2 past the 255th; skin markers, unlabelled trajectories, angles, never-measured
    kinetics among the segments' points; millimetres): the 19 segments in Plug-in Gait's order, each
    rotation the one written to float32's rounding (1e-4 mm on a 92 mm axis: a few 1e-6), each
    segment's position its proximal joint centre, the base's the pelvis origin, in metres."""
    walk, truth = read_c3d(pig_session.walk), pig_session.walking
    assert walk.links == PLUG_IN_GAIT and len(walk.time) == len(truth.time) == 201
    assert len(ezc3d.c3d(str(pig_session.walk))["parameters"]["POINT"]["LABELS2"]["value"]) > 0
    assert walk.meta["units"] == dict(position="mm", converted_to="m") and walk.meta["frame_rate"] == 100.0
    assert walk.meta["clock"] == "shared" and walk.meta["angular_velocity"] == "derived"
    assert not walk.meta["missing_frames"] and walk.meta["triad_max_deviation"] < 1e-5
    written = pig_frames(pig_session.model, truth)
    for i, segment in enumerate(walk.links):
        np.testing.assert_allclose(walk.orientation[:, i], written[segment], atol=1e-5, rtol=0, err_msg=segment)
    links = {"RFE": "RightUpperLeg", "RTI": "RightLowerLeg", "LHU": "LeftUpperArm", "RRA": "RightForeArm"}
    for segment, link in links.items():  # the hip, knee, shoulder and elbow centres (PROXIMAL_JOINT)
        assert segment in PROXIMAL_JOINT
        np.testing.assert_allclose(walk.position[:, walk.links.index(segment)], truth.position[:, truth.links.index(link)],
                                   atol=1e-6, rtol=0, err_msg=segment)
    np.testing.assert_allclose(walk.base_position, truth.base_position, atol=1e-6, rtol=0)
    # the angular velocities are the orientations' central differences: a frame fixed on a link turns
    # with it, so they are the link's, to the differences' O(dt^2) at 100 Hz
    rows = [truth.links.index(link) for link in map(PIG_LINK.get, walk.links)]
    assert np.abs(walk.angular_velocity - truth.angular_velocity[:, rows])[1:-1].max() < 5e-3  # rad/s


def test_the_static_trial_calibrates_plug_in_gaits_frames_onto_the_models_links_exactly(pig_session):
    """Calibrated on the static trial (the subject in the N-pose facing +x, as the map asks), the map
    takes every Plug-in Gait frame of the walk onto the model link it was written from: the walk's own
    link orientations to float32's rounding, whatever the markers' misalignments (the pelvis tilted 0.2 rad)."""
    model, truth = pig_session.model, pig_session.walking
    calibrated = calibrate(load_map("plugin_gait_to_human"), read_c3d(pig_session.static), model, frame=0)
    mapped = apply_map(read_c3d(pig_session.walk), calibrated)
    rows = [truth.links.index(link) for link in mapped.links]
    assert mapped.links[0] == "Pelvis" and len(mapped.links) == 19
    np.testing.assert_allclose(mapped.orientation, truth.orientation[:, rows], atol=1e-5, rtol=0)


def test_occluded_markers_become_missing_targets_and_the_rest_is_tracked(pig_session, tmp_path):
    """Vicon lost the left knee marker for frames 40-44 (written with residual -1, as Vicon does) and an
    exporter zeroed the right hand's origin for frames 80-81: the segments those points define (thigh
    and shank; hand) are missing there and only there, so are their targets once mapped, their angular
    velocities are missing next to the gaps; the tracker goes through with every other link on its
    target."""
    model, truth = pig_session.model, pig_session.walking
    path = plug_in_gait_c3d(tmp_path / "gaps.c3d", model, truth, pig_session.subject,
                            occluded={"LKNE": slice(40, 45)}, zeroed={"RHNO": slice(80, 82)})
    assert MARKERS["LKNE"][2] == ("LFE", "LTI")
    walk = read_c3d(path)
    assert walk.meta["missing_frames"] == {"LFE": 5, "LTI": 5, "RHN": 2} and walk.gaps() == walk.meta["missing_frames"]
    calibrated = calibrate(load_map("plugin_gait_to_human"), read_c3d(pig_session.static), model, frame=0)
    mapped = apply_map(walk, calibrated)
    targets = recording_targets(mapped, mapped.links)
    missing = ~torch.isfinite(targets.rotation[:, 0]).flatten(-2).all(-1)  # [T,L]
    expected = {"LeftUpperLeg": list(range(40, 45)), "LeftLowerLeg": list(range(40, 45)), "RightHand": [80, 81]}
    assert {link: missing[:, i].nonzero()[:, 0].tolist() for i, link in enumerate(mapped.links)
            if missing[:, i].any()} == expected
    w = targets.angular_velocity[:, 0, mapped.links.index("LeftUpperLeg")]
    assert bool(torch.isnan(w[39:46]).all()) and bool(torch.isfinite(w[:39]).all() and torch.isfinite(w[46:]).all())
    trajectory = DynamicalIK(model, mapped.links, dt=0.01).run(targets)
    assert bool(torch.isfinite(trajectory.joint_positions).all())
    mnte = trajectory.diagnostics["mnte"][:, 0]  # over the links seen in each frame
    assert bool(torch.isfinite(mnte).all()) and float(mnte[30:].max()) < 1e-3 and float(mnte[150:].max()) < 1e-6


@pytest.mark.parametrize("kept", [0.5, 0.99])
def test_a_cut_written_static_trial_is_refused_from_the_header_frame_count(pig_session, tmp_path, kept):
    whole = pig_session.static.read_bytes()
    (tmp_path / "cut.c3d").write_bytes(whole[:int(len(whole) * kept)])
    with pytest.raises(RecordingError, match=r"cut.c3d: truncated: the header declares 51 frames, the file holds \d+"):
        read_c3d(tmp_path / "cut.c3d")


@pytest.mark.parametrize("kept", [0.5, 0.99])
def test_a_cut_file_is_refused_from_the_header_frame_count(tmp_path, kept):
    whole = shared_file("c3d/HC002D02.c3d").read_bytes()
    (tmp_path / "cut.c3d").write_bytes(whole[:int(len(whole) * kept)])
    with pytest.raises(RecordingError, match=r"cut.c3d: truncated: the header declares 51 frames, the file holds \d+"):
        read_c3d(tmp_path / "cut.c3d")

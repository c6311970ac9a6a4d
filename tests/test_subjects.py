"""io.subjects: a subject's model from a recording places the MVNX file's joints exactly (checked
through pinocchio on the written URDF, not torchik's kinematics) and takes BVH segment lengths from
the bone offsets; a converted .npz builds the same subject; track, models take it from the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_file

from torchik.cli import main
from torchik.io import load_recording, read, save_recording
from torchik.io.maps import load_map
from torchik.io.subjects import LENGTH_CHILD, subject_from_recording
from torchik.method.models.human import TEMPLATE


def mvnx_file(request, source: str):
    """The MVN export the tests write (conftest's mvn_export), or the real one of ../shared/data."""
    return request.getfixturevalue("mvn_export").path if source == "written" else shared_file("mvnx/test_mocap.mvnx")


def plug_in_gait(request, source: str):
    """(static trial, walk): the Plug-in Gait session the tests write (conftest's pig_session: a 1.45 m,
    32.1 kg subject, as HC002 is) or the real HC002 one of ../shared/data."""
    if source == "written":
        session = request.getfixturevalue("pig_session")
        return session.static, session.walk
    return shared_file("c3d/HC002D02.c3d"), shared_file("c3d/HC002D25.c3d")


@pytest.fixture(autouse=True)
def _no_allocator_tuning(monkeypatch):
    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)


@pytest.mark.parametrize("source", ["written", "shared"])
@pytest.mark.parametrize("dof", [48, 66])
def test_the_mvnx_model_places_every_joint_at_the_files_pos_b_points(tmp_path, dof, source, request):
    pinocchio = pytest.importorskip("pinocchio")
    path = mvnx_file(request, source)
    assert main(["models", "--from", str(path), "--model", f"human{dof}", "--write", str(tmp_path)]) == 0
    model = pinocchio.buildModelFromUrdf(str(tmp_path / f"human{dof}.urdf"))
    points = read(path).meta["skeleton"]["points"]
    checked = 0
    for segment in TEMPLATE[1:]:
        label = next(lb for lb in points[segment.name] if lb.startswith("j") and lb in points[segment.parent])
        # the first revolute joint of the segment's spherical joint: placed in its parent link's frame
        # (the dummy links between the revolute joints add no offset)
        first = next(j for j in range(1, model.njoints) if model.names[j].startswith(f"{segment.joint}_rot"))
        assert model.names[model.parents[first]].startswith(f"{by_name(segment.parent).joint}_rot") or \
            segment.parent == "Pelvis"
        np.testing.assert_allclose(model.jointPlacements[first].translation, points[segment.parent][label],
                                   atol=1e-6, rtol=0, err_msg=f"{segment.name}: {label}")
        checked += 1
    assert checked == 22  # every joint of the 23-segment body
    report = json.loads((tmp_path / "subject.json").read_text())
    assert report["mass_from"].startswith("the template") and len(report["joint_origins_from_file"]) == 22


def by_name(name: str):
    return next(s for s in TEMPLATE if s.name == name)


@pytest.fixture(scope="module")
def humanik_bvh(tmp_path_factory, mvn_export):
    """human66's walk (conftest's mvn_export) written as a HumanIK BVH."""
    from torchik.synthetic.skeletons import write_scenario_bvh

    return write_scenario_bvh(tmp_path_factory.mktemp("bvh") / "walk.bvh", mvn_export.walking, mvn_export.model)


@pytest.mark.parametrize("file,map_name", [("written HumanIK", "humanik_to_human"), ("cmu_131_01.bvh", "cmu_to_human"),
                                           ("bandai_walk_normal_001.bvh", "bandai_to_human")])
def test_bvh_segment_lengths_are_the_bone_offsets_norms(file, map_name, request):
    path = request.getfixturevalue("humanik_bvh") if file.startswith("written") else shared_file(f"bvh/{file}")
    recording = read(path)
    built = subject_from_recording(recording)
    assert built.link_map == load_map(map_name).name
    skeleton, scale = recording.meta["skeleton"], recording.meta["metres_per_unit"]
    sources = {e.link: e.segment for e in load_map(map_name).entries}
    raw = {}  # the file's OFFSET lines, in its own units
    text = path.read_text().split()
    for i, word in enumerate(text[:-4]):
        if word in ("ROOT", "JOINT") and text[i + 3] == "OFFSET":
            raw[text[i + 1]] = np.array([float(v) for v in text[i + 4:i + 7]])
    checked = 0
    for segment, length in built.from_file.items():
        child = sources[LENGTH_CHILD[segment]]
        if skeleton["parents"][child] == sources[segment]:  # one bone: the length is its offset's norm
            assert abs(length - np.linalg.norm(raw[child]) * scale) < 1e-6, segment
            checked += 1
    assert checked >= 8  # the limbs at least
    assert {"RightUpperLeg", "RightLowerLeg", "LeftUpperArm", "LeftForeArm"} <= set(built.from_file)


@pytest.mark.parametrize("source", ["written", "shared"])
def test_a_plug_in_gait_static_trial_places_the_hips_at_its_hip_joint_centres(source, request):
    """The hips sit across the pelvis as far apart as the file's hip joint centres (LHJC, RHJC): the written
    subject's own (the template's, scaled), HC002's 92.6 mm, narrower than the template's 141 mm at 1.45 m."""
    recording = read(plug_in_gait(request, source)[0])
    built = subject_from_recording(recording)
    width = recording.meta["skeleton"]["hip_width"]
    right, left = (built.subject.joint_origins[f"{side}UpperLeg"] for side in ("Right", "Left"))
    assert right[1] == pytest.approx(-width / 2) and left[1] == pytest.approx(width / 2)
    template = 2 * abs(by_name("RightUpperLeg").joint_origin[1]) * 1.45 / 1.68
    if source == "written":
        assert width == pytest.approx(template, abs=1e-6)
    else:
        assert width == pytest.approx(0.0926, abs=5e-4) and width < template - 0.04


@pytest.mark.parametrize("source", ["written", "shared"])
def test_a_converted_npz_builds_the_same_subject(tmp_path, source, request):
    recording = read(plug_in_gait(request, source)[0])
    save_recording(recording, tmp_path / "static.npz")
    a, b = subject_from_recording(recording), subject_from_recording(load_recording(tmp_path / "static.npz"))
    assert a.subject == b.subject and a.from_file == b.from_file
    assert a.height_from == "the file" and a.subject.height == 1.45
    # the written trial has no plates: its Bodymass; HC002's static trial's plates weigh the child at 31.07 kg
    assert a.subject.mass == pytest.approx(32.1 if source == "written" else 31.07, abs=5e-3)
    assert {"RightUpperLeg", "RightLowerLeg", "RightFoot", "RightUpperArm", "RightForeArm"} <= set(a.from_file)


@pytest.mark.parametrize("source", ["written", "shared"])
def test_track_with_the_subject_from_the_static_trial(tmp_path, capsys, source, request):
    static, walk = plug_in_gait(request, source)
    assert main(["track", "--input", str(walk), "--calibration", str(static), "--subject-from", str(static),
                 "--model", "human48"]) == 0
    out = capsys.readouterr().out
    assert "subject from" in out and "height 1.450 m (the file)" in out and "through map 'plug-in gait to human'" in out


@pytest.mark.parametrize("source", ["written", "shared"])
def test_a_cohort_manifests_subject_from_column_builds_the_measured_subject(tmp_path, source, request):
    from torchik.pipelines.cohort.manifest import ManifestError, read_manifest

    static, walk = plug_in_gait(request, source)
    (tmp_path / "m.csv").write_text(f"trial,subject,recording,model,subject_from\n"
                                    f"t1,s1,{walk},human48,{static}\n")
    (spec,) = read_manifest(tmp_path / "m.csv")
    assert spec.subject_model == subject_from_recording(read(static)).subject
    (tmp_path / "bad.csv").write_text(f"trial,subject,recording,model,subject_from\n"
                                      f"t1,s1,{walk},icub,{static}\n")
    with pytest.raises(ManifestError, match="generate a human model"):
        read_manifest(tmp_path / "bad.csv")

"""models.human: the generated subject 1 is the published human-gazebo model; other subjects scale."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
from conftest import REPO, reference_urdf

from torchik.errors import ModelError
from torchik.method.models import SEGMENTS, HumanSubject, human_urdf, load_model


def joints_of(text: str) -> dict:
    root = ET.fromstring(text)
    out = {}
    for j in root.findall("joint"):
        origin, axis, limit = j.find("origin"), j.find("axis"), j.find("limit")
        out[j.get("name")] = dict(
            type=j.get("type"), parent=j.find("parent").get("link"), child=j.find("child").get("link"),
            xyz=np.array(origin.get("xyz").split(), dtype=float),
            axis=None if axis is None or j.get("type") == "fixed" else np.array(axis.get("xyz").split(), dtype=float),
            limit=None if limit is None else (float(limit.get("lower")), float(limit.get("upper"))),
        )
    return out


def links_of(text: str) -> dict:
    root = ET.fromstring(text)
    out = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        mass = float(inertial.find("mass").get("value")) if inertial is not None else 0.0
        out[link.get("name")] = mass
    return out


@pytest.mark.parametrize("dof", [66, 48])
def test_subject_1_matches_the_published_model(dof):
    reference = reference_urdf(f"humanSubject01_{dof}dof.urdf").read_text()
    ours, theirs = joints_of(human_urdf(dof)), joints_of(reference)
    assert list(ours) == list(theirs)  # same joints, same order
    for name, ref in theirs.items():
        mine = ours[name]
        assert (mine["type"], mine["parent"], mine["child"]) == (ref["type"], ref["parent"], ref["child"]), name
        assert np.abs(mine["xyz"] - ref["xyz"]).max() <= 1e-3, name  # placements within 1 mm
        if ref["type"] == "revolute":
            assert np.array_equal(mine["axis"], ref["axis"]), name  # axes exact
            assert mine["limit"] == ref["limit"], name  # limits exact
    # segment masses as published (the hand-COM frames carry 1e-5 kg there, nothing here)
    ref_mass, our_mass = links_of(reference), links_of(human_urdf(dof))
    for segment in SEGMENTS:
        assert our_mass[segment] == pytest.approx(ref_mass[segment], rel=1e-4)


def test_zero_configuration_is_a_t_pose_with_frames_aligned_to_the_world():
    model = load_model("human66")
    out = model(*model.zero_configuration(1), SEGMENTS, jacobian=False)
    assert torch.allclose(out.rotation, torch.eye(3, dtype=torch.float64).expand_as(out.rotation))
    pos = dict(zip(SEGMENTS, out.position[0]))
    assert pos["Head"][2] > pos["T8"][2] > pos["Pelvis"][2] > pos["RightLowerLeg"][2] > pos["RightFoot"][2]
    assert pos["LeftHand"][1] > 0.6 and pos["RightHand"][1] < -0.6  # arms stretched along y: a T
    assert abs(pos["LeftHand"][2] - pos["LeftShoulder"][2]) < 1e-12


def test_other_subjects_scale_with_height_and_mass():
    tall = HumanSubject(height=1.68 * 1.1, mass=80.0)
    base, scaled = joints_of(human_urdf(66)), joints_of(human_urdf(66, tall))
    for name in base:
        assert np.allclose(scaled[name]["xyz"], 1.1 * base[name]["xyz"], atol=1e-8)
    masses = links_of(human_urdf(66, tall))
    assert sum(masses.values()) == pytest.approx(80.0, rel=1e-6)


def test_a_measured_segment_length_moves_only_what_that_segment_carries():
    subject = HumanSubject(segment_lengths={"RightUpperArm": 0.30})
    joints, base = joints_of(human_urdf(48, subject)), joints_of(human_urdf(48))
    assert joints["jRightElbow_roty"]["xyz"][1] == pytest.approx(-0.30)
    assert joints["jLeftElbow_roty"]["xyz"][1] == pytest.approx(base["jLeftElbow_roty"]["xyz"][1])
    assert np.allclose(joints["jRightShoulder_rotx"]["xyz"], base["jRightShoulder_rotx"]["xyz"])


def test_inertias_are_those_of_uniform_shapes():
    root = ET.fromstring(human_urdf(66))
    link = next(l for l in root.findall("link") if l.get("name") == "RightUpperArm")
    mass = float(link.find("inertial/mass").get("value"))
    inertia = link.find("inertial/inertia")
    cyl = link.find("visual/geometry/cylinder")
    length, r = float(cyl.get("length")), float(cyl.get("radius"))
    assert float(inertia.get("iyy")) == pytest.approx(mass * r * r / 2, rel=1e-6)  # arm cylinders lie along y
    assert float(inertia.get("ixx")) == pytest.approx(mass * (3 * r * r + length * length) / 12, rel=1e-6)


def test_bad_subjects_are_refused_with_the_reason():
    with pytest.raises(ModelError, match="give metres"):
        HumanSubject(height=168)
    with pytest.raises(ModelError, match="unknown segments"):
        HumanSubject(segment_lengths={"Tail": 0.3})
    with pytest.raises(ModelError, match="66 or 48"):
        human_urdf(50)


@pytest.mark.parametrize("dof", [66, 48])
def test_the_urdfs_in_models_are_the_generators_output(dof):
    """models/human*.urdf are written by `torchik models --write models/`; they must not go stale."""
    assert (REPO / "models" / f"human{dof}.urdf").read_text() == human_urdf(dof)

"""The static-pose family (torchik/pipelines/diagnosis/posture.py).

Recording: a Human48 walk (5 s at 50 Hz, the scenarios' sensor noise) whose sensors were calibrated
on a static frame in which the right arm stood abducted and turned (shoulder x -30 deg, y +20 deg:
36 deg in all) away from the map's N-pose. The offsets are made as io/maps.calibrate makes them,
R_static^T R_reference, with the static frame's link orientations from the model's forward
kinematics in the posture held: independent of the family's linearised model.

Properties:
- a static pose's correction undoes its injection (the identity on every link, its own and others);
- on that recording the first effect the loop adds is the static pose below the right upper arm,
  plausible, and no misalignment of a single arm link is kept; afterwards the arm's MNTE against
  the recording calibrated in the true posture is within 2x the clean recording's (its noise);
- a recording that no map calibrated has no static-pose candidate;
- a joint limit that the reference pose holds a joint at (an N-pose's shoulders) moved is refused
  as the sign of a static pose, not taken as a limit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from torchik.io.maps import reference_configuration
from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis.analysis import analyse
from torchik.pipelines.diagnosis.candidates import candidates
from torchik.pipelines.diagnosis.effect import halves, replace
from torchik.pipelines.diagnosis.joints import JointLimit
from torchik.pipelines.diagnosis.loop import diagnose, errors
from torchik.pipelines.diagnosis.posture import StaticPose, held_by_reference, reference_rotations
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
ARM = ("RightUpperArm", "RightForeArm", "RightHand")
HELD = (("jRightShoulder_rotx", -30.0), ("jRightShoulder_roty", 20.0))  # deg from the N-pose
CALIBRATED = dict(link_map=dict(calibration=dict(reference_pose="npose")))


def _rotations(model, s) -> np.ndarray:
    p0, R0, _ = model.zero_configuration(1)
    return model(p0, R0, s, list(LINKS), jacobian=False).rotation[0].numpy()


@pytest.fixture(scope="module")
def walks(one_thread):
    """(model, URDF, the walk calibrated in the true posture, the same calibrated in the posture held)."""
    model = load_model("human48")
    walk = scenario("walking", model, LINKS, 5.0, 50.0, seed=2, orientation_noise=0.005, gyro_noise=0.02)
    reference = reference_configuration(model, "npose")
    held = reference.clone()
    for name, deg in HELD:
        held[0, model.joint_names.index(name)] += math.radians(deg)
    offsets = _rotations(model, held).transpose(0, 2, 1) @ _rotations(model, reference)  # [L,3,3]
    truth = replace(walk, meta=dict(walk.meta, **CALIBRATED))
    return model, human_urdf(48), truth, replace(truth, orientation=walk.orientation @ offsets[None])


def test_a_correction_undoes_the_injection(walks):
    model, _, truth, _ = walks
    K = reference_rotations(model, "npose", ARM).numpy()
    pose = StaticPose("static_pose", ARM[0], dict(pose="npose", links=list(ARM), reference=K.tolist(),
                                                  rotation_vector=[0.3, -0.2, 0.5]))
    moved = pose.inject(truth)
    assert not np.allclose(moved.orientation[:, LINKS.index(ARM[1])], truth.orientation[:, LINKS.index(ARM[1])])
    np.testing.assert_allclose(pose.correct(moved).orientation, truth.orientation, atol=1e-12)


def test_the_loop_finds_the_posture_held(walks):
    model, urdf, truth, held = walks
    log: list[str] = []
    d, clean = diagnose(model, urdf, [held, truth], LINKS, max_effects=3, log=log.append)
    first = d.effects[0]
    assert (first.kind, first.target) == ("static_pose", ARM[0]) and not first.implausible()
    assert not [e for e in d.effects if e.kind == "misalignment" and e.target in ARM]
    arm = [LINKS.index(n) for n in ARM]
    analysis, b = d.last
    against_truth = errors(analyse(d.model, [truth], LINKS, gain=20.0), 0)
    floor = errors(*clean.last)
    assert against_truth.mnte[arm].mean() <= 2.0 * floor.mnte[arm].mean()
    assert errors(analysis, b).mnte[arm].mean() <= 2.0 * floor.mnte[arm].mean()


def test_no_candidate_without_a_calibrated_pose(walks):
    model, urdf, truth, _ = walks
    plain = replace(truth, meta={})
    analysis = analyse(model, [plain], LINKS)
    train, test = halves(analysis.time)
    assert analysis.poses == (None,)
    assert not candidates(analysis, 0, train, test, urdf, ("static_pose",))


def test_a_limit_the_reference_pose_holds_is_no_finding(walks):
    """A shoulder beyond the limit an N-pose holds it at says the static pose; a limit the pose does
    not hold (the hip's extension), or the same limit under a T-pose, may be a finding."""
    model = walks[0]
    shoulder = JointLimit("joint_limit", "jRightShoulder_rotx", dict(side="upper", limit=math.pi / 2, needed=2.0))
    hip = JointLimit("joint_limit", "jRightHip_roty", dict(side="upper", limit=math.radians(15.0), needed=0.4))
    assert "static pose" in held_by_reference(shoulder, model, "npose")
    assert held_by_reference(shoulder, model, "tpose") == "" and held_by_reference(hip, model, "npose") == ""
    assert held_by_reference(shoulder, model, None) == ""

"""What a kept effect changes in what a report shows (contribution.py, issue 35 item 3).

Properties:
- a sensor turned by 6 deg about an axis its joint cannot follow changes the tracked result by degrees,
  the same turn of 0.3 deg by a small fraction of one: the measure grows with the effect;
- an effect above its family's floor that changes nothing a report shows (a limit widened where the
  walk never goes) is moved to the negligible ones, saying why, and the subject rebuilt without it;
  the effect beside it that does change the result stays, its contribution recorded.
"""

from __future__ import annotations

import math

import pytest
import torch
from conftest import human48_walk

from torchik.method.kinematics import KinematicModel
from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis import contribution, elimination
from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
from torchik.pipelines.diagnosis.joints import JointLimit
from torchik.pipelines.diagnosis.placement import Misalignment
from torchik.pipelines.diagnosis.result import Step, errors
from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

LINKS = TRACKED_LINKS["human48"]
DEG = math.pi / 180


def _turned(degrees: float) -> Misalignment:
    """The LeftLowerLeg sensor turned about the shank's forward axis, which the knee has no axis for."""
    return Misalignment("misalignment", "LeftLowerLeg", dict(rotation_vector=[degrees * DEG, 0.0, 0.0]))


@pytest.mark.parametrize("degrees, low, high", [(6.0, 2.0, 8.0), (0.3, 0.0, 0.4)])
def test_a_turned_sensor_changes_the_tracked_result_by_about_its_size(one_thread, degrees, low, high):
    model, urdf, walk = human48_walk(4.0, seed=3, orientation_noise=0.001)
    turned = _turned(degrees)
    measured = turned.inject(walk)
    with_, without = Subject(turned.correct(measured), urdf, model), Subject(measured, urdf, model)
    analyse_subjects([with_, without], LINKS, DEFAULT_GAIN, False, 50)
    size, where = contribution.change(contribution.of_analysis(*with_.current), contribution.of_analysis(*without.current))
    assert low <= size <= high, (size, where)


def test_an_effect_that_changes_nothing_a_report_shows_is_negligible_and_taken_out(one_thread):
    model, urdf, walk = human48_walk(4.0, seed=3, orientation_noise=0.001)
    turned = _turned(6.0)
    joint = "jRightShoulder_rotx"  # the walk's arms swing forward and back, far from this one's upper limit
    upper = float(model.upper[model.joint_names.index(joint)])
    widened = JointLimit("joint_limit", joint, dict(side="upper", limit=upper, needed=upper + 3 * DEG))
    assert widened.below_floor(0.02) == ""  # 3 deg: above the limits' floor
    measured = turned.inject(walk)
    recording, augmented = elimination.without(measured, urdf, [turned, widened], None)
    s = Subject(recording, augmented, KinematicModel.from_urdf(augmented, name="human48+"), source=(measured, urdf))
    analyse_subjects([s], LINKS, DEFAULT_GAIN, False, 50)
    s.steps = [Step(turned, errors(*s.current), errors(*s.current)), Step(widened, errors(*s.current),
                                                                            errors(*s.current))]
    said: list[str] = []
    contribution.drop_invisible([s], LINKS, DEFAULT_GAIN, False, 50, said.append)
    assert s.effects == [turned] and turned.params["contribution_deg"] >= contribution.VISIBLE
    assert s.negligible[("joint_limit", joint)] is widened
    assert "nothing a report shows changes" in widened.notes and widened.params["contribution_deg"] < 0.1
    assert s.urdf == urdf and said  # rebuilt without it, and said so
    # its analysis is the one tracked without the effect already: as tracking the rebuilt subject again
    again = Subject(s.recording, s.urdf, s.model)
    analyse_subjects([again], LINKS, DEFAULT_GAIN, False, 50)
    (reused, b), (fresh, c) = s.current, again.current
    assert torch.allclose(reused.s[:, b], fresh.s[:, c], atol=1e-7)
    assert torch.allclose(reused.r[:, b], fresh.r[:, c], atol=1e-7)

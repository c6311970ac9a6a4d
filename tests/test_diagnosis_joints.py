"""A missing axis' fit (torchik/pipelines/diagnosis/joints.py) under orientation noise.

Property: a knee's missing ab/adduction swinging 7 deg at 0.6 Hz under 1 deg of white orientation
noise on every sensor (the study's 10402) is significant and above the noise, its angle fitted
smoothed to a body's bandwidth (fitted sample by sample and penalised per sample, a 300-sample test
half cost more than the swing explains); on the same walk without it, no missing axis is both.

Recording: Human48 walking, 12 s at 50 Hz, through the truth model with the axis added
(synthetic.with_missing_dof), gyro noise 0.01 rad/s.
"""

from __future__ import annotations

import math

import pytest

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis import joints
from torchik.pipelines.diagnosis.analysis import analyse, noise_floor
from torchik.pipelines.diagnosis.effect import SIGNIFICANT, halves
from torchik.pipelines.diagnosis.synthetic import recording_of, with_missing_dof

LINKS = TRACKED_LINKS["human48"]
NOISE, GYRO_NOISE, SECONDS = math.radians(1.0), 0.01, 12.0


@pytest.fixture(scope="module")
def knee():
    """(Human48, its URDF, the walk with a missing right-knee axis, the same walk without it)."""
    model, urdf = load_model("human48"), human_urdf(48)
    effect = joints.MissingDof("missing_dof", "jRightKnee", dict(axis=[1.0, 0.0, 0.0], parent="RightUpperLeg",
                                                                 child="RightLowerLeg", first_joint="jRightKnee_roty"))
    truth, motion = with_missing_dof(urdf, effect, math.radians(7.0), 0.6, 0.3, duration=SECONDS, seed=2)
    swinging = recording_of(truth, motion, LINKS, 2, NOISE, GYRO_NOISE)
    truth0, still = with_missing_dof(urdf, effect, 0.0, 0.6, 0.3, duration=SECONDS, seed=2)
    return model, urdf, swinging, recording_of(truth0, still, LINKS, 2, NOISE, GYRO_NOISE)


def _kept(model, urdf, recording) -> list[joints.MissingDof]:
    """The missing-axis candidates that are significant and above the noise."""
    analysis = analyse(model, [recording], LINKS)
    train, test = halves(analysis.time)
    noise = noise_floor(analysis, 0).axis_rms
    return [c for c in joints.fit(analysis, 0, train, test, urdf) if c.kind == "missing_dof" and c.fit is not None
            and not c.significant(SIGNIFICANT, noise)]


def test_a_knee_axis_swinging_seven_degrees_under_a_degree_of_noise_is_found(knee):
    model, urdf, swinging, _ = knee
    assert [c.target for c in _kept(model, urdf, swinging)] == ["jRightKnee"]


def test_without_it_no_missing_axis_is_kept(knee):
    model, urdf, _, still = knee
    assert _kept(model, urdf, still) == []

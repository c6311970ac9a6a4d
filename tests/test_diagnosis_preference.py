"""The loop's preferences where the data score two causes alike and the physics does not (preference.py).

A missing axis whose angle is mostly an offset comes after a misalignment of a sensor on either side
of it, unless a heading drift of that sensor scores above the misalignment.

A gyro reading its rates with a scale error, on a pelvis that turns steadily through a curved walk,
simulated by experiments/sensor_physics.py (pinocchio's kinematics; the rate stream converted with the
wrong sensitivity while the filter integrates the calibrated gyro). The scale error reads kappa times the
pelvis' mean turning rate more than the truth: a constant in the sensor frame, which the bias family,
fitted on its integral, scores far above the scale error seen in the swings.

Property: the diagnosis names the scale error within 0.5 % of the simulated one, and no bias of that
gyro. (With the bias taken first, as before preference.scaled_first, the elimination later drops it,
below its floor, but the scale error fitted beside it comes out 0.6 % short: 4.29 against 4.89 %.)
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis import preference
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.effect import Score
from torchik.pipelines.diagnosis.gyro import GyroBias
from torchik.pipelines.diagnosis.joints import MissingDof
from torchik.pipelines.diagnosis.loop import diagnose
from torchik.pipelines.diagnosis.placement import Misalignment

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import sensor_physics  # noqa: E402

LINKS = TRACKED_LINKS["human48"]
SEED = 7117  # gyro_scale on the Pelvis, +4.9 %, in a walk turning at 6.8 deg/s (tuning: 0-199, 600-609; study: 1000+)


def test_a_scale_error_on_a_steadily_turning_segment_is_not_named_a_bias(one_thread):
    pytest.importorskip("pinocchio")
    rec, injected, info = sensor_physics.generate(SEED, "gyro_scale", 1, LINKS, duration=8.0, rate=100.0, reference=None)
    assert injected[0].targets == ["Pelvis"] and abs(info["motion"]["turn_deg_s"]) > 5.0
    d, = diagnose(load_model("human48"), human_urdf(48), [rec], LINKS, max_effects=4)
    on_pelvis = {e.kind: e for e in d.effects if e.target == "Pelvis"}
    assert "gyro_bias" not in on_pelvis, [e.summary() for e in d.effects]
    assert abs(100 * on_pelvis["gyro_scale"].params["scale_error"] - float(injected[0].sizes[0])) < 0.5


def _scored(effect, score: float):
    effect.fit = Score(score, 0.5, 1.0, 1.0, 100)
    return effect


def test_a_mostly_offset_axis_comes_after_a_misalignment_of_its_sides_unless_their_drift_leads():
    """An axis between L3 and T12 whose angle is mostly an offset, scoring best: T12's misalignment
    comes before it (alone: T12's gyro bias stays where it scored), another link's candidate keeps its
    place. With L3's heading drift scoring above L3's misalignment (a drift's mean is an offset too),
    nothing moves: the drift goes first in its own place."""
    axis = _scored(MissingDof("missing_dof", "jL1T12", dict(parent="L3", child="T12", angle_mean=0.1,
                                                                angle_rms=0.02)), 7000.0)
    elsewhere = _scored(HeadingDrift("heading_drift", "RightToe", dict(rate=0.02)), 6000.0)
    bias = _scored(GyroBias("gyro_bias", "T12", dict(bias=[0.0, 0.0, 0.01])), 300.0)
    turned = _scored(Misalignment("misalignment", "T12", dict(rotation_vector=[0.0, 0.0, 0.1])), 144.0)
    out = preference.offset_first(None, [axis, elsewhere, bias, turned])
    assert out == [turned, axis, elsewhere, bias]
    assert "mostly an offset" in turned.notes and "mostly an offset" not in bias.notes

    drift = _scored(HeadingDrift("heading_drift", "L3", dict(rate=0.03)), 263.0)
    below = _scored(Misalignment("misalignment", "L3", dict(rotation_vector=[0.0, 0.0, 0.1])), 144.0)
    passing = [axis, elsewhere, drift, below]
    assert preference.offset_first(None, passing) == passing


def test_a_drift_of_a_sensor_whose_gyro_bias_is_kept_comes_before_an_axis_near_it(one_thread):
    """A walk (seed 7150), its right elbow's missing axis scoring above the right upper arm's heading
    drift, the drift's own gyro silent (the bias fitted first took its word): the axis stays first while
    no bias of that gyro is kept, and the drift goes before it once one is (a filter that corrects tilt
    and not heading integrates the bias' vertical part)."""
    pytest.importorskip("pinocchio")
    from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
    from torchik.pipelines.diagnosis.result import Step, errors
    from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

    rec, *_ = sensor_physics.generate(7150, "clean", None, LINKS, duration=6.0, rate=100.0, reference=None)
    urdf = human_urdf(48)
    s = Subject(rec, urdf, load_model("human48"), source=(rec, urdf))
    analyse_subjects([s], LINKS, DEFAULT_GAIN, False)
    axis = _scored(s.candidates(("missing_dof",), target="jRightElbow")[0], 907.0)
    drift = _scored(s.candidates(("heading_drift",), target="RightUpperArm")[0], 754.0)
    drift.params.update(gyro_shares=False, own_gyro_score=0.0)
    assert preference.gyro_first(s, [axis, drift], 10.0) == [axis, drift]
    bias = GyroBias("gyro_bias", "RightUpperArm", dict(bias=[0.02, 0.0, 0.02]))
    s.steps.append(Step(bias, errors(*s.current), errors(*s.current)))
    assert preference.gyro_first(s, [axis, drift], 10.0) == [drift, axis]
    assert "gyro's bias is kept" in drift.notes

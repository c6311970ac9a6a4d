"""Effects on one link told from the same effect on its neighbour (issue 18, item 2).

A delay or a heading drift of one sensor shows in the joints between it and its neighbours, which
the neighbour's opposite effect explains as well. What tells them apart is physical:

- a sensor can be late on the others, never early: a late LeftUpperLeg sensor is named there, not
  as a LeftLowerLeg sensor early by the same time (placement.SensorDelay.implausible);
- a drifting heading turns the sensor's own gyro with it, and its orientations: a drift of the
  RightUpperArm sensor (whose turn the shoulder's ball joint takes up) is named as that, not as a
  gyro bias of the arm or a drift of a neighbour (placement.fit: the gyro's integral in the drift's
  score; gyro._bias: a constant turn about the vertical is a drift, not a bias);
- a drift whose turn over the recording stays within the noise is kept only where its own gyro
  shows it (HeadingDrift.significant): the common part of a chain's headings is not a finding;
  nor is a misalignment within one sample's noise beside a kept effect (elimination.hanger_on),
  what that effect, corrected a few per cent off, leaves on the links next to it.

Recordings: Human48 walking, 8 s at 50 Hz, the scenarios' sensor noise; the effect injected with
Effect.inject.
"""

from __future__ import annotations

import math

import pytest
from conftest import human48_walk

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.effect import SIGNIFICANT, Score
from torchik.pipelines.diagnosis.elimination import hanger_on
from torchik.pipelines.diagnosis.loop import diagnose
from torchik.pipelines.diagnosis.placement import Misalignment, SensorDelay

LINKS = TRACKED_LINKS["human48"]


@pytest.fixture(scope="module")
def walk(one_thread):
    return human48_walk(8.0, seed=4, orientation_noise=0.01)


def _kept(walk, effect):
    model, urdf, recording = walk
    d, = diagnose(model, urdf, [effect.inject(recording)], LINKS, max_effects=3)
    return d


def test_a_late_sensor_is_named_on_itself_not_on_its_neighbour_early(walk):
    d = _kept(walk, SensorDelay("sensor_delay", "LeftUpperLeg", dict(delay=0.06)))
    delays = {e.target: e.params["delay"] for e in d.effects if e.kind == "sensor_delay"}
    assert set(delays) == {"LeftUpperLeg"}, d.effects
    assert delays["LeftUpperLeg"] == pytest.approx(0.06, abs=0.01)


def test_a_heading_drift_is_named_on_the_sensor_whose_gyro_turns(walk):
    d = _kept(walk, HeadingDrift("heading_drift", "RightUpperArm", dict(rate=math.radians(1.5), t0=0.0)))
    assert {(e.kind, e.target) for e in d.effects} == {("heading_drift", "RightUpperArm")}, d.effects


def test_a_drift_whose_turn_is_within_the_noise_is_kept_only_on_its_gyros_word():
    """HeadingDrift.significant: with a held-out score well above the threshold, a drift whose turn
    over 12 s stays within 3 times the noise (0.15 deg/s, 1 deg noise) is not kept unless its own
    gyro shows it; a drift of 0.6 deg/s is."""
    noise = math.radians(1.0)
    fit = Score(50.0, 0.5, 1.0, 1.0, 600, chunks=(6.0,) * 8, predicted=(6.0,) * 8)  # a steady gain: calibrated 50

    def drift(deg_per_s, own):
        return HeadingDrift("heading_drift", "L5", dict(rate=math.radians(deg_per_s), t0=0.0, t1=12.0,
                                                        own_gyro_score=own), fit=fit, n_params=1)

    assert "within 3 times the noise" in drift(0.15, 2.0).significant(SIGNIFICANT, noise)
    assert drift(0.15, 40.0).significant(SIGNIFICANT, noise) == ""
    assert drift(0.6, 2.0).significant(SIGNIFICANT, noise) == ""


def test_a_misalignment_within_one_samples_noise_beside_a_kept_effect_is_its_hanger_on():
    """elimination.hanger_on: under 0.8 deg of noise, a hand sensor turned by 1.2 deg beside a kept
    drift of the forearm's is what the drift leaves; turned by 2.3 deg, or with nothing kept beside
    it (the foot's, or before the drift is kept), it is a candidate like any other."""
    model, urdf, noise = load_model("human48"), human_urdf(48), math.radians(0.8)
    drift = HeadingDrift("heading_drift", "LeftForeArm", dict(rate=math.radians(-2.8), t0=0.0))

    def turned(link, deg):
        return Misalignment("misalignment", link, dict(rotation_vector=[0.0, math.radians(deg), 0.0]))

    assert "beside the kept heading_drift at LeftForeArm" in hanger_on(turned("LeftHand", 1.2), [drift], model, urdf,
                                                                       LINKS, noise)
    assert hanger_on(turned("LeftHand", 2.3), [drift], model, urdf, LINKS, noise) == ""
    assert hanger_on(turned("RightFoot", 1.2), [drift], model, urdf, LINKS, noise) == ""
    assert hanger_on(turned("LeftHand", 1.2), [], model, urdf, LINKS, noise) == ""

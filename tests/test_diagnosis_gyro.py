"""The gyro family's bias fit (torchik/pipelines/diagnosis/gyro.py) against differentiated orientation noise.

Property: a gyro bias of 1 deg/s, some 20 times below the noise that differentiating 0.5 deg of
orientation noise puts on each sample of e, is found significant on held-out time and within 20 %
(the fit sees it through the orientations' change over long spans, where that noise telescopes);
on the same recording without it no link's bias is significant. A bias along the vertical axis
of a sensor that stays upright stays a bias, though its gyro alone cannot tell it from a heading
drift; a drift, which also turns the orientations, is refused as a bias.

Recording: Human48 walking, 12 s at 50 Hz (the study's length), orientation noise 0.5 deg, gyro noise
0.01 rad/s; the bias on the pelvis, injected with Effect.inject.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis import gyro
from torchik.pipelines.diagnosis.analysis import analyse
from torchik.pipelines.diagnosis.candidates import candidates
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.effect import SIGNIFICANT, halves
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
BIAS = math.radians(1.0)  # rad/s


@pytest.fixture(scope="module")
def walk(one_thread):
    model = load_model("human48")
    return model, scenario("walking", model, LINKS, 12.0, 50.0, seed=3, orientation_noise=math.radians(0.5),
                           gyro_noise=0.01)


def _biases(model, recording):
    """{link: its GyroBias candidate} fitted on the recording."""
    analysis = analyse(model, [recording], LINKS)
    train, test = halves(analysis.time)
    return {c.target: c for c in gyro.fit(analysis, 0, train, test) if c.kind == "gyro_bias"}


@pytest.mark.parametrize("axis", ([1.0, 0.0, 0.0], [0.0, 0.6, 0.8]))
def test_a_bias_of_one_degree_per_second_is_found_within_a_fifth(walk, axis):
    model, recording = walk
    truth = BIAS * np.asarray(axis)
    found = _biases(model, gyro.GyroBias("gyro_bias", "Pelvis", dict(bias=truth.tolist())).inject(recording))["Pelvis"]
    assert found.score > SIGNIFICANT and found.fit is not None and found.fit.calibrated > SIGNIFICANT
    assert np.linalg.norm(np.asarray(found.params["bias"]) - truth) < 0.2 * BIAS


def test_noise_alone_gives_no_significant_bias(walk):
    model, recording = walk
    assert max(c.score for c in _biases(model, recording).values()) < SIGNIFICANT


def _pelvis_bias(model, recording):
    """The pelvis' GyroBias candidate, fitted with the heading drifts beside it."""
    analysis = analyse(model, [recording], LINKS)
    train, test = halves(analysis.time)
    found = candidates(analysis, 0, train, test, human_urdf(48), kinds=("gyro_bias", "heading_drift"))
    return next(c for c in found if (c.kind, c.target) == ("gyro_bias", "Pelvis"))


def test_a_bias_along_an_upright_sensors_vertical_stays_a_bias_and_a_drift_does_not_pass_for_one(walk):
    model, recording = walk
    rate = 1.5 * BIAS
    biased = gyro.GyroBias("gyro_bias", "Pelvis", dict(bias=[0.0, 0.0, rate])).inject(recording)
    found = _pelvis_bias(model, biased)
    assert "vertical_turn_score" in found.params  # to the gyro alone, a turn about the vertical
    assert found.score > SIGNIFICANT and not found.implausible()
    drifting = HeadingDrift("heading_drift", "Pelvis", dict(rate=rate, t0=float(recording.time[0]))).inject(recording)
    assert "heading drift" in _pelvis_bias(model, drifting).implausible()

"""shared_drift: a drift its gyro was unaware of beside a bias of that gyro about the vertical, of
the drift's rate, is one drift its gyro shares.

Property: on a recording whose L5 sensor's heading drifts at 1.5 deg/s with its gyro sharing it (a
bias about the vertical a filter without heading reference integrates), a subject that holds the pair
(the unaware drift and the bias, as the loop may name them) comes out holding one shared drift of
that rate in their place, the pair listed among the rejected, and the tracking errors not worse.
"""

from __future__ import annotations

import math

import pytest
from conftest import human48_walk

from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis import elimination, shared_drift
from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.gyro import GyroBias
from torchik.pipelines.diagnosis.result import Step, errors
from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

LINKS = TRACKED_LINKS["human48"]
RATE = 1.5 * math.pi / 180


def test_an_unaware_drift_and_its_gyros_vertical_bias_become_one_shared_drift(one_thread):
    model, urdf, walk = human48_walk(6.0, seed=4, orientation_noise=0.002)
    measured = HeadingDrift("heading_drift", "L5", dict(rate=RATE, t0=0.0, gyro_shares=True)).inject(walk)
    i = measured.links.index("L5")
    up = measured.orientation[:, i, 2, :].mean(0)  # the world vertical in the L5 sensor's frame, on average
    pair = [HeadingDrift("heading_drift", "L5", dict(rate=RATE, t0=0.0, t1=float(walk.time[-1]), gyro_shares=False)),
            GyroBias("gyro_bias", "L5", dict(bias=(RATE * up / (up ** 2).sum() ** 0.5).tolist()))]
    recording, _ = elimination.without(measured, urdf, pair, None)
    s = Subject(recording, urdf, model, source=(measured, urdf))
    analyse_subjects([s], LINKS, DEFAULT_GAIN, False, 100)
    s.derived = s.current[0].derived[s.current[1]]
    s.steps = [Step(e, errors(*s.current), errors(*s.current)) for e in pair]
    before = errors(*s.current).overall
    said: list[str] = []
    shared_drift.merge([s], LINKS, DEFAULT_GAIN, False, 100, 1e-3, said.append)
    assert [e.kind for e in s.effects] == ["heading_drift"] and s.effects[0].params["gyro_shares"], s.effects
    assert s.effects[0].params["rate"] == pytest.approx(RATE, rel=0.1)
    assert all(e in s.rejected for e in pair) and said
    after = errors(*s.current).overall
    assert after["mnte"] <= before["mnte"] * 1.001 and after["rmse"] <= before["rmse"] * 1.001

"""A strap's turn kept on the neighbour of the turned sensor (neighbour.py).

A simulated suit (experiments/sensor_physics.py: pinocchio's kinematics, IMUs through a complementary
filter) walks 8 s; its T12 sensor is then turned on the segment (the sensor's orientation times the
turn, as a strap turned is) by 10 deg about the segment's long axis, which Human48's lumbar joints
(flexion and lateral bending) cannot follow. The loop's wrong path is built by hand: the L3 sensor's
misalignment fitted and added first, as the greedy loop does where L3, between the turned T12 and the
pelvis, scores best.

Property: the L3 turn is replaced by T12's, within 2 deg of the 10 deg put on it; on the walk without
the turn, a misalignment forced on L3 is not moved to a neighbour's sensor (none tracks clearly better).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from diagnosis_path import added, tracked_subject

from torchik.method.models import TRACKED_LINKS, human_urdf
from torchik.pipelines.diagnosis import neighbour
from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
from torchik.pipelines.diagnosis.effect import replace, rotation_about
from torchik.pipelines.diagnosis.subject import Subject

pytest.importorskip("pinocchio")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import sensor_physics  # noqa: E402

LINKS = TRACKED_LINKS["human48"]
SEED = 7420  # neither the tuning seeds (0-199, 600-609) nor the studies' (1000-1899, 2000-2899, 3000-3899)
TURN = 10.0  # deg, about T12's long axis (z)
SAY = lambda _: None  # noqa: E731


def _subject(turn_deg: float) -> Subject:
    urdf = human_urdf(48)
    recording, _, _ = sensor_physics.generate(SEED, "clean", None, LINKS, duration=8.0, rate=100.0, reference=None)
    i = recording.links.index("T12")
    R = recording.orientation.copy()
    R[:, i] = R[:, i] @ rotation_about(np.array([0.0, 0.0, 1.0]), np.array([math.radians(turn_deg)]))[0]
    return tracked_subject(replace(recording, orientation=R), urdf)


def test_a_turn_kept_on_l3_moves_to_the_turned_t12(one_thread):
    s = _subject(TURN)
    added(s, "misalignment", "L3")
    assert neighbour.moved_to_neighbours(s, LINKS, DEFAULT_GAIN, 10.0, False, 300, SAY) == 1
    turned = {e.target: e for e in s.effects if e.kind == "misalignment"}
    assert "T12" in turned and "L3" not in turned, [e.summary() for e in s.effects]
    about_z = math.degrees(turned["T12"].params["rotation_vector"][2])
    assert abs(abs(about_z) - TURN) < 2.0, turned["T12"].summary()


def test_without_a_turn_nothing_moves(one_thread):
    s = _subject(0.0)
    added(s, "misalignment", "L3")
    kept = [e.summary() for e in s.effects]
    assert neighbour.moved_to_neighbours(s, LINKS, DEFAULT_GAIN, 10.0, False, 300, SAY) == 0
    assert [e.summary() for e in s.effects] == kept

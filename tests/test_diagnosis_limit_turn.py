"""A joint limit that is a sensor's turn about the joint's axis (limit_turn.py).

A simulated suit (experiments/sensor_physics.py: pinocchio's kinematics, IMUs through a complementary
filter) walks 8 s; its left shoulder's sensor is then turned (a strap turned on the segment: the
sensor's orientation times that turn) by 8 deg about the axis of the shoulder girdle's
jLeftC7Shoulder_rotx, whose range in Human48 reaches 5 deg below its zero, and 8 deg about the
segment's y axis, which no joint follows. The loop's path is built by hand: the misalignment fitted
(its y part; the joint follows the x part, until its limit), then what is left at the limit explained
by the limit set wider.

Property: the limit is replaced by the misalignment completed about the joint's axis by the least turn
that brings the simulated motion back within the limit (the injected x part less the margin the true
motion keeps from the limit), within 1.5 deg, its y part kept. Without a misalignment of the shoulder's
sensor kept, the limit stays (as likely a cause as a strap); on the clean walk tracked by a model whose
range of that joint is narrower than the motion on both sides, the limit stays: no turn brings the
motion within it.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from diagnosis_path import added, tracked_subject

from torchik.method.models import TRACKED_LINKS, human_urdf
from torchik.pipelines.diagnosis import limit_turn
from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
from torchik.pipelines.diagnosis.effect import replace, rotation_about
from torchik.pipelines.diagnosis.joints import JointLimit
from torchik.pipelines.diagnosis.subject import Subject

pytest.importorskip("pinocchio")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import sensor_physics  # noqa: E402

LINKS = TRACKED_LINKS["human48"]
SEED = 7160  # neither the tuning seeds (0-199, 600-609) nor the reported studies' (1000-1899, 2000-2899)
JOINT = "jLeftC7Shoulder_rotx"
TURN = 8.0  # deg, about each of the two axes


def _limit_added(s: Subject) -> JointLimit:
    """The joint's limit candidate fitted and added, as the loop would."""
    return added(s, "joint_limit", JOINT)


def _joint_axis(urdf: str) -> np.ndarray:
    """The joint's axis in the shoulder's frame at zero: the chain below it turns it little."""
    from torchik.pipelines.diagnosis.joints import joint_groups

    group = next(g for g in joint_groups(urdf, LINKS) if JOINT in g.joints)
    return np.asarray(group.axes[group.joints.index(JOINT)])


def _turned_shoulder():
    """(the subject of the clean walk with the shoulder's sensor turned, the joint's axis, the truth)."""
    urdf = human_urdf(48)
    recording, _, info = sensor_physics.generate(SEED, "clean", None, LINKS, duration=8.0, rate=100.0, reference=None)
    axis = _joint_axis(urdf)
    turn = math.radians(TURN) * (np.array([0.0, 1.0, 0.0]) - axis)  # toward the joint's lower limit, and about y
    i = recording.links.index("LeftShoulder")
    R = recording.orientation.copy()
    R[:, i] = R[:, i] @ rotation_about(turn / np.linalg.norm(turn), np.array([np.linalg.norm(turn)]))[0]
    return tracked_subject(replace(recording, orientation=R), urdf), axis, info["truth"]


def test_a_strap_turned_past_a_narrow_limit_is_named_as_the_turn(one_thread):
    s, axis, truth = _turned_shoulder()
    added(s, "misalignment", "LeftShoulder")
    limit = _limit_added(s)
    assert limit.params["side"] == "lower"
    lower = math.degrees(limit.params["limit"])
    margin = float(np.degrees(np.min(truth["joint_positions"][:, truth["joint_names"].index(JOINT)]))) - lower
    assert limit_turn.limit_as_turn(s, limit, LINKS, DEFAULT_GAIN, 10.0, False, 300, lambda _: None)
    assert not any(isinstance(e, JointLimit) for e in s.effects), [e.summary() for e in s.effects]
    turned = [e for e in s.effects if e.kind == "misalignment" and e.target == "LeftShoulder"]
    assert len(turned) == 1, [e.summary() for e in s.effects]
    about_axis = -math.degrees(float(np.dot(turned[0].params["rotation_vector"], axis)))
    assert abs(about_axis - (TURN - margin)) < 1.5, (about_axis, TURN, margin)
    about_y = math.degrees(turned[0].params["rotation_vector"][1])
    assert abs(about_y - TURN) < 1.5, turned[0].summary()


def test_without_the_sensors_turn_kept_the_limit_stays(one_thread):
    s, _, _ = _turned_shoulder()
    limit = _limit_added(s)
    kept = [e.summary() for e in s.effects]
    assert not limit_turn.limit_as_turn(s, limit, LINKS, DEFAULT_GAIN, 10.0, False, 300, lambda _: None)
    assert [e.summary() for e in s.effects] == kept


def test_a_range_narrower_than_the_motion_on_both_sides_stays_a_limit(one_thread):
    """The clean walk, the joint's range cut to a third of what the walk moves it over, about its middle."""
    recording, _, info = sensor_physics.generate(SEED, "clean", None, LINKS, duration=8.0, rate=100.0, reference=None)
    truth = info["truth"]
    angle = truth["joint_positions"][:, truth["joint_names"].index(JOINT)]
    middle, third = float(np.mean([angle.min(), angle.max()])), float(angle.max() - angle.min()) / 6
    urdf = re.sub(rf'(<joint name="{JOINT}".*?<limit[^>]*?)lower="[^"]*" upper="[^"]*"',
                  rf'\1lower="{middle - third:.6f}" upper="{middle + third:.6f}"', human_urdf(48), flags=re.S)
    assert urdf != human_urdf(48), "the joint's limits were rewritten"
    s = tracked_subject(recording, urdf)
    added(s, "misalignment", "LeftShoulder")  # what little the noise gives: the turn the limit is tried as
    limit = _limit_added(s)
    kept = [e.summary() for e in s.effects]
    assert not limit_turn.limit_as_turn(s, limit, LINKS, DEFAULT_GAIN, 10.0, False, 300, lambda _: None)
    assert [e.summary() for e in s.effects] == kept

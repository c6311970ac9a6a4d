"""The loop's rounds (torchik/pipelines/diagnosis/loop.py): several effects in one round.

Properties:
- two effects on links far apart (not the same links nor one joint away) are both added in the
  first round, and the loop then ends because nothing significant is left, not at its cap;
- two effects on links one joint apart are added in different rounds (the second fitted with the
  first in place), each kept.

Recordings: Human48 walking, 5 s at 50 Hz, the scenarios' sensor noise; gyro biases of 0.1 rad/s
(5.7 deg/s), far above what their fits resolve at that noise, injected with Effect.inject.
"""

from __future__ import annotations

import pytest
from conftest import human48_walk

from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis.gyro import GyroBias
from torchik.pipelines.diagnosis.loop import diagnose

LINKS = TRACKED_LINKS["human48"]
ROUNDS = 4


@pytest.fixture(scope="module")
def walk(one_thread):
    return human48_walk(5.0, seed=5, orientation_noise=0.005)


def _run(walk, targets):
    """(the diagnosis, {target: the round that added it}) of the walk with a gyro bias on each target."""
    model, urdf, recording = walk
    for n, link in enumerate(targets):
        recording = GyroBias("gyro_bias", link, dict(bias=[0.1 * (n % 2), 0.1 * ((n + 1) % 2), 0.0])).inject(recording)
    log: list[str] = []
    d, = diagnose(model, urdf, [recording], LINKS, max_effects=ROUNDS, log=log.append)
    added = {}
    for line in log:
        if line.startswith("round ") and "gyro bias on" in line:
            added.setdefault(line.split("gyro bias on ")[1].split(":")[0], int(line.split()[1].rstrip(":")))
    return d, added


def test_effects_far_apart_are_added_in_one_round(walk):
    d, added = _run(walk, ("LeftForeArm", "RightLowerLeg"))
    assert added == {"LeftForeArm": 1, "RightLowerLeg": 1}
    assert {(e.kind, e.target) for e in d.effects} >= {("gyro_bias", "LeftForeArm"), ("gyro_bias", "RightLowerLeg")}
    assert d.complete and d.stop != "cap"


def test_effects_one_joint_apart_are_added_in_turn(walk):
    d, added = _run(walk, ("LeftForeArm", "LeftHand"))
    assert sorted(added.values()) == [1, 2]
    assert {(e.kind, e.target) for e in d.effects} >= {("gyro_bias", "LeftForeArm"), ("gyro_bias", "LeftHand")}

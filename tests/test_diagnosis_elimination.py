"""Backward elimination (torchik/pipelines/diagnosis/elimination.py and the loop's use of it).

Properties:
- a variant rebuilt without one kept effect is the original with the others corrected, in order;
- the effect added last, and one a later model effect depends on, are not taken out alone;
- effects relate (and only then are re-scored) on a link in common or across one joint;
- a kept effect whose cause is absent no longer pays with the others in place and is dropped, as
  an echo of the effect added last (the report's first lines say so), the subject rebuilt without
  it; a kept effect whose cause is present is kept;
- a kept effect that, re-scored with the others in place, is under its family's floor is dropped as
  negligible;
- a drop after which the subject's error rises (as the loop measures it) is undone: the effect is
  kept, the subject as it was.

Recordings: Human48 walking, 5 s at 50 Hz, the scenarios' sensor noise; a gyro bias of 0.1 rad/s
(5.7 deg/s) on one link, far above what its fit resolves at that noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import kept_subject

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis import elimination
from torchik.pipelines.diagnosis.effect import SIGNIFICANT
from torchik.pipelines.diagnosis.gyro import GyroBias, StreamDelay
from torchik.pipelines.diagnosis.joints import JointLimit, MissingDof
from torchik.pipelines.diagnosis.loop import Diagnosis
from torchik.pipelines.diagnosis.report import answer
from torchik.pipelines.diagnosis.subject import Subject
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
CAUSE, OTHER, FAR = "LeftForeArm", "LeftHand", "RightLowerLeg"  # OTHER is next to CAUSE across the wrist


@pytest.fixture(scope="module")
def biased(one_thread):
    """(model, URDF, a walk whose CAUSE gyro reads 0.1 rad/s too much about its x axis, that bias)."""
    model = load_model("human48")
    walk = scenario("walking", model, LINKS, 5.0, 50.0, seed=3, orientation_noise=0.005, gyro_noise=0.02)
    bias = GyroBias("gyro_bias", CAUSE, dict(bias=[0.1, 0.0, 0.0]))
    return model, human_urdf(48), bias.inject(walk), bias


def _subject(model, urdf, recording, kept) -> Subject:
    """A subject of the loop that kept `kept` (in that order) on `recording`, tracked and analysed."""
    return kept_subject(model, urdf, recording, kept, LINKS)


def _eliminate(s: Subject) -> None:
    """The loop's backward elimination on subject s: its variants tracked, then re-scored."""
    found = elimination.variants(s, s.effects)
    elimination.track([], found, LINKS, 20.0, False, 300)
    elimination.eliminate(found, LINKS, 20.0, SIGNIFICANT, False, 300, lambda _: None)


def test_a_variant_is_the_original_with_the_others_corrected(biased):
    model, urdf, recording, bias = biased
    other = GyroBias("gyro_bias", OTHER, dict(bias=[0.0, 0.02, 0.0]))
    without_other, same = elimination.without(recording, urdf, [bias, other], other)
    np.testing.assert_allclose(without_other.angular_velocity, bias.correct(recording).angular_velocity)
    without_bias, _ = elimination.without(recording, urdf, [bias, other], bias)
    np.testing.assert_allclose(without_bias.angular_velocity, other.correct(recording).angular_velocity)
    assert same == urdf


def test_the_last_effect_and_those_a_later_one_builds_on_are_not_taken_out():
    axis = MissingDof("missing_dof", "jLeftKnee", dict(first_joint="jLeftKnee_roty"))
    on_it = JointLimit("joint_limit", axis.joint_name(), dict(side="upper", limit=0.1, needed=0.3))
    elsewhere = GyroBias("gyro_bias", OTHER, dict(bias=[0.0, 0.0, 0.0]))
    last = GyroBias("gyro_bias", CAUSE, dict(bias=[0.0, 0.0, 0.0]))
    assert elimination.removable([axis, on_it, elsewhere, last]) == [on_it, elsewhere]
    assert elimination.removable([elsewhere, axis, last]) == [elsewhere, axis]


def test_effects_relate_on_their_links_and_across_one_joint(biased):
    model, urdf, _, bias = biased
    on = lambda link: GyroBias("gyro_bias", link, dict(bias=[0.0, 0.0, 0.0]))  # noqa: E731
    assert elimination.related(on(OTHER), bias, model, urdf, LINKS)
    assert not elimination.related(on(FAR), bias, model, urdf, LINKS)
    limit = JointLimit("joint_limit", "jLeftElbow_rotz", dict(side="upper", limit=0.0, needed=0.1))
    assert elimination.reach(limit, model, LINKS) == {"LeftForeArm", "LeftHand"}
    assert elimination.related(on("LeftUpperArm"), limit, model, urdf, LINKS)
    assert not elimination.related(on(FAR), limit, model, urdf, LINKS)
    device = StreamDelay("stream_delay", "all", dict(delay=0.05, links=list(LINKS)))
    assert elimination.related(on(FAR), device, model, urdf, LINKS)


def test_an_effect_without_its_cause_is_dropped_as_an_echo(biased):
    model, urdf, recording, bias = biased
    echo = GyroBias("gyro_bias", OTHER, dict(bias=[0.0, 0.03, 0.0]))  # OTHER's gyro has no bias
    s = _subject(model, urdf, recording, [echo, GyroBias("gyro_bias", CAUSE, dict(bias=list(bias.params["bias"])))])
    _eliminate(s)
    assert [e.target for e in s.effects] == [CAUSE]
    assert s.rejected == [echo] and f"echo of gyro_bias at {CAUSE}" in echo.notes
    np.testing.assert_allclose(s.recording.angular_velocity, bias.correct(recording).angular_velocity)
    d = Diagnosis(s.steps, s.recording, recording, s.urdf, s.model, LINKS, s.current, s.current, None,
                  rejected=s.rejected)
    text = "\n".join(answer(d))
    assert f"gyro bias on {OTHER}" in text and f"rejected as an echo of gyro_bias at {CAUSE}" in text


def test_an_effect_whose_cause_is_present_is_kept(biased):
    model, urdf, recording, bias = biased
    kept = [GyroBias("gyro_bias", CAUSE, dict(bias=list(bias.params["bias"]))),
            GyroBias("gyro_bias", OTHER, dict(bias=[0.0, 0.03, 0.0]))]  # last: not re-scored
    s = _subject(model, urdf, recording, kept)
    _eliminate(s)
    assert s.effects == kept and not s.rejected


def test_a_drop_that_raises_the_error_is_undone(biased):
    model, urdf, recording, bias = biased
    echo = GyroBias("gyro_bias", OTHER, dict(bias=[0.0, 0.03, 0.0]))
    cause = GyroBias("gyro_bias", CAUSE, dict(bias=list(bias.params["bias"])))
    s = _subject(model, urdf, recording, [echo, cause])
    kept_recording = s.recording
    rises = iter([1.0, 2.0])  # the error before the drop, then after it: up by 100 %
    found = elimination.variants(s, s.effects)
    elimination.track([], found, LINKS, 20.0, False, 300)
    said: list[str] = []
    elimination.eliminate(found, LINKS, 20.0, SIGNIFICANT, False, 300, said.append,
                          lambda subject, key: next(rises), 1e-3)
    assert s.effects == [echo, cause] and not s.rejected and "dropped" not in echo.notes
    assert s.recording is kept_recording
    assert any(line.startswith(f"gyro_bias at {OTHER} kept") for line in said)


def test_an_effect_the_others_leave_under_its_floor_is_dropped():
    """A real bias of 0.19 deg/s (under the 0.2 deg/s floor; significant on a quiet gyro) kept before the
    large one of its neighbour: re-scored with the other in place it is negligible, and dropped so."""
    model = load_model("human48")
    walk = scenario("walking", model, LINKS, 5.0, 50.0, seed=3, orientation_noise=0.005, gyro_noise=0.002)
    small = GyroBias("gyro_bias", OTHER, dict(bias=[0.0, float(np.radians(0.19)), 0.0]))
    cause = GyroBias("gyro_bias", CAUSE, dict(bias=[0.1, 0.0, 0.0]))
    recording = small.inject(cause.inject(walk))
    s = _subject(model, human_urdf(48), recording, [small, GyroBias("gyro_bias", CAUSE, dict(bias=[0.1, 0.0, 0.0]))])
    _eliminate(s)
    assert [e.target for e in s.effects] == [CAUSE]
    assert "is negligible" in small.notes and "below the 0.2 deg/s that matters" in small.notes, small.notes

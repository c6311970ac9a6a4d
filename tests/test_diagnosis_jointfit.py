"""The joint fit of the kept effects at the end of the loop (torchik/pipelines/diagnosis/jointfit.py).

Properties:
- with two correlated effects kept at values off the injected ones (a foot's and its toe's heading
  drift: the tracker shares their residual across the ankle) and an unrelated one (a hand's gyro
  bias), the joint step brings the parameters nearer the injected values (every one within two joint
  standard errors of its own, which the kept values were not), the test half's residual falls and the
  step is taken;
- the joint standard errors of the correlated pair are larger than with the other held (and than
  each one's own fit gives), and the unrelated effect's are not;
- kept at the values the loop's own fits settle on, the step is not significant on the test half and
  is not taken: the values stay, with the joint standard errors;
- a misalignment moves only along the directions its fit identifies;
- the report (its first lines, the table's note, the JSON and the calibration) says where the values
  and standard errors come from, and says so when the step was not taken.

Recording: Human48 walking, 5 s at 50 Hz, the scenarios' sensor noise.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import kept_subject

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis import jointfit
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.effect import SIGNIFICANT
from torchik.pipelines.diagnosis.gyro import GyroBias
from torchik.pipelines.diagnosis.loop import Diagnosis
from torchik.pipelines.diagnosis.placement import Misalignment
from torchik.pipelines.diagnosis.report import answer, write
from torchik.pipelines.diagnosis.subject import Subject
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
INJECTED = [HeadingDrift("heading_drift", "LeftFoot", dict(rate=0.03, t0=0.0)),
            HeadingDrift("heading_drift", "LeftToe", dict(rate=-0.02, t0=0.0)),
            GyroBias("gyro_bias", "RightHand", dict(bias=[0.05, 0.0, 0.02]))]
OFF = [0.01, -0.01, [0.005, 0.005, 0.0]]  # how far the kept values start from the injected ones


def _kept() -> list:
    """The injected effects, each moved by OFF (as a fit with the others not yet right leaves them)."""
    out = []
    for e, off in zip(INJECTED, OFF):
        name = "rate" if isinstance(e, HeadingDrift) else "bias"
        params = dict(e.params, **{name: (np.asarray(e.params[name]) + np.asarray(off)).tolist()})
        out.append(type(e)(e.kind, e.target, params))
    return out


def _subject(model, urdf, recording, kept) -> Subject:
    """A subject of the loop that kept `kept` on `recording`, each with the standard errors of its own
    fit with the others in place (as the loop's refine steps leave them)."""
    s = kept_subject(model, urdf, recording, kept, LINKS)
    for effect in kept:
        update = s.refit(effect)
        assert update is not None
        effect.stderr = update.stderr
    return s


@pytest.fixture(scope="module")
def fitted(one_thread):
    """(the subject after its joint fit, the Joint, the loop's standard errors [P], the recording)."""
    model, urdf = load_model("human48"), human_urdf(48)
    recording = scenario("walking", model, LINKS, 5.0, 50.0, seed=3, orientation_noise=0.005, gyro_noise=0.02)
    for effect in INJECTED:
        recording = effect.inject(recording)
    s = _subject(model, urdf, recording, _kept())
    loop_sd = jointfit._vector(s.effects)[1]
    joint, = jointfit.refit([s], LINKS, 20.0, False, 300)
    assert joint is not None
    return s, joint, loop_sd, recording


def test_the_joint_step_brings_the_parameters_nearer_the_injected_ones(fitted):
    s, joint, _, _ = fitted
    truth = np.concatenate([np.atleast_1d(e.params["rate" if isinstance(e, HeadingDrift) else "bias"])
                            for e in INJECTED])
    assert joint.kept and joint.test_after < joint.test_before
    before, after = (joint.theta - truth) / joint.stderr, (joint.theta + joint.delta - truth) / joint.stderr
    assert np.all(np.abs(after) < 2.0) and not np.all(np.abs(before) < 2.0)
    assert np.square(after).sum() < np.square(before).sum()
    np.testing.assert_allclose(jointfit._vector(s.effects)[0], joint.theta + joint.delta)


def test_correlated_effects_have_larger_joint_errors(fitted):
    s, joint, loop_sd, _ = fitted
    pair, alone = slice(0, 2), slice(2, 5)  # the two drifts, the hand's bias
    assert np.all(joint.stderr[pair] > 3 * joint.conditional[pair])
    assert np.all(joint.stderr[pair] > loop_sd[pair])
    np.testing.assert_allclose(joint.stderr[alone], joint.conditional[alone], rtol=0.05)
    np.testing.assert_allclose(jointfit._vector(s.effects)[1], joint.stderr)  # the effects carry the joint errors


def test_a_misalignment_moves_only_along_its_identified_directions():
    identified = [[0.0, 0.6, 0.8]]
    e = Misalignment("misalignment", "LeftHand", dict(rotation_vector=[0.0, 0.06, 0.08], identified=identified),
                     stderr=dict(rotation_vector=[0.01, 0.01, 0.01]))
    theta, _, names, basis = jointfit._vector([GyroBias("gyro_bias", "Pelvis", dict(bias=[0.0, 0.0, 0.0]),
                                                        stderr=dict(bias=[0.1, 0.1, 0.1])), e])
    assert len(names) == 6 and basis.shape == (6, 4)
    np.testing.assert_allclose(basis[3:, 3], identified[0])
    np.testing.assert_allclose(basis[:3, :3], np.eye(3))


def _diagnosis(s: Subject, joint, recording) -> Diagnosis:
    return Diagnosis(s.steps, s.recording, recording, s.urdf, s.model, LINKS, s.current, s.current, None,
                     joint=joint)


def test_the_report_says_the_values_are_from_the_joint_fit(fitted, tmp_path):
    s, joint, _, recording = fitted
    d = _diagnosis(s, joint, recording)
    assert any("from the joint fit" in line for line in answer(d))
    paths = write(d, tmp_path, "walk", "human48", rrd=False)
    assert "Parameters and standard errors: parameters and standard errors from the joint fit" in \
        paths["report"].read_text()
    summary = json.loads(paths["json"].read_text())
    assert summary["joint_fit"]["kept"] and "from the joint fit" in summary["fit_source"]
    assert "from the joint fit" in json.loads(paths["calibration"].read_text())["fit"]


def test_the_report_says_when_the_sequential_values_were_kept(fitted):
    s, joint, _, recording = fitted
    refused = jointfit.Joint(joint.names, joint.theta, joint.delta, joint.stderr, joint.conditional,
                             test_before=1.0, test_after=1.5, kept=False)
    text = "\n".join(answer(_diagnosis(s, refused, recording)))
    assert "parameters from the loop's sequential fit" in text and "not taken" in text


def test_a_step_that_explains_nothing_more_leaves_the_loop_values(fitted):
    """The injected effects kept at the values the loop's own fits settle on: the joint step finds
    nothing significant to add, the values stay, and the effects carry the joint standard errors."""
    s, _, _, recording = fitted
    settled = [type(e)(e.kind, e.target, dict(e.params)) for e in s.effects]  # the joint values: near the truth
    again = kept_subject(s.model, s.urdf, recording, settled, LINKS)
    for e in settled:
        update = again.refit(e)
        assert update is not None
        e.refine(update)
    values = jointfit._vector(settled)[0]
    joint, = jointfit.refit([again], LINKS, 20.0, False, 300)
    assert joint is not None and not joint.kept and joint.gain <= SIGNIFICANT
    np.testing.assert_array_equal(jointfit._vector(settled)[0], values)
    np.testing.assert_allclose(jointfit._vector(settled)[1], joint.stderr)
    assert "parameters from the loop's sequential fit" in joint.note


def test_the_finite_difference_step_ignores_an_unidentified_components_error():
    """A misalignment identified about (0.6, 0.8, 0) whose z component's error is meaningless (huge):
    the step along the identified direction is the smaller of the errors of x and y."""
    basis = np.array([[0.6], [0.8], [0.0]])
    np.testing.assert_allclose(jointfit.step_scale(basis, np.array([0.02, 0.01, 1e6])), [0.01])

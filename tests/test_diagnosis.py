"""The diagnosis loop on synthetic recordings with one undeclared effect injected (random parameters,
sensor noise), over 10 seeds per effect; two effects at once; and noise alone.

All recordings are diagnosed as one batch (a module fixture): Human48 walking, 5 s at 50 Hz, all 23
links, orientation noise 0.005 rad and gyro noise 0.02 rad/s. Seed s of every effect starts from the
same noisy recording as the clean subject s, whose errors are the noise floor.

Effects and where they are injected: random parameters, and a random link (or knee or elbow for
the joint effects) among those where the effect is observable (see MIDDLE, MOVING, CONSTRAINED).

Properties checked, per effect, over the 10 seeds:
- the first effect the loop adds is the injected one, at the injected link or joint (>= 9 of 10);
- its parameters are recovered within the effect's tolerance (>= 9 of 10);
- on the affected links, the error after (MNTE and angular-velocity RMSE; the base velocity for a
  position offset) is at most max(before / 10, 2 x the noise floor) (>= 9 of 10), both against
  the recording the loop corrected and, for the measurement effects but the misalignment (see
  AGAINST_TRUTH), the final estimate against the recording before the injection (so that a
  correction cannot pass by moving the data).
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis.calibration import apply_calibration
from torchik.pipelines.diagnosis.drift import HeadingDrift
from torchik.pipelines.diagnosis.effect import CHUNKS, GUARD, SIGNIFICANT, blocks, halves, lowpass_blocks, score
from torchik.pipelines.diagnosis.gyro import GyroBias, GyroScale, StreamDelay
from torchik.pipelines.diagnosis.joints import JointLimit, MissingDof
from torchik.pipelines.diagnosis.loop import diagnose, errors
from torchik.pipelines.diagnosis.placement import Misalignment, SensorDelay
from torchik.pipelines.diagnosis.position import PositionOffset
from torchik.pipelines.diagnosis.synthetic import beyond_limit, recording_of, with_missing_dof
from torchik.synthetic.scenarios import scenario

SEEDS = range(10)
DURATION, RATE, NOISE, GYRO_NOISE = 5.0, 50.0, 0.005, 0.02
LINKS = TRACKED_LINKS["human48"]
DEG = math.pi / 180
# links where an effect of the kind is observable with Human48 and attributable to one sensor: a
# misalignment or delay needs a link between two joints that lack axes (the forearm: elbow y, z and
# wrist x, z), and a misalignment must turn the sensor about both missing axes (x and y of the
# forearm); otherwise the data cannot tell the sensor from its neighbour (the loop then says so)
MIDDLE = ("LeftForeArm", "RightForeArm")
MOVING = ("LeftForeArm", "RightForeArm", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot", "LeftHand", "RightHand")
CONSTRAINED = ("LeftForeArm", "RightForeArm", "LeftLowerLeg", "RightLowerLeg", "L5", "L3")


def _unit(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _inject(kind: str, rng):
    """(effect to inject, affected links) with random parameters."""
    if kind == "misalignment":
        link = rng.choice(MIDDLE)
        axis = _unit(rng)
        while min(abs(axis[0]), abs(axis[1])) < 0.4:  # seen at both joints: about the elbow's and the wrist's missing axes
            axis = _unit(rng)
        return Misalignment(kind, link, dict(rotation_vector=(axis * rng.uniform(3, 10) * DEG).tolist())), [link]
    if kind == "gyro_bias":
        link = rng.choice(LINKS)
        return GyroBias(kind, link, dict(bias=(_unit(rng) * rng.uniform(0.05, 0.15)).tolist())), [link]
    if kind == "gyro_scale":
        link = rng.choice(MOVING)
        return GyroScale(kind, link, dict(scale_error=float(rng.choice([-1, 1]) * rng.uniform(0.03, 0.1)))), [link]
    if kind == "stream_delay":
        link = rng.choice(MOVING)
        # two samples or more: a delay within one is below the floor that matters (placement.DELAY_FLOOR)
        return StreamDelay(kind, link, dict(delay=float(rng.integers(2, 5)) / RATE)), [link]
    if kind == "sensor_delay":
        link = rng.choice(MIDDLE)
        return SensorDelay(kind, link, dict(delay=float(rng.uniform(1.5, 3)) / RATE)), [link]
    if kind == "heading_drift":
        link = rng.choice(CONSTRAINED)
        return HeadingDrift(kind, link, dict(rate=float(rng.choice([-1, 1]) * rng.uniform(0.6, 2.0) * DEG), t0=0.0)), [link]
    if kind == "position_offset":
        return PositionOffset(kind, "Pelvis", dict(offset=(_unit(rng) * rng.uniform(0.03, 0.1)).tolist())), ["Pelvis"]
    raise ValueError(kind)


MISSING = (("Knee", "UpperLeg", "LowerLeg", "Foot"), ("Elbow", "UpperArm", "ForeArm", "Hand"))  # joint, parent, child, below
BEYOND = (("jLeftKnee_roty", "lower", ["LeftLowerLeg", "LeftFoot", "LeftToe"]),
          ("jRightKnee_roty", "lower", ["RightLowerLeg", "RightFoot", "RightToe"]),
          ("jRightElbow_rotz", "lower", ["RightForeArm", "RightHand"]),
          ("jLeftElbow_rotz", "upper", ["LeftForeArm", "LeftHand"]))
MEASUREMENT = ("misalignment", "gyro_bias", "gyro_scale", "stream_delay", "sensor_delay", "heading_drift",
               "position_offset")


@pytest.fixture(scope="module")
def runs(one_thread):
    return diagnose_cases()


def diagnose_cases(only=None) -> dict[str, list]:
    """{case: [(truth, affected links, Diagnosis)] * 10} for every effect, 'pair' and 'clean' (the
    cases named in `only` and 'clean', when given)."""
    want = lambda case: only is None or case in only  # noqa: E731
    model, urdf = load_model("human48"), human_urdf(48)
    recordings, cases = [], []
    clean = [scenario("walking", model, LINKS, DURATION, RATE, seed=s, orientation_noise=NOISE, gyro_noise=GYRO_NOISE)
             for s in SEEDS]
    for s in SEEDS:
        recordings.append(clean[s])
        cases.append(("clean", None, []))
    for kind in filter(want, MEASUREMENT):
        rng = np.random.default_rng(1000 + MEASUREMENT.index(kind))
        for s in SEEDS:
            effect, affected = _inject(kind, rng)
            recordings.append(effect.inject(clean[s]))
            cases.append((kind, effect, affected))
    rng = np.random.default_rng(77)
    for s in SEEDS if want("pair") else ():  # two at once: a misalignment and a gyro bias elsewhere
        first, _ = _inject("misalignment", rng)
        second = GyroBias("gyro_bias", rng.choice(("LeftLowerLeg", "RightLowerLeg", "T8")),
                          dict(bias=(_unit(rng) * rng.uniform(0.05, 0.15)).tolist()))
        recordings.append(second.inject(first.inject(clean[s])))
        cases.append(("pair", (first, second), [first.target, second.target]))
    rng = np.random.default_rng(99)
    # an ab/adduction axis (x of the parent) at a knee or an elbow, which Human48 lacks
    for s in SEEDS if want("missing_dof") else ():
        side, (joint, parent, child, hand) = rng.choice(("Left", "Right")), MISSING[rng.integers(len(MISSING))]
        effect = MissingDof("missing_dof", f"j{side}{joint}", dict(axis=[1.0, 0.0, 0.0], parent=side + parent,
                                                                  child=side + child, first_joint=f"j{side}{joint}_roty"))
        # within what a knee's or an elbow's missing direction moves (joints.HINGE_RANGE: a range under 15 deg)
        truth, motion = with_missing_dof(urdf, effect, rng.uniform(0.05, 0.12), 0.9, rng.uniform(0, 2 * math.pi),
                                         duration=DURATION, rate=RATE, seed=s)
        recordings.append(recording_of(truth, motion, LINKS, s, NOISE, GYRO_NOISE))
        cases.append(("missing_dof", effect, [side + child, side + hand] + (["%sToe" % side] if joint == "Knee" else [])))
    for s in SEEDS if want("joint_limit") else ():  # a knee hyperextended, or an elbow, beyond Human48's limit of 0
        joint, bound, links = BEYOND[rng.integers(len(BEYOND))]
        motion, reached = beyond_limit(model, joint, rng.uniform(0.1, 0.25), bound, duration=DURATION, rate=RATE, seed=s)
        recordings.append(recording_of(model, motion, LINKS, s, NOISE, GYRO_NOISE))
        cases.append(("joint_limit", JointLimit("joint_limit", joint, dict(side=bound, needed=reached)), links))
    results = diagnose(model, urdf, recordings, LINKS, max_effects=3, refine=1, max_samples=100)
    out: dict[str, list] = {}
    for (kind, truth, affected), result in zip(cases, results):
        out.setdefault(kind, []).append((truth, affected, result))
    out["floor"] = out["clean"]
    out["truth"] = clean
    return out


# Measurement effects whose final estimate is also held against the recording before the
# injection. Not the misalignment: on the forearm the data determine two of its three directions
# (its `identified` rows, checked to 1 degree above: 0.01 to 0.22 degrees on these seeds); the
# third, which the joints absorb, is left at zero, and the 0.4 to 4.7 degrees the seeds put there
# keep the estimate off the truth (1 - cos of that angle, as measured) in 7 of 10.
AGAINST_TRUTH = tuple(kind for kind in MEASUREMENT if kind != "misalignment")


def _against_truth(result, truth):
    """The errors of the loop's final estimate against `truth`, the recording before the effect
    was injected (same noise): what the loop's own `after`, measured against the recording it
    corrected, cannot show."""
    analysis, b = result.last
    ids = [truth.links.index(name) for name in analysis.links]
    as_tensor = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=analysis.R_m.dtype)  # noqa: E731
    R_m, w_m, v_m = analysis.R_m.clone(), analysis.w_m.clone(), analysis.v_m.clone()
    R_m[:, b], w_m[:, b] = as_tensor(truth.orientation[:, ids]), as_tensor(truth.angular_velocity[:, ids])
    v_m[:, b] = as_tensor(truth.base_linear_velocity)
    return errors(dataclasses.replace(analysis, R_m=R_m, w_m=w_m, v_m=v_m), b)


def _error_ok(result, floor, affected, position=False, truth=None) -> bool:
    """After <= max(before / 10, 2 x floor) on every affected link (both MNTE and RMSE); with
    `truth` (the recording before the injection), the final estimate measured against it, too."""
    if truth is not None and not _error_ok(result, floor, affected, position):
        return False
    before, after, base = result.before, result.after if truth is None else _against_truth(result, truth), floor.after
    if position:
        return after.base_velocity <= max(before.base_velocity / 10, 2 * base.base_velocity)
    for link in affected:
        i = LINKS.index(link)
        for name in ("mnte", "rmse"):
            b, a, f = getattr(before, name)[i], getattr(after, name)[i], getattr(base, name)[i]
            if a > max(b / 10, 2 * f):
                return False
    return True


def _param_ok(kind: str, truth, found) -> bool:
    p = found.params
    if kind == "misalignment":  # within 1 degree in the directions the data determine
        V = np.asarray(p["identified"]).reshape(-1, 3)
        return len(V) > 0 and np.linalg.norm(V @ (np.asarray(p["rotation_vector"]) - truth.params["rotation_vector"])) < DEG
    if kind == "gyro_bias":  # within 10 %
        b = np.asarray(truth.params["bias"])
        return np.linalg.norm(np.asarray(p["bias"]) - b) < 0.1 * np.linalg.norm(b)
    if kind == "gyro_scale":  # within 10 % of the scale error
        return abs(p["scale_error"] - truth.params["scale_error"]) < 0.1 * abs(truth.params["scale_error"])
    if kind in ("stream_delay", "sensor_delay"):  # within one sample
        return abs(p["delay"] - truth.params["delay"]) < 1.0 / RATE
    if kind == "heading_drift":  # within 10 % of the rate
        return abs(p["rate"] - truth.params["rate"]) < 0.1 * abs(truth.params["rate"])
    if kind == "position_offset":  # within 5 mm
        return np.linalg.norm(np.asarray(p["offset"]) - truth.params["offset"]) < 0.005
    if kind == "missing_dof":  # the axis within 10 degrees (as a line)
        return abs(float(np.dot(p["axis"], truth.params["axis"]))) > math.cos(10 * DEG)
    if kind == "joint_limit":  # the angle the motion reaches within 1 degree
        return abs(p["needed"] - truth.params["needed"]) < DEG
    raise ValueError(kind)


@pytest.mark.parametrize("kind", MEASUREMENT + ("missing_dof", "joint_limit"))
def test_the_injected_effect_is_named_recovered_and_removed(runs, kind):
    named = recovered = reduced = 0
    for seed, (truth, affected, result) in enumerate(runs[kind]):
        effects = result.effects
        if not effects or effects[0].kind != kind or effects[0].target != truth.target:
            continue
        named += 1
        recovered += _param_ok(kind, truth, effects[0])
        reduced += _error_ok(result, runs["floor"][seed][2], affected, kind == "position_offset",
                             runs["truth"][seed] if kind in AGAINST_TRUTH else None)
    assert named >= 9, f"{kind}: named in {named} of 10"
    assert recovered >= 9, f"{kind}: parameters recovered in {recovered} of 10"
    assert reduced >= 9, f"{kind}: error reduced in {reduced} of 10"


def test_two_effects_at_once_are_both_found(runs):
    """A misalignment and a gyro bias on another link: both named, both within tolerance (>= 9 of 10)."""
    both = 0
    for (first, second), _, result in runs["pair"]:
        found = {(e.kind, e.target): e for e in result.effects}
        both += (("misalignment", first.target) in found and ("gyro_bias", second.target) in found
                 and _param_ok("misalignment", first, found[("misalignment", first.target)])
                 and _param_ok("gyro_bias", second, found[("gyro_bias", second.target)]))
    assert both >= 9, f"both effects found in {both} of 10"


def test_noise_alone_adds_nothing(runs):
    """Noise alone: nothing added (>= 9 of 10)."""
    empty = sum(not result.effects for _, _, result in runs["clean"])
    added = [r.effects[0].summary() for _, _, r in runs["clean"] if r.effects]
    assert empty >= 9, f"nothing added in {empty} of 10; added: {added}"


def test_the_calibration_file_undoes_the_measurement_effects(runs):
    """Applying the JSON calibration to the raw recording gives the loop's corrected recording."""
    _, _, result = runs["pair"][0]
    calibration = json.loads(json.dumps(result.calibration()))
    again = apply_calibration(result.original, calibration)
    assert np.allclose(again.orientation, result.recording.orientation, atol=1e-9)
    assert np.allclose(again.angular_velocity, result.recording.angular_velocity, atol=1e-9)
    assert len(calibration["effects"]) >= 2


@pytest.mark.parametrize("rate,duration", [(50, 5.0), (100, 12.3), (100, 2.2), (12, 6.0), (30, 0.8)])
def test_train_and_test_halves_are_a_guard_apart(rate, duration):
    """Alternate blocks, no training sample closer to a test sample than the fits' filter span
    (1 / min(5 Hz, rate / 4)), so that they share no noise; without the guard every sample after
    the transient is in one half."""
    time = torch.arange(0.0, duration, 1.0 / rate, dtype=torch.float64) + 3.0
    train, test = halves(time)
    assert int(train.sum()) > 0.3 * len(time) / 2 and int(test.sum()) > 0.3 * len(time) / 2
    start = 1.0 if duration > 3.0 else 0.0  # the transient, skipped when there is time for it
    span = float(time[-1] - time[0]) - start
    block = 1.0 if span >= 1.5 else span / 4  # shorter recordings alternate quarters
    expected = min(1.0 / min(5.0, rate / 4), block / 2)  # the guard, capped at half a block
    assert expected >= GUARD or block < 1.0
    gap = (time[train][:, None] - time[test][None, :]).abs().min()
    assert float(gap) >= expected - 1e-9
    train0, test0 = halves(time, guard=0.0)
    assert bool((train0 | test0)[time >= time[0] + start].all()) and not bool((train0 & test0).any())


@pytest.mark.parametrize("guard", [None, 0.0])
def test_the_fits_low_pass_never_carries_a_test_sample_into_a_train_value(guard):
    """lowpass_blocks filters each run of train or test samples on its own: changing every test
    sample leaves every filtered train value as it was (and the reverse), with or without the guard;
    every sample belongs to a run, and the runs alternate train and test."""
    time = torch.arange(0.0, 12.0, 0.02, dtype=torch.float64)
    train, test = halves(time, guard=guard)
    x = torch.randn(len(time), 4, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    base = lowpass_blocks(x, time, 5.0, train, test)
    for side, other in ((train, test), (test, train)):
        moved = lowpass_blocks(torch.where(other[:, None, None], x + 10.0 * torch.randn_like(x), x), time, 5.0, train, test)
        assert torch.equal(moved[side], base[side])
        assert not torch.allclose(moved[other], base[other])
    label = blocks(train, test)
    assert bool((torch.diff(label) >= 0).all()) and int(label.max()) >= 9
    for run in range(int(label.max()) + 1):
        inside = label == run
        assert not (bool((inside & train).any()) and bool((inside & test).any()))


@pytest.mark.parametrize("seed", range(5))
def test_the_calibrated_score_keeps_an_effect_of_varying_strength_and_drops_one_that_comes_and_goes(seed):
    """Score.calibrated: an effect whose strength varies with the motion (a scale error on a link that
    moves fast, then hardly) but is all there is keeps its score (gains scatter as the noise says); one
    that explains the residual in some stretches and not in others (noise wandering into its shape)
    scores above SIGNIFICANT but not once calibrated."""
    g = torch.Generator().manual_seed(seed)
    t = torch.arange(0.0, 16.0, 0.02, dtype=torch.float64)
    stretch = torch.div(torch.arange(len(t)), len(t) // CHUNKS, rounding_mode="floor").clamp(max=CHUNKS - 1)
    shape = torch.stack((torch.sin(7 * t), torch.cos(5 * t), torch.sin(3 * t)), -1)  # [T,3]
    noise = 0.1 * torch.randn(len(t), 3, generator=g, dtype=torch.float64)
    strength = torch.tensor([1.0, 0.2, 0.6, 0.1, 0.8, 0.3, 0.05, 0.5], dtype=torch.float64)[stretch, None]
    real = score(strength * shape + noise, noise, 1)
    assert real.calibrated > SIGNIFICANT and real.calibrated >= 0.5 * real.score, (real.score, real.dispersion)
    share = torch.tensor([0.5, 0.0, 0.0, 0.5, 0.0, 0.1, 0.0, 0.0], dtype=torch.float64)[stretch, None]  # of y_hat
    y_hat = 0.2 * shape
    wander = score(share * 6 * y_hat + noise, share * 6 * y_hat + noise - y_hat, 1)
    assert wander.score > SIGNIFICANT and wander.calibrated <= SIGNIFICANT, (wander.score, wander.calibrated)


def test_a_refine_step_within_its_standard_errors_is_within_error():
    """A correction no larger than its standard error is not applied (nor re-tracked); one beyond is.
    A joint limit's refit is the range needed, not a correction: never negligible."""
    within = GyroBias("gyro_bias", "T8", dict(bias=[0.001, -0.002, 0.0]), dict(bias=[0.002, 0.002, 0.002]))
    beyond = GyroBias("gyro_bias", "T8", dict(bias=[0.001, -0.003, 0.0]), dict(bias=[0.002, 0.002, 0.002]))
    assert within.within_error() and not beyond.within_error()
    limit = JointLimit("joint_limit", "jLeftKnee_roty", dict(side="lower", limit=0.0, needed=0.0), dict(needed=1.0))
    assert not limit.within_error()


def test_joint_effects_beyond_a_body_are_implausible():
    """A limit moved by more than MAX_WIDENING, and an added axis that never comes within MAX_OFFSET
    of the zero the static pose gives it, are refused; within them they are not."""
    from torchik.pipelines.diagnosis.joints import MAX_OFFSET, MAX_WIDENING

    limit = lambda beyond: JointLimit("joint_limit", "jLeftKnee_roty", dict(side="lower", limit=0.0,  # noqa: E731
                                                                            needed=-beyond))
    assert limit(0.9 * MAX_WIDENING).implausible() == "" and limit(1.1 * MAX_WIDENING).implausible()
    axis = lambda lo, hi: MissingDof("missing_dof", "jLeftWrist", dict(angle_range=[lo, hi]))  # noqa: E731
    assert axis(-0.1, 1.5 * MAX_OFFSET).implausible() == "" and axis(0.9 * MAX_OFFSET, 3 * MAX_OFFSET).implausible() == ""
    assert axis(1.1 * MAX_OFFSET, 2 * MAX_OFFSET).implausible() and axis(-2 * MAX_OFFSET, -1.1 * MAX_OFFSET).implausible()

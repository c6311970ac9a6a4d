"""The physics of the independent recording generator (experiments/sensor_physics.py).

Properties: perfect sensors report the true orientations and, half an output sample late (their
integrate-and-dump), pinocchio's angular velocities; a sensor point's acceleration is the second
derivative of its position; a 6-axis filter turns a bias about the vertical into a heading drift
that its compensated rate shares; a 9-axis filter follows a turning field in heading while its
gyro stays unbiased, and estimates a bias (keeping its orientation) that its raw rate still carries;
a turned strap turns the reported orientation by the strap, in the segment's frame; a turned marker
cluster turns the fitted orientation by the offset, the angular velocity being the orientations'
derivative; a late rate stream is the stream sampled late; every family gives a valid recording
with the seed's motion; the module imports nothing from torchik.pipelines.

The models are torchik's human_urdf text (the published URDFs are not needed).
"""

from __future__ import annotations

import ast
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from torchik.method.models import TRACKED_LINKS

pin = pytest.importorskip("pinocchio")
EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"
sys.path.insert(0, str(EXPERIMENTS))
import sensor_physics as sp  # noqa: E402

LINKS = TRACKED_LINKS["human48"]
RATE = 100.0
DEG = math.pi / 180


@pytest.fixture(scope="module")
def body():
    model, _ = sp.human_model(48, reference=None)
    names, lower, upper = sp.joint_table(model)
    motion = sp.walking_motion(np.random.default_rng(11), names, lower, upper, (-1.0, 9.0))
    return sp.Body(model, motion)


def _time(seconds: float) -> np.ndarray:
    return np.arange(int(seconds * RATE)) / RATE


def _angle_deg(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The angle (deg) of A^T B for rotations [...,3,3]."""
    return np.degrees(np.linalg.norm(sp.logm(np.swapaxes(A, -1, -2) @ B), axis=-1))


def _central_rate(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World angular velocity of orientations [T,...,3,3] by log(R_{k+1} R_{k-1}^T) / 2dt, interior frames."""
    return sp.logm(R[2:] @ np.swapaxes(R[:-2], -1, -2)) / (t[2:] - t[:-2]).reshape(-1, *([1] * (R.ndim - 2)))


def _heading_slope(reported: np.ndarray, true: np.ndarray, t: np.ndarray, after: float) -> float:
    """deg/s: the slope of the heading of the world-frame error reported true^T, fitted after `after` s."""
    heading = np.degrees(np.unwrap(sp.yaw(reported @ np.swapaxes(true, -1, -2))))
    late = t >= after
    return float(np.polyfit(t[late], heading[late], 1)[0])


def test_perfect_sensors_report_the_true_orientations_and_the_rates_half_a_sample_late(body):
    """No noise and no errors: the filter's orientation is the sensor's within 0.01 deg rms over 5 s,
    and the reported world rate is pinocchio's frame angular velocity (getFrameVelocity, called here)
    at t - dt/2, the middle of the integrate-and-dump window: far closer than at t."""
    t = _time(5.0)
    out = sp.simulate_imus(body, sp.ImuSetup.ideal(LINKS), t)
    assert np.sqrt((_angle_deg(out.true_orientation, out.orientation) ** 2).mean()) < 0.01
    model, data = body.model, body.model.createData()
    frames, every = body.frames(LINKS), slice(5, None, 10)
    errors = {}
    for lag in (0.5 / RATE, 0.0):
        q, v, _ = body.configuration(t[every] - lag)
        w = np.empty((len(q), len(frames), 3))
        for n in range(len(q)):
            pin.forwardKinematics(model, data, q[n], v[n])
            w[n] = [pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED).angular for f in frames]
        errors[lag] = np.sqrt(((out.angular_velocity[every] - w) ** 2).sum(-1).mean())
    assert errors[0.5 / RATE] < 0.01, errors  # rad/s, of rates of about 2 rad/s rms
    assert errors[0.5 / RATE] < 0.1 * errors[0.0], errors


def test_a_sensor_point_s_acceleration_is_the_second_derivative_of_its_position(body):
    """Points 3-10 cm off the segments' origins: the classical acceleration (pinocchio's
    getFrameClassicalAcceleration, and the module's own) matches a central second difference of the
    point's position (h = 1 ms), the angular velocity and its derivative their first differences;
    the joints stay within Human48's limits."""
    offsets = np.random.default_rng(0).uniform(-0.1, 0.1, (len(LINKS), 3))
    frames = body.points(LINKS, offsets)
    t, h = np.array([0.37, 2.9, 4.41]), 1e-3
    kin = body.kinematics(np.concatenate((t - h, t, t + h)), frames)
    before, now, after = (slice(k * len(t), (k + 1) * len(t)) for k in range(3))
    fd = (kin.position[before] - 2 * kin.position[now] + kin.position[after]) / h ** 2
    scale = np.abs(kin.acceleration[now]).max()
    assert scale > 1.0  # a walk's accelerations, not a still body
    assert np.abs(fd - kin.acceleration[now]).max() < 1e-3 * scale
    q, v, a = body.configuration(t)
    data = body.model.createData()
    for n in range(len(t)):
        pin.forwardKinematics(body.model, data, q[n], v[n], a[n])
        pinocchio_acc = [pin.getFrameClassicalAcceleration(body.model, data, f, pin.LOCAL_WORLD_ALIGNED).linear
                         for f in frames]
        assert np.allclose(pinocchio_acc, kin.acceleration[now][n], atol=1e-9)
    rate = sp.logm(kin.rotation[after] @ np.swapaxes(kin.rotation[before], -1, -2)) / (2 * h)
    assert np.abs(rate - kin.world_rate[now]).max() < 1e-4 * np.abs(kin.world_rate[now]).max()
    fd = (kin.body_rate[after] - kin.body_rate[before]) / (2 * h)
    assert np.abs(fd - kin.body_rate_dot[now]).max() < 1e-4 * np.abs(kin.body_rate_dot[now]).max()
    _, lower, upper = sp.joint_table(body.model)
    angles = body.configuration(np.linspace(-1.0, 9.0, 2001))[0][:, 7:]
    assert (angles >= lower).all() and (angles <= upper).all()


def test_a_6_axis_filter_turns_a_bias_about_the_vertical_into_a_heading_drift_its_rate_shares(body):
    """The pelvis' gyro biased 2 deg/s about its z axis (about the vertical), a 6-axis filter (no
    magnetometer), rates compensated by the filter's bias estimate: the heading drifts at the bias
    rate (within 3 %: the pelvis tilts a few deg), and the reported rate's vertical part agrees with
    the derivative of the reported orientations (the drift is shared) while it is off the truth's by
    the bias."""
    t, bias = _time(6.0), 2.0
    links = ("Pelvis", "T8", "RightUpperLeg")
    setup = sp.ImuSetup.ideal(links, magnetometer=np.zeros(3, bool), compensated=np.ones(3, bool),
                              gyro_bias=np.array([[0.0, 0.0, bias * DEG], [0, 0, 0], [0, 0, 0]]))
    out = sp.simulate_imus(body, setup, t)
    assert _heading_slope(out.orientation[:, 0], out.true_orientation[:, 0], t, 0.0) == pytest.approx(bias, rel=0.03)
    own = _central_rate(out.orientation[:, 0], t)[:, 2]
    reported, true = out.angular_velocity[1:-1, 0, 2], out.true_rate[1:-1, 0, 2]
    assert abs((reported - own).mean()) < 0.03 * bias * DEG
    assert (reported - true).mean() == pytest.approx(bias * DEG, rel=0.03)
    assert _heading_slope(out.orientation[:, 1], out.true_orientation[:, 1], t, 0.0) == pytest.approx(0.0, abs=0.02)


def test_a_9_axis_filter_follows_a_turning_field_in_heading_while_its_gyro_stays_unbiased(body):
    """The pelvis' magnetic field turning at 2 deg/s about the vertical: the filter keeps the field
    where it was, so its heading turns at -2 deg/s (within 3 %, once the filter's transient of a
    few seconds is over), while the reported rate's vertical part stays the truth's (its mean within
    3 % of the field's rate)."""
    t, turn = _time(8.0), 2.0
    links = ("Pelvis", "T8")
    setup = sp.ImuSetup.ideal(links, field_turn=np.array([turn * DEG, 0.0]))
    out = sp.simulate_imus(body, setup, t)
    assert _heading_slope(out.orientation[:, 0], out.true_orientation[:, 0], t, 4.0) == pytest.approx(-turn, rel=0.03)
    vertical = out.angular_velocity[:, 0, 2] - out.true_rate[:, 0, 2]
    assert abs(vertical.mean()) < 0.03 * turn * DEG
    assert _heading_slope(out.orientation[:, 1], out.true_orientation[:, 1], t, 4.0) == pytest.approx(0.0, abs=0.01)


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)], ids=["horizontal", "vertical"])
def test_a_9_axis_filter_estimates_a_bias_and_keeps_its_orientation_while_the_raw_rate_carries_it(body, axis):
    """The pelvis' gyro biased 5 deg/s along its x (forward, horizontal) or z (vertical) axis, a
    9-axis filter, raw rates: after the filter's transient (6 s on) its orientation is within
    0.2 deg of the truth and its bias estimate within 3 % of the bias, while the raw rate, brought
    back to the sensor's axes, is off the truth's by the whole bias."""
    t, bias = _time(8.0), 5.0 * DEG * np.array(axis)
    setup = sp.ImuSetup.ideal(("Pelvis",), gyro_bias=bias[None])
    out = sp.simulate_imus(body, setup, t)
    late = t >= 6.0
    assert _angle_deg(out.true_orientation[late, 0], out.orientation[late, 0]).max() < 0.2
    assert np.linalg.norm(out.bias_estimate[-1, 0] - bias) < 0.03 * np.linalg.norm(bias)
    Rt = np.swapaxes(out.orientation[late, 0], -1, -2)
    off = (Rt @ (out.angular_velocity[late, 0] - out.true_rate[late, 0])[..., None])[..., 0].mean(0)
    assert np.linalg.norm(off - bias) < 0.03 * np.linalg.norm(bias)


def test_a_turned_strap_turns_the_reported_orientation_by_the_strap_in_the_segment_frame(body):
    """Three sensors strapped turned by 10 deg about random axes (C), the rest straight, no noise
    (the body model leaving 5 % of the accelerations): each turned sensor's reported orientation is
    the straight one's times C (within 1e-6 deg: the filter commutes with a turn of its sensor), its
    world rate the same; the straight sensors report as before."""
    t = _time(4.0)
    links = ("Pelvis", "T8", "RightForeArm", "LeftLowerLeg", "Head")
    straight = sp.ImuSetup.ideal(links, residual_share=0.05)
    C = sp.expm(sp.unit_vectors(np.random.default_rng(3), 3) * 10 * DEG)
    mount = straight.mount.copy()
    mount[[1, 2, 3]] = C
    a = sp.simulate_imus(body, straight, t)
    b = sp.simulate_imus(body, replace(straight, mount=mount), t)
    assert _angle_deg(a.orientation @ mount, b.orientation).max() < 1e-6
    assert _angle_deg(a.orientation[:, [1, 2, 3]], b.orientation[:, [1, 2, 3]]).min() > 9.99
    assert np.abs(a.angular_velocity - b.angular_velocity).max() < 1e-9


def test_a_late_rate_stream_is_the_stream_sampled_late(body):
    """Rate streams late by 3 output samples, and by 2.5 (half an output sample between two internal
    ones): the rates are the undelayed ones 3 samples earlier (to 1e-7: the filters start earlier
    to have the late samples), and the 2.5-sample one is between those 2 and 3 earlier; the
    orientations are unchanged."""
    t = _time(3.0)
    setup = sp.ImuSetup.ideal(("Pelvis", "RightHand"))
    a = sp.simulate_imus(body, setup, t)
    b = sp.simulate_imus(body, replace(setup, rate_delay=np.array([3.0, 2.5]) / RATE), t)
    assert np.abs(b.angular_velocity[3:, 0] - a.angular_velocity[:-3, 0]).max() < 1e-7
    mid = 0.5 * (a.angular_velocity[:-3, 1] + a.angular_velocity[1:-2, 1])
    assert np.abs(b.angular_velocity[3:, 1] - mid).max() < 0.05 * np.abs(a.angular_velocity[:, 1]).max()
    assert np.abs(b.angular_velocity[3:, 1] - a.angular_velocity[:-3, 1]).max() > 0.01
    assert np.abs(b.orientation - a.orientation).max() < 1e-7


def test_a_cluster_offset_turns_the_fitted_orientation_and_the_rate_is_the_orientations_derivative(body):
    """Marker clusters without noise: one turned 10 deg on its segment (and shifted 4 mm) gives
    fitted orientations the clean ones times the turn (1e-9), the others unchanged; the angular
    velocity is the orientations' derivative (a central difference of them within 0.01 rad/s rms)
    and, the turn being constant, the clean one's."""
    t = _time(3.0)
    links = ("Pelvis", "RightUpperArm", "LeftFoot")
    clean = sp.ClusterSetup.draw(links, np.random.default_rng(5))
    turn = sp.expm(np.array([0.0, 0.6, 0.8]) * 10 * DEG)
    offset = replace(clean, turn=np.stack([np.eye(3), turn, np.eye(3)]),
                     shift=np.array([[0, 0, 0], [0.004, 0, 0], [0, 0, 0]]))
    a = sp.simulate_clusters(body, clean, t)
    b = sp.simulate_clusters(body, offset, t)
    assert _angle_deg(a["orientation"] @ offset.turn, b["orientation"]).max() < 1e-7
    assert _angle_deg(a["true_orientation"], a["orientation"]).max() < 1e-7
    derivative = _central_rate(b["orientation"], t)
    assert np.sqrt(((b["angular_velocity"][1:-1] - derivative) ** 2).sum(-1).mean()) < 0.01
    assert np.abs(b["angular_velocity"] - a["angular_velocity"]).max() < 1e-6
    assert np.sqrt(((b["angular_velocity"][1:-1] - b["true_rate"][1:-1]) ** 2).sum(-1).mean()) < 0.02


def test_every_family_gives_a_valid_recording_with_the_seed_s_motion():
    """Each family (2 s at 50 Hz, torchik's URDF text) gives a Recording (validated on construction)
    of the links asked, its effects named on them (or on a joint Human48 lacks, or "all"), and one
    seed gives every family the same motion."""
    links = ("Pelvis", "L5", "T8", "Head", "RightUpperArm", "RightForeArm", "LeftUpperLeg", "LeftLowerLeg")
    truth = {}
    for family in sp.FAMILIES:
        recording, injected, info = sp.generate(4, family, links=links, duration=2.0, rate=50.0, reference=None)
        assert recording.links == links and recording.orientation.shape == (100, len(links), 3, 3)
        assert (family in ("clean", "optical_clean")) == (not injected), (family, injected)
        for inj in injected:
            assert inj.family == family and inj.kinds()
            assert all(x in links or x == "all" or inj.family == "missing_axis" for x in inj.targets)
        truth[family] = info["truth"]["orientation"]
    assert all(np.array_equal(truth["clean"], R) for family, R in truth.items() if family != "missing_axis")
    # Human66 moves one more axis: the segments above it (the pelvis at least) move as Human48's
    assert np.abs(truth["missing_axis"][:, 0] - truth["clean"][:, 0]).max() < 1e-12


def test_the_module_imports_nothing_from_torchik_pipelines():
    """Its imports (anywhere in it), parsed: from torchik only the recording container and the models."""
    tree = ast.parse((EXPERIMENTS / "sensor_physics.py").read_text())
    modules = {a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names}
    modules |= {"." * node.level + (node.module or "") for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert not any(m.startswith(("torchik.pipelines", ".")) for m in modules), modules
    assert {m for m in modules if m.startswith("torchik")} <= {"torchik.io.recording", "torchik.method.models"}

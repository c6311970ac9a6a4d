"""What the data can say (torchik/pipelines/diagnosis/streams.py, issue 35 item 4).

Properties:
- an angular velocity differentiated from the orientations, by the project's central difference or by
  np.gradient of their quaternions as a user converting a file would, is told from a gyro on the data
  alone, whatever the file says; a gyro with orientation noise never passes for one;
- the BVH reader declares its rates derived and its segments one clock;
- on a derived stream no gyro family is fitted (the report says why), and with one clock no sensor
  is fitted late on the others.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import human48_walk
from test_bvh import bvh_text

from torchik.io import read
from torchik.io.recording import angular_velocity_from_orientations
from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis.candidates import candidates
from torchik.pipelines.diagnosis.effect import halves, replace
from torchik.pipelines.diagnosis.streams import derived_rates, derived_velocity
from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

LINKS = TRACKED_LINKS["human48"]


def quaternion_gradient(R: np.ndarray, time: np.ndarray) -> np.ndarray:
    """[T,L,3] world rates 2 dq/dt q* with dq/dt by np.gradient of the quaternions (w, x, y, z), made
    continuous in sign: a user's conversion, not the project's scheme."""
    w = np.sqrt(np.clip(1.0 + np.trace(R, axis1=-2, axis2=-1), 1e-12, None)) / 2.0
    q = np.stack((w, (R[..., 2, 1] - R[..., 1, 2]) / (4 * w), (R[..., 0, 2] - R[..., 2, 0]) / (4 * w),
                  (R[..., 1, 0] - R[..., 0, 1]) / (4 * w)), -1)
    flips = np.cumsum(np.concatenate((np.zeros_like(q[:1, ..., 0]), (q[1:] * q[:-1]).sum(-1) < 0)), axis=0) % 2
    q = np.where(flips[..., None] == 1, -q, q)
    dq = np.gradient(q, time, axis=0)
    s, v, ds, dv = q[..., 0], q[..., 1:], dq[..., 0], dq[..., 1:]
    return 2.0 * (s[..., None] * dv - ds[..., None] * v - np.cross(dv, v))


@pytest.fixture(scope="module")
def human48():
    return human48_walk(6.0, seed=2, orientation_noise=0.005)


@pytest.fixture(scope="module")
def walk(human48):
    return human48[2]


def test_a_gyro_with_orientation_noise_is_no_derivative(walk):
    R, w, t = (torch.from_numpy(x) for x in (walk.orientation, walk.angular_velocity, walk.time))
    assert not bool(derived_rates(R, w, t).any())


@pytest.mark.parametrize("scheme", ["central", "quaternion_gradient"])
def test_rates_differentiated_from_the_orientations_are_told_apart(walk, scheme):
    rates = (angular_velocity_from_orientations(walk.orientation, walk.time) if scheme == "central"
             else quaternion_gradient(walk.orientation, walk.time))
    R, w, t = (torch.from_numpy(x) for x in (walk.orientation, rates, walk.time))
    assert bool(derived_rates(R, w, t).all())


def test_a_velocity_differentiated_from_the_positions_is_told_apart(walk):
    p, t = torch.from_numpy(walk.base_position), torch.from_numpy(walk.time)
    assert bool(derived_velocity(p, torch.from_numpy(np.gradient(walk.base_position, walk.time, axis=0)), t))
    assert not bool(derived_velocity(p, torch.from_numpy(walk.base_linear_velocity) + 0.01 * torch.randn(
        len(walk.time), 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64), t))


def test_the_bvh_reader_declares_derived_rates_and_one_clock(tmp_path):
    path = tmp_path / "walk.bvh"
    path.write_text(bvh_text())
    meta = read(str(path)).meta
    assert meta["angular_velocity"] == "derived" and meta["clock"] == "shared"


def test_on_derived_rates_and_one_clock_no_gyro_family_and_no_late_sensor_is_fitted(human48):
    """The walk as a user's converted file gives it (np.gradient of the quaternions) and declaring one
    clock: every gyro family comes back without a fit, saying why, and so does every sensor delay."""
    model, urdf, walk = human48
    converted = replace(walk, angular_velocity=quaternion_gradient(walk.orientation, walk.time),
                        meta=dict(walk.meta, clock="shared"))
    s = Subject(converted, urdf, model)
    analyse_subjects([s], LINKS, 20.0, False)
    analysis, b = s.current
    assert bool(analysis.derived[b].all())
    train, test = halves(analysis.time)
    found = candidates(analysis, b, train, test, s.urdf, ("gyro_bias", "gyro_scale", "stream_delay", "sensor_delay"))
    assert found and all(c.fit is None for c in found)
    assert {c.kind for c in found} == {"gyro_bias", "gyro_scale", "stream_delay", "sensor_delay"}
    assert all("angular velocity is the orientations' derivative" in c.notes for c in found if c.kind != "sensor_delay")
    assert all("one clock" in c.notes for c in found if c.kind == "sensor_delay")

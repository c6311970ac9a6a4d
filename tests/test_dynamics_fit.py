"""dynamics_fit: the base's residual wrench traced to what the model or the plates lack.

The plates of a synthetic walk (the walking scenario's joint trajectories on Human48, 6 s at 200 Hz)
are the whole base wrench that pinocchio's rnea (an independent library) computes for the motion,
shared between two plates; the body that makes them is Human48's URDF edited as text. Properties:
- a trunk 10 % heavier than torchik's nominal model (its links' <mass> edited) is found, its mass
  fitted within 2 % of the segment's, and nothing else is added;
- a plate's time lag and another's constant centre-of-pressure offset injected into the plates are
  both found, to a millisecond and a millimetre, and no mass is changed;
- a trunk 60 % heavier is refused as implausible, and noise alone adds nothing.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch

from torchik import InputError
from torchik.method.dynamics import low_pass
from torchik.method.models import human_urdf, load_model
from torchik.pipelines.dynamics_effects import HUMAN_SEGMENTS
from torchik.pipelines.dynamics_fit import fit_dynamics
from torchik.synthetic.scenarios import scenario_motion

RATE, CUTOFF = 200.0, 20.0  # fast enough that the derivative's filter leaves the gait's forces whole


def heavier(text: str, links, factor: float) -> str:
    """The URDF text with each link's <mass value> times `factor` (its inertia left as it is)."""
    for name in links:
        text, count = re.subn(rf'(<link name="{name}">\s*<inertial><mass value=")([^"]+)(")',
                              lambda m: f"{m[1]}{float(m[2]) * factor!r}{m[3]}", text)
        assert count == 1, name
    return text


def pinocchio_plates(text: str, model, motion) -> torch.Tensor:
    """[T,2,6] two plates (force; moment about the world origin) sharing the base wrench pinocchio's rnea
    gives for the motion on the URDF `text`, from the velocity low-passed as torchik's trajectory
    dynamics takes it and its central differences."""
    pin = pytest.importorskip("pinocchio")
    reference = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    data = reference.createData()
    joints = [reference.joints[reference.getJointId(name)] for name in model.joint_names]
    iq, iv = [j.idx_q for j in joints], [j.idx_v for j in joints]
    velocity = low_pass(motion.velocity, RATE, CUTOFF)[:, 0]
    acceleration = torch.gradient(velocity, spacing=1 / RATE, dim=0)[0]
    p, R, s = (x[:, 0].numpy() for x in (motion.base_position, motion.base_rotation, motion.joint_positions))
    wrenches = []
    for k in range(len(p)):
        Rb, nu, nu_dot = R[k], velocity[k].numpy(), acceleration[k].numpy()
        q, v, a = np.zeros(reference.nq), np.zeros(reference.nv), np.zeros(reference.nv)
        q[:3], q[3:7], q[iq] = p[k], pin.Quaternion(Rb).coeffs(), s[k]
        v_l, w_l = Rb.T @ nu[:3], Rb.T @ nu[3:6]
        v[:3], v[3:6], v[iv] = v_l, w_l, nu[6:]
        a[:3], a[3:6], a[iv] = Rb.T @ nu_dot[:3] - np.cross(w_l, v_l), Rb.T @ nu_dot[3:6], nu_dot[6:]
        tau = pin.rnea(reference, data, q, v, a)  # the free flyer's wrench: what the contacts exert
        f, n = Rb @ tau[:3], Rb @ tau[3:6]
        wrenches.append(np.concatenate((f, n + np.cross(p[k], f))))
    total = torch.from_numpy(np.array(wrenches))
    share = (0.5 + 0.45 * torch.sin(2 * math.pi * 0.9 * motion.time))[:, None]
    return torch.stack((share * total, (1 - share) * total), 1)


@pytest.fixture(scope="module")
def walk():
    model = load_model("human48")
    return model, scenario_motion("walking", model, duration=6.0, rate=RATE)


def segment_mass(model, name: str) -> float:
    mass = model._tensors.geometry.link_mass[:, 0]
    return sum(float(mass[model.link_names.index(link)]) for link in HUMAN_SEGMENTS[name])


def test_a_heavier_trunk_is_found_within_two_percent(walk):
    model, motion = walk
    plates = pinocchio_plates(heavier(human_urdf(48), HUMAN_SEGMENTS["trunk"], 1.10), model, motion)
    fit = fit_dynamics(model, motion, plates, cutoff=CUTOFF)
    assert [e.name for e in fit.effects] == ["trunk mass"], fit.summary()
    trunk = fit.effects[0]
    assert trunk.relative == pytest.approx(0.10, abs=0.02)
    for (kg,) in trunk.halves:  # each half alone finds it too
        assert kg / segment_mass(model, "trunk") == pytest.approx(0.10, abs=0.02)
    assert fit.before.force > 0.02 and fit.after.force < 1e-3 and fit.after.moment < 1e-3
    assert segment_mass(fit.model, "trunk") == pytest.approx(1.10 * segment_mass(model, "trunk"), rel=0.002)
    assert "trunk mass" in fit.summary()


def test_a_plates_lag_and_a_centre_of_pressure_offset_are_found(walk):
    model, motion = walk
    plates = pinocchio_plates(human_urdf(48), model, motion)
    offset = torch.tensor([0.02, -0.015, 0.0], dtype=torch.float64)
    measured = plates.clone()
    measured[:, 1, 3:] += torch.linalg.cross(offset.expand(len(plates), 3), plates[:, 1, :3])  # plate 2's COP off
    late = torch.cat((measured[:1].expand(5, -1, -1), measured[:-5]))  # the plates 5 samples (25 ms) late
    fit = fit_dynamics(model, motion, late, cutoff=CUTOFF)
    found = {e.name: e for e in fit.effects}
    assert set(found) == {"plates' lag", "plate 2 centre of pressure"}, fit.summary()
    assert found["plates' lag"].value[0] == pytest.approx(0.025, abs=1e-3)
    assert fit.lag == pytest.approx(0.025, abs=1e-3)
    cop = found["plate 2 centre of pressure"].value  # in the plate's plane: x, y of a level plate
    assert cop == pytest.approx((0.02, -0.015), abs=1e-3)
    assert fit.after.force < 1e-3 and fit.after.moment < 1e-3
    inside = slice(40, -40)
    assert (fit.plate_wrenches[inside] - plates[inside]).abs().max() < 0.02 * plates.abs().max()


def test_an_implausible_mass_is_refused_and_noise_adds_nothing(walk):
    model, motion = walk
    plates = pinocchio_plates(heavier(human_urdf(48), HUMAN_SEGMENTS["trunk"], 1.6), model, motion)
    fit = fit_dynamics(model, motion, plates, cutoff=CUTOFF)
    refused = {r.name: r for r in fit.refused}
    assert "trunk mass" in refused and "beyond the plausible" in refused["trunk mass"].reason
    assert "trunk mass" not in {e.name for e in fit.effects}

    exact = pinocchio_plates(human_urdf(48), model, motion)
    noise = torch.randn(exact.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    noisy = exact + noise * torch.tensor([5.0, 5.0, 10.0, 1.0, 1.0, 1.0], dtype=torch.float64)
    quiet = fit_dynamics(model, motion, noisy, cutoff=CUTOFF)
    assert quiet.effects == [], quiet.summary()


def test_bad_input_is_named(walk):
    model, motion = walk
    with pytest.raises(InputError, match="plate_wrenches"):
        fit_dynamics(model, motion, torch.zeros(3, 2, 6, dtype=torch.float64))
    with pytest.raises(InputError, match="segment 'trunk'"):
        fit_dynamics(model, motion, torch.zeros(len(motion.time), 1, 6, dtype=torch.float64),
                     segments={"trunk": ("Spine",)})

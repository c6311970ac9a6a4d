"""OpenSim's inverse dynamics of a torchik model and motion (torchik/io/opensim_model.py); skipped
without opensim (the extra torchik[opensim]).

Properties:
- the OpenSim model built from Human66 (a subject of other dimensions than the template's, and
  Human48) puts every body where torchik's kinematics puts its link, at random postures;
- given the same coordinates, speeds and accelerations (InverseDynamicsSolver, no filtering or
  differentiation of OpenSim's own), OpenSim's generalized forces are torchik's: the joints' torques,
  and the base's force and moment (projected on the base's pin axes), with ground reactions on both
  feet as ExternalLoads. Tolerance 1e-6 N m (N): the solvers agree to 1e-10 without loads; the loads'
  data file holds 10 significant digits, forces of a few hundred N at lever arms of a metre rounded by
  some 1e-7 N m;
- importing torchik and its io package does not import opensim.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import REPO

from torchik import so3
from torchik.method.dynamics import inverse_dynamics
from torchik.method.models import HumanSubject, load_model

osim = pytest.importorskip("opensim")
om = pytest.importorskip("torchik.io.opensim_model")

TOLERANCE = 1e-6  # N m, N: the docstring says why
FEET = ("RightFoot", "LeftFoot")


def random_motion(model, T: int, seed: int):
    """T random states of `model`: base pose, joint angles within +-1 rad, velocities, accelerations."""
    gen = torch.Generator().manual_seed(seed)
    n = model.n_dof
    p = torch.randn(T, 3, generator=gen, dtype=torch.float64)
    R = so3.random_rotation((T,), generator=gen).double()
    s = torch.rand(T, n, generator=gen, dtype=torch.float64) * 2 - 1
    nu = torch.randn(T, 6 + n, generator=gen, dtype=torch.float64)
    nu_dot = 3 * torch.randn(T, 6 + n, generator=gen, dtype=torch.float64)
    return p, R, s, nu, nu_dot


@pytest.fixture(scope="module")
def child():
    """Human66 for a subject of other dimensions than the template's (a child's)."""
    return load_model("human66", HumanSubject(height=1.45, mass=32.0))


def test_bodies_where_torchik_puts_the_links(child):
    p, R, s, nu, nu_dot = random_motion(child, 3, seed=1)
    model = om.opensim_model(child)
    names = om.coordinate_names(child)
    state = model.initSystem()
    motion = om.opensim_motion(p, R, s, nu, nu_dot)
    bodies = om.body_names(child)
    links = [b for b in dict.fromkeys(bodies) if b in child.link_names]
    with torch.no_grad():
        expected = child(p, R, s, tuple(links), jacobian=False)
    for k in range(len(p)):
        for c, name in enumerate(names):
            model.getCoordinateSet().get(name).setValue(state, float(motion.q[k, c]), False)
        model.realizePosition(state)
        for i, link in enumerate(links):
            pose = model.getBodySet().get(link).getTransformInGround(state)
            position = np.array([pose.p().get(j) for j in range(3)])
            rotation = np.array([[pose.R().get(a, b) for b in range(3)] for a in range(3)])
            assert np.abs(position - expected.position[k, i].numpy()).max() < 1e-12
            assert np.abs(rotation - expected.rotation[k, i].numpy()).max() < 1e-12


@pytest.mark.parametrize("name", ["human66", "human48"])
def test_same_forces_as_torchik(name, child, tmp_path):
    model = child if name == "human66" else load_model(name)
    T = 6
    p, R, s, nu, nu_dot = random_motion(model, T, seed=2)
    gen = torch.Generator().manual_seed(3)
    wrenches = 100 * torch.randn(T, len(FEET), 6, generator=gen, dtype=torch.float64)
    expected = inverse_dynamics(model, p, R, s, nu, nu_dot, wrenches, FEET).forces.numpy()
    with torch.no_grad():
        origins = model(p, R, s, FEET, jacobian=False).position.numpy()
    time = 0.01 * np.arange(T)
    loads = om.external_loads(tmp_path / "loads.xml", time, FEET, wrenches.numpy(), origins)
    opensim = om.opensim_model(model)
    om.add_external_loads(opensim, loads)
    motion = om.opensim_motion(p, R, s, nu, nu_dot)
    forces = om.solve(opensim, om.coordinate_names(model), motion, time)
    assert np.abs(forces[:, 6:] - expected[:, 6:]).max() < TOLERANCE
    assert np.abs(forces[:, :6] - om.base_forces(expected[:, :6], motion.q)).max() < TOLERANCE
    assert np.abs(expected[:, 6:]).max() > 10.0  # torques of some size were compared


def test_base_rates_are_the_pins():
    """The base's Euler rates and their derivatives turn back into omega_B and its derivative."""
    p, R, s, nu, nu_dot = random_motion(load_model("human48"), 4, seed=4)
    motion = om.opensim_motion(p, R, s, nu, nu_dot)
    E = om.pin_axes(motion.q[:, 3], motion.q[:, 4])
    assert np.abs(np.einsum("tij,tj->ti", E, motion.u[:, 3:6]) - nu[:, 3:6].numpy()).max() < 1e-12
    assert np.allclose(so3.rpy_to_matrix(torch.from_numpy(motion.q[:, [5, 4, 3]])).numpy(), R.numpy(), atol=1e-12)


def test_opensim_not_imported_with_torchik():
    code = "import sys, torchik, torchik.io, torchik.pipelines.dynamics; assert 'opensim' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)

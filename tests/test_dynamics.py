"""dynamics: the generalized forces of floating-base motions (torchik/method/dynamics/).

Properties:
- they equal pinocchio's recursive Newton-Euler (`pinocchio.rnea`, free flyer, links on fixed joints
  lumped) to 1e-9 N and N m on random states with external wrenches, for Human66, Human48 and iCub,
  once pinocchio's LOCAL base velocity, acceleration and wrench are turned to MIXED, both ways of
  summing over the tree (16 rows: the ancestor matrix; 40: level by level);
- compiled (`CompiledInverseDynamics`, its capture replaced by the traced function itself), in
  chunks with the last one padded, the forces are the eager call's; a model whose links' masses
  are changed (`with_inertial`) moves the weight the base holds by the change;
- standing still without contacts, the base holds the weight, -M g, at the centre of mass mass.py gives;
- an external wrench enters as -J^T w, J the link's MIXED Jacobian of the kinematics;
- a row's forces do not depend on the batch (1 or 64 rows, two ways of composing the tree), nor on
  the other subjects of a stacked model; float32 agrees with float64;
- along a sampled trajectory, the accelerations come from the low-passed velocity.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import REPO

from torchik import InputError, KinematicModel, so3
from torchik.method.dynamics import inverse_dynamics, low_pass, reach, trajectory_dynamics
from torchik.method.kinematics.mass import centre_of_mass, total_mass
from torchik.method.models import HumanSubject, load_model
from torchik.synthetic.motion import periodic_motion

MODELS = ["human66", "human48", "icub"]
# the base, links on movable joints, and links fixed at an offset to another (lumped into it)
WRENCH_LINKS = {
    "human66": ("Pelvis", "RightFoot", "LeftHand", "RightHandCOM"),
    "human48": ("Pelvis", "LeftFoot", "RightHand", "LeftHandCOM"),
    "icub": ("root_link", "r_sole", "l_hand", "r_hip_3"),
}


def urdf_path(name: str):
    if name == "icub":
        pytest.importorskip("icub_models")
        from torchik.method.models import icub_urdf_path

        return icub_urdf_path()
    return REPO / "models" / f"{name}.urdf"


@pytest.fixture(scope="module", params=MODELS)
def model_and_path(request):
    """(the model, its URDF, the links the tests push on)"""
    path = urdf_path(request.param)
    return KinematicModel.from_urdf(path), path, WRENCH_LINKS[request.param]


def random_state(model: KinematicModel, batch: int, seed: int, links: int = 0):
    """Random base poses, joint angles within the limits, velocities, accelerations [B,6+n] and, for
    `links` links, external wrenches [B,L,6] (forces of tens of N, moments of N m)."""
    g = torch.Generator().manual_seed(seed)
    kw = dict(generator=g, dtype=torch.float64)
    n = model.n_dof
    p, R = torch.randn(batch, 3, **kw), so3.random_rotation((batch,), g)
    s = model.lower + (model.upper - model.lower) * torch.rand(batch, n, **kw)
    velocity, acceleration = torch.randn(batch, 6 + n, **kw), 3.0 * torch.randn(batch, 6 + n, **kw)
    wrenches = torch.randn(batch, links, 6, **kw) * torch.tensor([30.0, 30.0, 30.0, 3.0, 3.0, 3.0], dtype=torch.float64)
    return p, R, s, velocity, acceleration, wrenches


def pinocchio_forces(path, model: KinematicModel, p, R, s, velocity, acceleration, wrenches, links):
    """pinocchio's rnea [B,6+n] in torchik's convention. pinocchio's free flyer moves with the base's
    velocity in the base frame, v_l = R^T p_dot, w_l = R^T omega; its acceleration is their derivative,
    a_l = R^T p_ddot - w_l x v_l, alpha_l = R^T omega_dot; its wrench (f_l; n_l) is in the base frame,
    about its origin: f = R f_l, n = R n_l (so that f_l . v_l + n_l . w_l = f . p_dot + n . omega). An
    external wrench is given to the joint that carries the link, in that joint's frame, about its origin."""
    pin = pytest.importorskip("pinocchio")
    reference = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = reference.createData()
    joints = [reference.joints[reference.getJointId(name)] for name in model.joint_names]
    iq, iv = [j.idx_q for j in joints], [j.idx_v for j in joints]
    frames = [reference.getFrameId(link) for link in links]
    out = []
    for b in range(p.shape[0]):
        Rb = R[b].numpy()
        q, v, a = np.zeros(reference.nq), np.zeros(reference.nv), np.zeros(reference.nv)
        q[:3], q[3:7], q[iq] = p[b].numpy(), pin.Quaternion(Rb).coeffs(), s[b].numpy()
        v_l, w_l = Rb.T @ velocity[b, :3].numpy(), Rb.T @ velocity[b, 3:6].numpy()
        v[:6], v[iv] = np.concatenate((v_l, w_l)), velocity[b, 6:].numpy()
        a[:3] = Rb.T @ acceleration[b, :3].numpy() - np.cross(w_l, v_l)
        a[3:6], a[iv] = Rb.T @ acceleration[b, 3:6].numpy(), acceleration[b, 6:].numpy()
        pin.framesForwardKinematics(reference, data, q)
        fext = pin.StdVec_Force()
        for _ in range(reference.njoints):
            fext.append(pin.Force.Zero())
        for frame, (f, n) in zip(frames, wrenches[b].reshape(-1, 2, 3).numpy()):
            joint = reference.frames[frame].parentJoint
            placement = data.oMi[joint]
            moment = n + np.cross(data.oMf[frame].translation - placement.translation, f)
            fext[joint] = fext[joint] + pin.Force(placement.rotation.T @ f, placement.rotation.T @ moment)
        tau = pin.rnea(reference, data, q, v, a, fext)
        out.append(np.concatenate((Rb @ tau[:3], Rb @ tau[3:6], tau[iv])))
    return np.array(out)


@pytest.mark.parametrize("batch", [16, 40])  # the sums over the tree by the ancestor matrix, then level by level
def test_the_forces_equal_pinocchios_recursive_newton_euler(model_and_path, batch):
    model, path, links = model_and_path
    p, R, s, velocity, acceleration, wrenches = random_state(model, batch, seed=1, links=len(links))
    ours = inverse_dynamics(model, p, R, s, velocity, acceleration, wrenches, links).forces
    theirs = pinocchio_forces(path, model, p, R, s, velocity, acceleration, wrenches, links)
    assert np.abs(theirs).max() > 50.0  # forces of a real motion, not a vanishing one
    assert np.abs(ours.numpy() - theirs).max() <= 1e-9


def test_standing_still_the_base_holds_the_weight_at_the_centre_of_mass(model_and_path):
    """Zero velocity and acceleration, no contact: the base wrench is (-M g; (c - p_B) x -M g), no
    joint turns the body's weight into work, and the torques are what holds each subtree up."""
    model, _, _ = model_and_path
    p, R, s, velocity, _, _ = random_state(model, 8, seed=2)
    zero = torch.zeros_like(velocity)
    out = inverse_dynamics(model, p, R, s, zero, zero)
    weight = torch.tensor([0.0, 0.0, 9.81], dtype=torch.float64) * total_mass(model)
    com = centre_of_mass(model, p, R, s, jacobian=False).position
    assert (out.base_wrench[:, :3] - weight).abs().max() <= 1e-9
    assert (out.base_wrench[:, 3:] - torch.linalg.cross(com - p, weight.expand_as(p))).abs().max() <= 1e-9
    assert out.joint_powers.abs().max() == 0.0
    # the torques equal those of gravity alone through the centre-of-mass Jacobian: J_c^T (-M g)
    J = centre_of_mass(model, p, R, s).jacobian
    assert (out.forces - (J.transpose(1, 2) @ weight)).abs().max() <= 1e-9


def test_an_external_wrench_enters_through_the_links_jacobian(model_and_path):
    """tau(w) - tau(0) = -sum_l J_l^T w_l: the wrenches are (force; moment about the link's origin)
    in world axes, the frame of the kinematics' MIXED Jacobians."""
    model, _, links = model_and_path
    p, R, s, velocity, acceleration, wrenches = random_state(model, 8, seed=3, links=len(links))
    pushed = inverse_dynamics(model, p, R, s, velocity, acceleration, wrenches, links).forces
    free = inverse_dynamics(model, p, R, s, velocity, acceleration).forces
    J = model(p, R, s, links).jacobian  # [B,L,6,6+n]
    expected = -(J.transpose(2, 3) @ wrenches.unsqueeze(-1)).squeeze(-1).sum(1)
    assert (pushed - free - expected).abs().max() <= 1e-9
    # every link's wrench, default order: the same as naming the links
    everywhere = torch.zeros(8, len(model.link_names), 6, dtype=torch.float64)
    everywhere[:, [model.link_names.index(link) for link in links]] = wrenches
    assert torch.allclose(inverse_dynamics(model, p, R, s, velocity, acceleration, everywhere).forces, pushed,
                          rtol=0.0, atol=1e-10)


def test_a_row_does_not_depend_on_the_batch():
    """64 rows (the tree composed level by level) and each row alone (pointer jumping): the same forces."""
    model = load_model("human66")
    p, R, s, velocity, acceleration, _ = random_state(model, 64, seed=4)
    batch = inverse_dynamics(model, p, R, s, velocity, acceleration).forces
    for b in (0, 17, 63):
        row = slice(b, b + 1)
        alone = inverse_dynamics(model, p[row], R[row], s[row], velocity[row], acceleration[row]).forces
        assert (alone - batch[row]).abs().max() <= 1e-10


def test_stacked_subjects_each_use_their_own_masses():
    subjects = [HumanSubject(height=1.62, mass=55.0), HumanSubject(height=1.91, mass=96.0)]
    models = [load_model("human48", subject=subject) for subject in subjects]
    stacked = KinematicModel.stack(models)
    p, R, s, velocity, acceleration, _ = random_state(models[0], 2, seed=5)
    together = inverse_dynamics(stacked, p, R, s, velocity, acceleration).forces
    for b, model in enumerate(models):
        row = slice(b, b + 1)
        alone = inverse_dynamics(model, p[row], R[row], s[row], velocity[row], acceleration[row]).forces
        assert (together[row] - alone).abs().max() <= 1e-10
    assert (together[0] - together[1]).abs().max() > 10.0  # different bodies, different forces


def test_float32_agrees_with_float64():
    model = load_model("human48")
    links = WRENCH_LINKS["human48"]
    state = random_state(model, 32, seed=6, links=len(links))
    exact = inverse_dynamics(model, *state, links).forces
    single = inverse_dynamics(model.to(torch.float32), *(x.float() for x in state), links).forces
    assert single.dtype == torch.float32
    assert (single.double() - exact).abs().max() <= 1e-5 * exact.abs().max()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_the_gpu_as_on_the_cpu():
    model = load_model("human66")
    links = WRENCH_LINKS["human66"]
    state = random_state(model, 256, seed=7, links=len(links))
    cpu = inverse_dynamics(model, *state, links).forces
    gpu = inverse_dynamics(model.to(device="cuda"), *(x.cuda() for x in state), links).forces
    assert (gpu.cpu() - cpu).abs().max() <= 1e-9


def test_bad_input_is_named():
    model = load_model("human48")
    p, R, s, velocity, acceleration, wrenches = random_state(model, 4, seed=8, links=2)
    with pytest.raises(InputError, match="acceleration"):
        inverse_dynamics(model, p, R, s, velocity, acceleration[:, :-1])
    with pytest.raises(InputError, match="external_wrenches"):
        inverse_dynamics(model, p, R, s, velocity, acceleration, wrenches, ("Pelvis", "Head", "L5"))


def test_along_a_trajectory_the_accelerations_are_the_low_passed_velocitys_derivative():
    """A smooth motion (1 and 2 Hz) at 200 Hz, low-passed at 20 Hz: away from the ends, the forces of
    the exact velocities' central differences, to 1e-4 of their size."""
    model = load_model("human48")
    motion = periodic_motion(model, duration=3.0, rate=200.0, batch=2)
    out = trajectory_dynamics(model, motion, cutoff=20.0)
    T, B = motion.velocity.shape[:2]
    acceleration = torch.gradient(motion.velocity, spacing=1 / 200.0, dim=0)[0]
    flat = lambda x: x.flatten(0, 1)  # noqa: E731
    expected = inverse_dynamics(model, flat(motion.base_position), flat(motion.base_rotation),
                                flat(motion.joint_positions), flat(motion.velocity), flat(acceleration)).forces
    expected = expected.reshape(T, B, -1)
    inside = slice(40, -40)  # the filter's ends (a few samples of 1 / cutoff) reflect their last values
    assert out.forces.shape == (T, B, 6 + model.n_dof)
    assert (out.forces[inside] - expected[inside]).abs().max() <= 1e-4 * expected.abs().max()


def test_the_low_pass_keeps_a_slow_sine_and_removes_a_fast_one():
    t = torch.arange(0.0, 4.0, 0.01, dtype=torch.float64)
    slow = torch.sin(2 * math.pi * t)
    filtered = low_pass((slow + 0.3 * torch.sin(2 * math.pi * 40.0 * t))[:, None], 100.0, 6.0)[:, 0]
    gain = 1 / (1 + (1 / 6.0) ** 4)  # at 1 Hz; at 40 Hz, 5e-4
    assert (filtered - gain * slow)[50:-50].abs().max() <= 2e-4


def test_the_low_pass_reach_holds_nine_tenths_of_its_weight():
    """reach(rate, cutoff): the samples either side holding all but 10 % of |impulse response|; a lower
    cut-off reaches farther, a higher rate in more samples."""
    k = reach(100.0, 6.0)
    impulse = torch.zeros(201, dtype=torch.float64)
    impulse[100] = 1.0
    weight = low_pass(impulse, 100.0, 6.0).abs()
    inside = lambda k: float(weight[100 - k:101 + k].sum() / weight.sum())  # noqa: E731
    assert k == 6 and inside(k) >= 0.9 > inside(k - 1)
    assert reach(100.0, 3.0) > k and reach(1000.0, 6.0) > 9 * k


def test_the_residuals_frames_keep_clear_of_the_uncovered_by_the_reach():
    """residual_frames: the covered frames with a plate loaded, less those within the reach of one the
    plates do not cover or do not know (NaN)."""
    from types import SimpleNamespace

    from torchik.pipelines.dynamics import residual_frames

    T = 100
    covered = np.zeros(T, dtype=bool)
    covered[20:80] = True
    wrenches = np.ones((T, 2, 6))
    wrenches[50] = np.nan  # a plate two feet shared
    d = SimpleNamespace(time=np.arange(T) / 100.0, covered=covered, wrenches=wrenches, wrench_links=("R", "L"),
                        stance=np.ones((T, 2), dtype=bool), notes=dict(cutoff_hz=6.0))
    frames = residual_frames(d)
    assert np.flatnonzero(frames).tolist() == list(range(26, 44)) + list(range(57, 74))


def test_a_trajectory_at_an_uneven_rate_is_refused():
    model = load_model("human48")
    motion = periodic_motion(model, duration=0.5, rate=100.0)
    time = motion.time.clone()
    time[10] += 0.003
    with pytest.raises(InputError, match="evenly spaced"):
        trajectory_dynamics(model, replace(motion, time=time))


def test_a_trajectory_in_chunks_and_with_wrenches_is_each_samples_forces(monkeypatch):
    """Chunks of 3 samples (2 rows each), a stacked model (a sample per call), wrenches [T,B,L,6]:
    each sample's forces as `inverse_dynamics` gives them for that sample's state."""
    from torchik.method.dynamics import trajectory as module

    monkeypatch.setattr(module, "ROWS", 6)
    models = [load_model("human48", subject=HumanSubject(height=h, mass=m)) for h, m in ((1.6, 60.0), (1.8, 80.0))]
    links = WRENCH_LINKS["human48"]
    motion = periodic_motion(models[0], duration=0.2, rate=100.0, batch=2)
    T = motion.time.shape[0]
    wrenches = torch.randn(T, 2, len(links), 6, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
    velocity = low_pass(motion.velocity, 100.0)
    acceleration = torch.gradient(velocity, spacing=0.01, dim=0)[0]
    for model in (models[0], KinematicModel.stack(models)):
        out = trajectory_dynamics(model, motion, wrenches, links)
        for k in (0, 7, T - 1):
            sample = inverse_dynamics(model, motion.base_position[k], motion.base_rotation[k],
                                      motion.joint_positions[k], velocity[k], acceleration[k], wrenches[k], links)
            assert (out.forces[k] - sample.forces).abs().max() <= 1e-10
            assert torch.equal(out.joint_powers[k], out.joint_torques[k] * velocity[k, :, 6:])


def test_compiled_in_chunks_gives_the_eager_forces(monkeypatch):
    """The chunks' plumbing (40 rows in chunks of 16, the last padded), with the traced function as the
    compiled one: TorchInductor's own compilation is test_capture's."""
    from torchik.method import capture as capture_module
    from torchik.method.dynamics import compiled as module

    monkeypatch.setattr(module, "capture", lambda fn, inputs: _traced(capture_module, fn))
    model = load_model("human48")
    links = WRENCH_LINKS["human48"]
    p, R, s, velocity, acceleration, wrenches = random_state(model, 40, seed=10, links=len(links))
    expected = inverse_dynamics(model, p, R, s, velocity, acceleration, wrenches, links).forces
    fn = module.CompiledInverseDynamics(model, 40, links, chunk=16)
    assert fn.chunk == 16 and fn.compile_seconds >= 0.0
    assert (fn(p, R, s, velocity, acceleration, wrenches) - expected).abs().max() <= 1e-10
    with pytest.raises(InputError, match="compiled for 40 rows"):
        fn(p[:8], R[:8], s[:8], velocity[:8], acceleration[:8], wrenches[:8])
    with pytest.raises(InputError, match="wrench_links"):
        fn(p, R, s, velocity, acceleration)


def _traced(capture_module, fn):
    """fn as the capture traces it (each level's tensors made afresh), not compiled."""
    def run(*inputs):
        capture_module._tracing = True
        try:
            return fn(*inputs)
        finally:
            capture_module._tracing = False
    return run


def test_a_heavier_link_makes_the_base_hold_more_weight():
    model = load_model("human48")
    mass = model._tensors.geometry.link_mass[:, 0].clone()
    mass[model.link_names.index("T8")] += 2.0
    heavier = model.with_inertial(mass=mass)
    p, R, s, velocity, _, _ = random_state(model, 4, seed=11)
    zero = torch.zeros_like(velocity)
    gap = (inverse_dynamics(heavier, p, R, s, zero, zero).base_wrench
           - inverse_dynamics(model, p, R, s, zero, zero).base_wrench)
    assert torch.allclose(gap[:, :3], torch.tensor([0.0, 0.0, 2.0 * 9.81], dtype=torch.float64), atol=1e-10)
    assert float(total_mass(heavier)) == pytest.approx(float(total_mass(model)) + 2.0)
    with pytest.raises(InputError, match="mass must be"):
        model.with_inertial(mass=mass[:-1])

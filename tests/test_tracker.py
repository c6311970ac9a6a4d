"""tracker: convergence at the rate K sets, second-order tracking, limits never crossed, batches equal singles."""

import math
import warnings

import pytest
import torch

from torchik import InputError, KinematicModel, so3
from torchik.method.metrics import orientation_error
from torchik.method.models import TRACKED_LINKS, HumanSubject, load_model
from torchik.method.state import State
from torchik.method.targets import Targets
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.motion import periodic_motion, targets_from_motion

F64 = dict(dtype=torch.float64)


def rigid_body() -> KinematicModel:
    return KinematicModel.from_urdf("<robot name='body'><link name='body'/></robot>")


def orientation_only(R: torch.Tensor) -> Targets:
    """Targets for a lone body: one constant orientation, no position target. R: [B,3,3]."""
    B = R.shape[0]
    return Targets(torch.zeros(B, 0, 3, **F64), torch.zeros(B, 0, 3, **F64), R[:, None], torch.zeros(B, 1, 3, **F64))


def angle_after(K: float, dt: float, steps: int, R0: torch.Tensor, target: torch.Tensor, scheme="midpoint") -> torch.Tensor:
    """Error angle [steps+1, B] of a lone body tracking a constant orientation."""
    body = rigid_body()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the unstable case warns, as it should
        tracker = DynamicalIK(body, ["body"], position_links=[], orientation_gain=K, dt=dt, scheme=scheme,
                              rotation_integrator="exp")
    B = R0.shape[0]
    tracker.reset(State(torch.zeros(B, 3, **F64), R0, torch.zeros(B, 0, **F64), torch.zeros(B, 6, **F64)))
    angles = [so3.log(R0.transpose(-1, -2) @ target).norm(dim=-1)]
    for _ in range(steps):
        state, _ = tracker.step(orientation_only(target))
        angles.append(so3.log(state.base_rotation.transpose(-1, -2) @ target).norm(dim=-1))
    return torch.stack(angles)


def random_start(B: int, seed: int, max_angle: float):
    g = torch.Generator().manual_seed(seed)
    target = so3.random_rotation((B,), g)
    axis = torch.randn(B, 3, generator=g, **F64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = max_angle * torch.rand(B, generator=g, **F64)
    return so3.exp(axis * angle[:, None]) @ target, target


@pytest.mark.parametrize("K_dt", [0.02, 0.1, 0.2])
def test_a_single_link_converges_at_the_rate_K_sets(K_dt):
    """Continuous law: d(theta)/dt = -K sin(theta), so tan(theta/2) = tan(theta0/2) exp(-K t).

    The discrete feedback is forward Euler: each step multiplies a small error by 1 - K dt exactly
    (checked below to 1e-9), against exp(-K dt) in continuous time. Over the half-life the two
    differ by less than 10 % for K dt <= 0.2 (the gap grows as exp(-K t K dt / 2) beyond)."""
    K, dt = 10.0, K_dt / 10.0
    R0, target = random_start(16, seed=1, max_angle=math.radians(170))
    half_life_steps = round(math.log(2) / (K * dt))
    theta = angle_after(K, dt, half_life_steps, R0, target)
    t = half_life_steps * dt
    predicted = 2 * torch.atan(torch.tan(theta[0] / 2) * math.exp(-K * t))
    assert float(((torch.sin(theta[-1]) - torch.sin(predicted)).abs() / torch.sin(predicted)).max()) < 0.10
    # small angles: the per-step factor is exactly 1 - K dt
    R0, target = random_start(4, seed=2, max_angle=1e-4)
    small = angle_after(K, dt, 5, R0, target)
    assert torch.allclose(small[1:] / small[:-1], torch.full_like(small[1:], 1 - K * dt), atol=1e-8)


def test_with_zero_gain_the_error_stays_constant():
    R0, target = random_start(8, seed=3, max_angle=2.0)
    theta = angle_after(0.0, 0.01, 100, R0, target)
    assert torch.allclose(theta, theta[0].expand_as(theta), atol=1e-12)


@pytest.mark.parametrize("scheme", ["midpoint", "paper"])
def test_beyond_the_stability_bound_the_error_grows(scheme):
    R0, target = random_start(4, seed=4, max_angle=0.01)
    with pytest.warns(UserWarning, match="stability bound"):
        DynamicalIK(rigid_body(), ["body"], position_links=[], orientation_gain=250.0, dt=0.01, scheme=scheme)
    theta = angle_after(250.0, 0.01, 20, R0, target, scheme)  # K dt = 2.5 > 2
    assert bool((theta[-1] > 10 * theta[0]).all())
    stable = angle_after(150.0, 0.01, 20, R0, target, scheme)  # K dt = 1.5 < 2 still converges
    assert bool((stable[-1] < 1e-3 * stable[0]).all())


def static_pose_targets(model, links, seed):
    g = torch.Generator().manual_seed(seed)
    p = torch.tensor([[0.1, -0.2, 0.9]], **F64)
    R = so3.exp(torch.tensor([[0.2, -0.1, 0.5]], **F64))
    s = 0.4 * torch.randn(1, model.n_dof, generator=g, **F64)
    kin = model(p, R, s, links, jacobian=False)
    targets = Targets(kin.position[:, :1], torch.zeros(1, 1, 3, **F64), kin.rotation, torch.zeros(1, len(links), 3, **F64))
    return targets, s


def test_human66_converges_to_a_static_pose_within_one_second():
    model, links = load_model("human66"), TRACKED_LINKS["human66"]
    targets, _ = static_pose_targets(model, links, seed=0)
    tracker = DynamicalIK(model, links, position_gain=20.0, orientation_gain=20.0, dt=0.01)
    tracker.reset(batch=1)
    for _ in range(100):  # 1 s at 100 Hz
        state, _ = tracker.step(targets)
    kin = model(state.base_position, state.base_rotation, state.joint_positions, links, jacobian=False)
    assert float(orientation_error(targets.rotation, kin.rotation).mean()) < 1e-6


def tracking_error(scheme: str, rate: int, model, links, motion_seed=0, **kw) -> float:
    motion = periodic_motion(model, 3.0, rate, seed=motion_seed)
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, position_gain=20.0, orientation_gain=20.0, dt=1.0 / rate, scheme=scheme, **kw)
    trajectory = tracker.run(sequence, initial=motion.state(0))
    after = motion.time >= 1.0  # after the transient
    return float((trajectory.joint_positions - motion.joint_positions)[after].abs().max())


def test_exact_targets_are_tracked_to_second_order_by_default_and_first_order_by_the_paper_scheme():
    model, links = load_model("human66"), TRACKED_LINKS["human66"]
    default_100, default_200 = (tracking_error("midpoint", r, model, links) for r in (100, 200))
    paper_100, paper_200 = (tracking_error("paper", r, model, links) for r in (100, 200))
    assert default_100 < 1e-4
    assert 3.5 < default_100 / default_200 < 4.6  # second order
    assert 1.8 < paper_100 / paper_200 < 2.2  # first order
    assert paper_100 > 100 * default_100


def beyond_limits_motion(model, steps, rate, seed):
    """A motion whose joints swing 1.2 rad about zero, well past most limits."""
    free = model.to()
    free.lower = torch.full_like(model.lower, -10.0)
    free.upper = torch.full_like(model.upper, 10.0)
    return periodic_motion(free, steps / rate, rate, joint_amplitude=1.2, seed=seed)


@pytest.mark.parametrize("name", ["human48", "icub"])
def test_joint_and_coupled_limits_are_never_crossed(name):
    model, links = load_model(name), TRACKED_LINKS[name]
    motion = beyond_limits_motion(model, 2000, 100, seed=5)
    sequence = targets_from_motion(model, motion, links)
    start = model.zero_configuration(1)
    s0 = ((model.lower + model.upper) / 2).clamp(-0.3, 0.3)[None].clone()
    if name == "icub":
        s0[0, [model.joint_names.index(j) for j in ("r_shoulder_roll", "l_shoulder_roll")]] = 0.6
        A, b = model.linear_limits.A, model.linear_limits.b
        assert bool((s0 @ A.T <= b).all())
    initial = State(start[0] + torch.tensor([0.0, 0.0, 0.9], **F64), start[1], s0, torch.zeros(1, 6 + model.n_dof, **F64))
    tracker = DynamicalIK(model, links, position_gain=10.0, orientation_gain=10.0, dt=0.01)
    trajectory = tracker.run(sequence, initial=initial)
    s = trajectory.joint_positions[:, 0]  # [T,n]
    assert len(s) == 2001
    assert float((s - model.upper).max()) <= 1e-6 and float((model.lower - s).max()) <= 1e-6
    touched = ((s - model.upper).abs() < 1e-3) | ((s - model.lower).abs() < 1e-3)
    assert bool(touched.any())  # the targets really pushed against the limits
    if name == "icub":
        assert float((s @ A.T - b).max()) <= 1e-6
    assert int(trajectory.diagnostics["active_constraints"].max()) > 0


def test_outputs_are_orthonormal_whichever_integrator():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 1.0, 100)
    sequence = targets_from_motion(model, motion, links)
    eye = torch.eye(3, **F64)
    for integrator, rho in (("baumgarte", 100.0), ("baumgarte", 0.0), ("exp", 0.0)):
        tracker = DynamicalIK(model, links, dt=0.01, rotation_integrator=integrator, baumgarte_gain=rho)
        trajectory = tracker.run(sequence)
        R = trajectory.base_rotation
        assert float((R.transpose(-1, -2) @ R - eye).abs().max()) < 1e-12
        links_R = model(trajectory.base_position[-1], R[-1], trajectory.joint_positions[-1], links, jacobian=False).rotation
        assert float((links_R.transpose(-1, -2) @ links_R - eye).abs().max()) < 1e-12


def test_a_batch_of_8_subjects_equals_8_single_runs(monkeypatch):
    from torchik.method.structure import BatchSetup

    monkeypatch.setattr(BatchSetup, "TREE_FROM", 8)  # the batch solved on the tree's structure
    subjects = [HumanSubject(height=1.5 + 0.05 * i, mass=55 + 3 * i) for i in range(8)]
    models = [load_model("human48", s) for s in subjects]
    stacked = KinematicModel.stack(models)
    links = TRACKED_LINKS["human48"]
    sequences = [targets_from_motion(m, periodic_motion(m, 0.5, 100, seed=i), links) for i, m in enumerate(models)]
    cat = lambda name: torch.cat([getattr(s, name) for s in sequences], dim=1)  # noqa: E731
    from torchik.method.state import TargetSequence

    batch = TargetSequence(sequences[0].time, cat("position"), cat("linear_velocity"), cat("rotation"),
                           cat("angular_velocity"))
    # one backend for both: the batched one, structured for the batch and dense for one subject
    together = DynamicalIK(stacked, links, dt=0.01, backend="batched").run(batch)
    for i, (model, sequence) in enumerate(zip(models, sequences)):
        alone = DynamicalIK(model, links, dt=0.01, backend="batched").run(sequence)
        assert torch.allclose(together.joint_positions[:, i], alone.joint_positions[:, 0], atol=1e-10)
        assert torch.allclose(together.base_rotation[:, i], alone.base_rotation[:, 0], atol=1e-10)


def test_nan_targets_are_dropped_counted_and_the_state_stays_finite():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 0.5, 100, batch=2)
    sequence = targets_from_motion(model, motion, links)
    sequence.rotation[10:20, 0, 3] = float("nan")  # subject 0 loses one sensor for 0.1 s
    sequence.position[15, 1, 0] = float("inf")
    trajectory = DynamicalIK(model, links, dt=0.01).run(sequence, initial=None)
    dropped = trajectory.diagnostics["dropped"]
    assert dropped[10:20, 0].tolist() == [1] * 10 and int(dropped[15, 1]) == 1 and int(dropped.sum()) == 11
    assert bool(torch.isfinite(trajectory.joint_positions).all())
    clean = DynamicalIK(model, links, dt=0.01).run(targets_from_motion(model, motion, links))
    # the other subject is untouched by subject 0's gap (until its own dropped sample)
    assert torch.equal(trajectory.joint_positions[:15, 1], clean.joint_positions[:15, 1])


def test_an_infeasible_step_falls_back_and_says_so():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    contradictory = model.to()
    from torchik.method.kinematics import LinearLimits

    A = torch.zeros(2, model.n_dof, **F64)
    A[0, 0], A[1, 0] = 1.0, -1.0  # s_0 <= -0.5 and s_0 >= 0.5: no configuration satisfies both
    contradictory.linear_limits = LinearLimits(A, torch.tensor([-0.5, -0.5], **F64), ("a", "b"))
    targets, _ = static_pose_targets(model, links, seed=1)
    tracker = DynamicalIK(contradictory, links, dt=0.01)
    tracker.reset(batch=1)
    state, diagnostics = tracker.step(targets)
    assert not bool(diagnostics.solved[0])
    assert all(bool(torch.isfinite(t).all()) for t in vars(state).values())


def test_jittered_timestamps_are_honoured():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    g = torch.Generator().manual_seed(7)
    dt = 0.01 * (1 + 0.3 * (2 * torch.rand(300, generator=g, **F64) - 1))
    t = torch.cat((torch.zeros(1, **F64), dt.cumsum(0)))
    fine = periodic_motion(model, float(t[-1]) + 0.01, 10000)
    idx = (t * 10000).round().long()
    from torchik.synthetic.motion import Motion

    motion = Motion(fine.time[idx], fine.base_position[idx], fine.base_rotation[idx], fine.joint_positions[idx],
                    fine.velocity[idx])
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, position_gain=20.0, orientation_gain=20.0, dt=0.01)
    honoured = tracker.run(sequence, initial=motion.state(0))
    after = motion.time >= 1.0
    error = float((honoured.joint_positions - motion.joint_positions)[after].abs().max())
    assert error < 1e-3
    # the same targets stepped with the nominal dt instead of the timestamps drift far more
    from torchik.method.state import TargetSequence

    uniform = TargetSequence(torch.arange(len(t), **F64) * 0.01, sequence.position, sequence.linear_velocity,
                             sequence.rotation, sequence.angular_velocity)
    tracker = DynamicalIK(model, links, position_gain=20.0, orientation_gain=20.0, dt=0.01)
    ignored = tracker.run(uniform, initial=motion.state(0))
    assert float((ignored.joint_positions - motion.joint_positions)[after].abs().max()) > 10 * error


def test_bad_configuration_is_refused_with_the_valid_choices():
    model = load_model("human48")
    with pytest.raises(InputError, match="valid: midpoint, paper"):
        DynamicalIK(model, ["Pelvis"], scheme="rk4")
    with pytest.raises(InputError, match="reset"):
        DynamicalIK(model, ["Pelvis"]).step(None)


def test_history_is_not_aliased_to_the_callers_buffers():
    """A caller that refills one target buffer in place every step gets the same result as fresh tensors."""
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 0.5, 100)
    sequence = targets_from_motion(model, motion, links)
    fresh = DynamicalIK(model, links, dt=0.01).run(sequence, initial=motion.state(0))
    tracker = DynamicalIK(model, links, dt=0.01)
    tracker.reset(motion.state(0))
    buffer = Targets(*(t.clone() for t in vars(sequence[0]).values()))
    for k in range(len(sequence)):
        for name, value in vars(sequence[k]).items():
            getattr(buffer, name).copy_(value)
        state, _ = tracker.step(buffer)  # samples at the nominal rate: run() steps them with the nominal dt
    assert torch.equal(state.joint_positions, fresh.joint_positions[-1])


@pytest.mark.parametrize("scheme", ["midpoint", "paper"])
def test_the_steps_mnte_is_the_reports_one_step_later(scheme):
    """One MNTE: the step's diagnostic (the state at the step's start against the targets of that
    instant) equals the report's (the estimate at t_k against the targets at t_k) one step later."""
    from torchik.io import recording_targets
    from torchik.method.settings import TrackerSettings
    from torchik.pipelines.evaluation import tracking_errors
    from torchik.synthetic.scenarios import scenario

    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    recording = scenario("walking", load_model("human66"), links, duration=1.0, rate=100.0)
    sequence = recording_targets(recording, links)
    trajectory = DynamicalIK(model, links, settings=TrackerSettings(scheme=scheme)).run(sequence)
    step = trajectory.diagnostics["mnte"][1:, 0]
    report = tracking_errors(model, trajectory, sequence, links, scheme)["mnte"][:-1, 0]
    assert float(step.min()) > 1e-6  # Human48 cannot reach Human66's targets: errors well above rounding
    assert torch.allclose(step, report, rtol=1e-9, atol=0.0)

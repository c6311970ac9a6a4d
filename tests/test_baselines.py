"""baselines: whole-body and pair-wise instantaneous IK converge to reachable static targets, stay
within the joint and coupled limits, solve a batch's subjects independently, and drop missing targets."""

import pytest
import torch

from torchik.errors import InputError
from torchik.method import so3
from torchik.method.baselines import PairwiseIK, WholeBodyIK, central_velocity
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import State
from torchik.method.targets import Targets

METHODS = {"whole-body": WholeBodyIK, "pair-wise": PairwiseIK}


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def models():
    return {name: load_model(name) for name in ("human66", "human48", "icub")}


def pose_targets(model, links, s, seed):
    """Targets of configuration s [B,n] with a random base pose: reachable by construction."""
    g = torch.Generator().manual_seed(seed)
    B = s.shape[0]
    p = torch.randn(B, 3, generator=g, dtype=torch.float64) * 0.2 + torch.tensor([0.0, 0.0, 0.9], dtype=torch.float64)
    R = so3.exp(0.3 * torch.randn(B, 3, generator=g, dtype=torch.float64))
    kin = model(p, R, s, links, jacobian=False)
    zeros = torch.zeros(B, len(links), 3, dtype=torch.float64)
    return Targets(kin.position[:, :1], zeros[:, :1], kin.rotation, zeros)


def inside_configuration(model, seed, batch=1):
    """A configuration well inside every limit: near mid-range, and for iCub inside A s <= b."""
    g = torch.Generator().manual_seed(seed)
    middle = ((model.lower + model.upper) / 2).clamp(-0.4, 0.4)
    s = middle + 0.2 * torch.randn(batch, model.n_dof, generator=g, dtype=torch.float64)
    s = torch.minimum(torch.maximum(s, model.lower + 0.05), model.upper - 0.05)
    if model.linear_limits is not None:
        for j in ("r_shoulder_roll", "l_shoulder_roll"):
            s[:, model.joint_names.index(j)] = 0.8
        assert bool((s @ model.linear_limits.A.T <= model.linear_limits.b - 1e-3).all())
    return s


def start_of(model, p, batch=1):
    p0, R0, s0 = model.zero_configuration(batch)
    return State(p.clone(), R0, s0, torch.zeros(batch, 6 + model.n_dof, dtype=torch.float64))


def excess(model, s):
    """How far s [B,n] lies beyond a joint or coupled limit (<= 0: inside)."""
    out = torch.maximum(s - model.upper, model.lower - s).amax()
    if model.linear_limits is not None:
        out = torch.maximum(out, (s @ model.linear_limits.A.T - model.linear_limits.b).amax())
    return float(out)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["human66", "human48", "icub"])
def test_converges_to_a_reachable_static_target(models, name, method):
    model, links = models[name], TRACKED_LINKS[name]
    targets = pose_targets(model, links, inside_configuration(model, seed=1), seed=2)
    # from the zero configuration: iCub's is outside its coupled limits, so this also checks the way in
    result = METHODS[method](model, links).solve(targets, start_of(model, targets.position[:, 0]))
    assert bool(result.converged.all()) and float(result.mnte.max()) < 1e-8
    assert excess(model, result.state.joint_positions) <= 1e-9


@pytest.mark.parametrize("method", METHODS)
def test_targets_beyond_the_limits_are_approached_without_crossing_them(models, method):
    model, links = models["icub"], TRACKED_LINKS["icub"]
    s = torch.zeros(1, model.n_dof, dtype=torch.float64) + 2.5  # far outside most limits
    targets = pose_targets(model, links, s, seed=3)
    start = start_of(model, targets.position[:, 0])
    start.joint_positions[:] = inside_configuration(model, seed=4)
    result = METHODS[method](model, links, max_iterations=30).solve(targets, start)
    assert excess(model, result.state.joint_positions) <= 1e-6
    assert not bool(result.converged.all())  # unreachable: it stops inside the limits, unconverged
    # and it did move towards them: better than where it started
    before = METHODS[method](model, links, max_iterations=0).solve(targets, start).mnte
    assert float(result.mnte) < float(before)


@pytest.mark.parametrize("method", METHODS)
def test_a_batch_solves_each_subject_as_if_alone(models, method):
    model, links = models["human48"], TRACKED_LINKS["human48"]
    s = inside_configuration(model, seed=5, batch=2)
    targets = pose_targets(model, links, s, seed=6)
    ik = METHODS[method](model, links)
    both = ik.solve(targets, start_of(model, targets.position[:, 0], batch=2))
    for b in range(2):
        one = Targets(*(t[b:b + 1] for t in vars(targets).values()))
        alone = ik.solve(one, start_of(model, one.position[:, 0]))
        assert torch.allclose(both.state.joint_positions[b], alone.state.joint_positions[0], atol=1e-9)


def test_a_missing_target_weighs_nothing_in_the_whole_body_fit(models):
    model, links = models["human66"], TRACKED_LINKS["human66"]
    targets = pose_targets(model, links, inside_configuration(model, seed=7), seed=8)
    targets.rotation[0, links.index("RightHand")] = float("nan")
    result = WholeBodyIK(model, links).solve(targets, start_of(model, targets.position[:, 0]))
    assert bool(result.converged.all()) and float(result.mnte.max()) < 1e-8  # the mean over the others


def test_a_pair_with_a_missing_end_keeps_its_joints(models):
    model, links = models["human66"], TRACKED_LINKS["human66"]
    targets = pose_targets(model, links, inside_configuration(model, seed=9), seed=10)
    targets.rotation[0, links.index("RightHand")] = float("nan")
    start = start_of(model, targets.position[:, 0])
    result = PairwiseIK(model, links).solve(targets, start)
    wrist = [model.joint_names.index(f"jRightWrist_rot{a}") for a in "xyz"]
    assert torch.equal(result.state.joint_positions[0, wrist], start.joint_positions[0, wrist])
    assert bool(result.converged.all()) and float(result.mnte.max()) < 1e-8


def test_targets_whose_chains_share_a_joint_do_not_split_into_pairs(models):
    model = models["human66"]
    # both hands' nearest target above them is the pelvis: the spine's joints lie in both chains
    with pytest.raises(InputError, match="not separable"):
        PairwiseIK(model, ("Pelvis", "RightHand", "LeftHand"))


def test_central_differences_are_exact_for_a_uniform_motion():
    t = torch.linspace(0.0, 1.0, 11, dtype=torch.float64)
    omega = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)
    R = so3.exp(t[:, None, None] * omega)  # [T,1,3,3], a constant world angular velocity
    p = t[:, None, None] * torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    s = t[:, None, None] * torch.tensor([0.5, -1.0], dtype=torch.float64)
    nu = central_velocity(t, p, R, s)
    expected = torch.cat((torch.tensor([1.0, 2.0, 3.0]), omega, torch.tensor([0.5, -1.0]))).double()
    assert torch.allclose(nu, expected.expand_as(nu), atol=1e-12)

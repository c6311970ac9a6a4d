"""baselines: whole-body instantaneous IK converges to reachable static targets and respects the limits."""

import pytest
import torch

from torchik import so3
from torchik.baselines import WholeBodyIK
from torchik.models import TRACKED_LINKS, load_model
from torchik.targets import Targets
from torchik.tracker import State


def pose_targets(model, links, s, seed):
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(1, 3, generator=g, dtype=torch.float64) * 0.2 + torch.tensor([0.0, 0.0, 0.9], dtype=torch.float64)
    R = so3.exp(0.3 * torch.randn(1, 3, generator=g, dtype=torch.float64))
    kin = model(p, R, s, links, jacobian=False)
    zeros = torch.zeros(1, len(links), 3, dtype=torch.float64)
    return Targets(kin.position[:, :1], zeros[:, :1], kin.rotation, zeros)


def start_of(model, p=None):
    p0, R0, s0 = model.zero_configuration(1)
    return State(p0 if p is None else p, R0, s0, torch.zeros(1, 6 + model.n_dof, dtype=torch.float64))


@pytest.mark.parametrize("name", ["human66", "human48"])
def test_converges_to_a_reachable_static_target(name):
    model, links = load_model(name), TRACKED_LINKS[name]
    middle = ((model.lower + model.upper) / 2).clamp(-0.4, 0.4)
    s = middle + 0.2 * torch.randn(1, model.n_dof, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    s = torch.minimum(torch.maximum(s, model.lower + 0.05), model.upper - 0.05)
    targets = pose_targets(model, links, s, seed=2)
    result = WholeBodyIK(model, links).solve(targets, start_of(model, targets.position[:, 0]))
    assert bool(result.converged.all()) and float(result.mnte.max()) < 1e-8


def test_targets_beyond_the_limits_are_approached_without_crossing_them():
    model, links = load_model("icub"), TRACKED_LINKS["icub"]
    s = torch.zeros(1, model.n_dof, dtype=torch.float64) + 2.5  # far outside most limits
    targets = pose_targets(model, links, s, seed=3)
    start = start_of(model, targets.position[:, 0])
    for j in ("r_shoulder_roll", "l_shoulder_roll"):
        start.joint_positions[0, model.joint_names.index(j)] = 0.6
    start.joint_positions[0, model.joint_names.index("r_elbow")] = 0.3
    start.joint_positions[0, model.joint_names.index("l_elbow")] = 0.3
    result = WholeBodyIK(model, links, max_iterations=30).solve(targets, start)
    s_out = result.state.joint_positions
    assert float(torch.maximum(s_out - model.upper, model.lower - s_out).max()) <= 1e-6
    assert float((s_out @ model.linear_limits.A.T - model.linear_limits.b).max()) <= 1e-6
    assert not bool(result.converged.all())  # unreachable: it stops at the cap, inside the limits

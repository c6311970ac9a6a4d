"""The placement family's misalignment against joints held at their limits (torchik/pipelines/diagnosis/placement.py).

Recording: a Human48 walk (5 s at 50 Hz, the scenarios' sensor noise) whose left shank sensor is
turned 35 deg about the knee's z axis, so that the knee the tracker estimates is carried past its
limit for part of the time (Misalignment.inject: R_m = R C).

Properties:
- adjacent_joints gives each link the joints between it and its nearest tracked ancestor and those
  between it and the tracked links below it (none above the base);
- a rotation of the shank's sensor about the knee's axis is followed by the joints wherever the
  knee and the ankle are free (project_blocks, and project_held there), and leaves a residual exactly at the
  samples where the knee is at its limit (project_held), as the tracker, which cannot move it
  further, leaves it;
- project_held and the projector at the limits, which recompute M only at the samples with a joint
  held, equal M built at every sample without the held joints' columns (a damped least-squares
  solve by QR, not the normal equations' inverse);
- a kind fitted alone (a refit) gives the candidates it has among all the kinds.
"""

from __future__ import annotations

import math

import pytest
import torch

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.diagnosis import placement
from torchik.pipelines.diagnosis.analysis import analyse
from torchik.pipelines.diagnosis.effect import halves
from torchik.pipelines.diagnosis.placement import Misalignment, adjacent_joints, project_blocks, project_held
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
SHANK, KNEE = "LeftLowerLeg", "jLeftKnee_rotz"


@pytest.fixture(scope="module")
def pushed(one_thread):
    """The analysis of the walk with the shank's sensor turned about the knee's axis."""
    model = load_model("human48")
    walk = scenario("walking", model, LINKS, 5.0, 50.0, seed=3)
    turned = Misalignment("misalignment", SHANK, dict(rotation_vector=[0.0, 0.0, -math.radians(35.0)]))
    return analyse(model, [turned.inject(walk)], LINKS)


def test_the_joints_next_to_a_link_are_those_up_to_its_tracked_neighbours(pushed):
    near = adjacent_joints(pushed)
    names = pushed.model.joint_names
    assert [names[j] for j in near[LINKS.index(SHANK)].nonzero()[:, 0].tolist()] == [
        "jLeftKnee_roty", KNEE, "jLeftAnkle_rotx", "jLeftAnkle_roty", "jLeftAnkle_rotz"]
    assert [names[j] for j in near[LINKS.index("LeftToe")].nonzero()[:, 0].tolist()] == ["jLeftBallFoot_roty"]


def test_a_turn_about_a_joint_at_its_limit_leaves_its_residual(pushed):
    j, i = pushed.model.joint_names.index(KNEE), LINKS.index(SHANK)
    ankle = [pushed.model.joint_names.index(f"jLeftAnkle_rot{a}") for a in "xyz"]
    at = pushed.active[pushed.sample, 0, j]
    assert bool(at.any()) and not bool(at.all())
    at = at | pushed.active[pushed.sample, 0][:, ankle].any(-1)
    G = pushed.joint_axes[:, 0, j][None, :, :, None]  # [1,S,3,1]: a turn about the knee's axis on the shank's rows
    free = project_blocks(pushed, 0, [i], G)[0].norm(dim=(-2, -1))
    held = project_held(pushed, 0, [i], G)[0].norm(dim=(-2, -1))
    assert bool((free <= 1e-6).all()) and bool((held[~at] <= 1e-6).all())
    assert bool((held[at] >= 0.1).all())  # of a unit turn


def _without(J: torch.Tensor, held: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """X - J_F (J_F^T J_F + lambda I)^-1 J_F^T X at every sample, J_F: J [S,R,C] without the columns of
    the joints held [S,n]; solved as least squares on [J_F; sqrt(lambda) I] by QR. X [S,R,k]."""
    free = torch.cat((torch.ones(len(J), 6, dtype=torch.bool), ~held), -1)
    J = J * free[:, None, :].to(J.dtype)
    damping = torch.eye(J.shape[-1], dtype=J.dtype).expand(len(J), -1, -1) * 1e-9 ** 0.5
    stacked = torch.cat((J, damping), 1)
    theta = torch.linalg.lstsq(stacked, torch.cat((X, X.new_zeros(len(J), J.shape[-1], X.shape[-1])), 1)).solution
    return X - J @ theta


def test_the_held_projection_is_m_without_the_held_joints_at_every_sample(pushed):
    links = [LINKS.index("LeftUpperLeg"), LINKS.index(SHANK)]  # the knee held at some samples; the ankle at all
    S, R = len(pushed.sample), pushed.J.shape[-2]
    held = pushed.active[pushed.sample, 0][None] & adjacent_joints(pushed)[links][:, None]  # [2,S,n]
    assert 0 < int(held[0].any(-1).sum()) < S and bool(held[1].any(-1).all())
    G = torch.randn(2, S, 3, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    got = project_held(pushed, 0, links, G)
    mask = pushed.rows[:, 0, :, None].to(G.dtype)
    for n, i in enumerate(links):
        X = torch.zeros(S, R, 2, dtype=torch.float64)
        X[:, 3 + 3 * i:6 + 3 * i] = G[n]
        assert torch.allclose(got[n], _without(pushed.J[:, 0], held[n], X) * mask, atol=1e-9)
    every = pushed.active[pushed.sample, 0]  # the projector at the limits: every joint at its limit held
    Y = torch.randn(S, R, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(pushed.projector(0, at_limits=True) @ Y, _without(pushed.J[:, 0], every, Y) * mask, atol=1e-9)


@pytest.mark.parametrize("kind", placement.KINDS)
def test_a_kind_fitted_alone_is_the_same_as_among_all(pushed, kind):
    """A refit asks for one kind (Subject.refit): the others are not fitted, and its candidates are
    those it has among all, to the digit."""
    train, test = halves(pushed.time)
    every = placement.fit(pushed, 0, train, test)
    alone = placement.fit(pushed, 0, train, test, kinds=(kind,))
    assert {c.kind for c in alone} == {kind}
    among = [c for c in every if c.kind == kind]
    assert [c.target for c in alone] == [c.target for c in among] and len(alone) == len(LINKS)
    for a, b in zip(alone, among):
        assert a.params == b.params and a.stderr == b.stderr and a.notes == b.notes
        assert (a.fit is None) == (b.fit is None) and (a.fit is None or a.fit.score == b.fit.score)

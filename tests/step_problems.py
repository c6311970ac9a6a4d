"""Random step problems built exactly as the tracker builds them, for the QP backends' tests."""

import torch

from torchik.method import so3
from torchik.method.limits import LimitSettings, linear_limit_bounds, velocity_bounds
from torchik.method.qp import JointTree, QPProblem, TreeHessian
from torchik.method.target_equations import TargetStructure, normal_equations


def step_problems(model, links, batch: int, seed: int, structured: bool = True, dtype=torch.float64) -> QPProblem:
    """`batch` step QPs at random configurations (some at or past their limits), random corrected
    velocities (up to a few rad/s, so that many rate bounds bind), random dropped targets, and the
    model's coupled limits. structured: carry the TreeHessian instead of a dense H."""
    gen = torch.Generator().manual_seed(seed)
    kw = dict(dtype=torch.float64)
    n = model.n_dof
    p = torch.randn(batch, 3, generator=gen, **kw)
    R = so3.random_rotation((batch,), gen)
    span = model.upper - model.lower
    s = model.lower + span * (1.2 * torch.rand(batch, n, generator=gen, **kw) - 0.1)  # 10 % past either limit
    if model.linear_limits is not None:
        # nine in ten states drawn back inside the coupled limits (towards the range's middle, which
        # satisfies them); the rest may make the QP infeasible, which a backend must report
        A, b = model.linear_limits.A, model.linear_limits.b
        middle = (model.lower + model.upper) / 2
        out = (s - middle) @ A.T
        room = (b - middle @ A.T).expand_as(out)
        shrink = torch.where(out > room, room / out, torch.ones_like(out)).amin(-1, keepdim=True)
        inside = torch.rand(batch, 1, generator=gen, **kw) < 0.9
        s = torch.where(inside, middle + 0.999 * shrink * (s - middle), s)
    base = (model.base_link,)
    task = TargetStructure.build(model, links, base)
    selection = model.select(tuple(dict.fromkeys(base + tuple(links))))
    kin = model(p, R, s, selection, jacobian=task.position is not None, jacobian_links=task.position, joint_axes=True)
    scale = 4.0 * torch.rand(batch, 1, 1, generator=gen, **kw)
    v_o = scale * torch.randn(batch, len(links), 3, generator=gen, **kw)
    v_p = torch.randn(batch, 1, 3, generator=gen, **kw)
    w_o = (torch.rand(batch, len(links), generator=gen, **kw) > 0.1).to(torch.float64)
    w_p = torch.ones(batch, 1, **kw)
    damping = 1e-9
    H, g = normal_equations(task, kin.joint_axes, kin.jacobian, v_p, v_o, damping, w_position=w_p, w_orientation=w_o,
                            hessian=not structured)
    tree = TreeHessian.from_targets(JointTree.build(model, links), kin.joint_axes, damping, 1, w_position=w_p,
                                    w_orientation=w_o) \
        if structured else None
    dt = torch.full((batch, 1), 0.01, **kw)
    lb, ub = velocity_bounds(s, model.lower, model.upper, LimitSettings(), dt)
    G = h = None
    if model.linear_limits is not None:
        A = model.linear_limits.A
        G = torch.cat((A.new_zeros(A.shape[0], 6), A), dim=1).expand(batch, -1, -1)
        h = linear_limit_bounds(s, A, model.linear_limits.b, LimitSettings(), dt)
    cast = lambda t: None if t is None else t.to(dtype)  # noqa: E731
    if tree is not None and dtype != torch.float64:
        tree = TreeHessian(tree.tree, cast(tree.axes), cast(tree.node_weight), cast(tree.position_weight), damping)
    return QPProblem(cast(H), cast(g), cast(lb), cast(ub), cast(G), cast(h), tree)

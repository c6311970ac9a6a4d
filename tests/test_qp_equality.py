"""qp: equality rows A x = b (a foot's velocity held at zero, say) beside the bounds and rows of the
tracker's step problems. The batched backend reaches PIQP's optimum to 1e-8 and holds every equality
to 1e-9, with multipliers that make its solution a KKT point; a zero row (a contact off for that
subject) constrains nothing (the same optimum as without the rows); PIQP's own solution holds the rows too."""

import numpy as np
import pytest
import qpsolvers
import torch
from step_problems import step_problems

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.qp import BatchedBackend, PiqpBackend, QPProblem

TIGHT = dict(eps_abs=1e-11, eps_rel=1e-12, eps_duality_gap_abs=1e-11, eps_duality_gap_rel=1e-12, max_iter=1000)


def with_equalities(problem: QPProblem, rows: int, seed: int) -> QPProblem:
    """The problem with `rows` random equality rows on the base's and the first joints' velocities,
    satisfiable within the bounds (b = A x0, x0 inside them), zero rows for every third subject."""
    gen = torch.Generator().manual_seed(seed)
    B, N = problem.g.shape
    A = torch.zeros(B, rows, N, dtype=problem.g.dtype)
    A[:, :, :12] = torch.randn(B, rows, 12, generator=gen, dtype=problem.g.dtype)
    A[::3] = 0.0
    lb, ub = problem.lb.clamp(min=-1.0), problem.ub.clamp(max=1.0)
    inside = lb <= ub
    x0 = torch.where(inside, lb + (ub - lb) * torch.rand(B, N, generator=gen, dtype=problem.g.dtype), 0.0)
    b = (A @ x0.unsqueeze(-1)).squeeze(-1)
    return QPProblem(problem.H, problem.g, problem.lb, problem.ub, problem.G, problem.h, problem.tree, A, b)


def objective(problem: QPProblem, x: torch.Tensor) -> torch.Tensor:
    H = problem.dense_hessian
    return 0.5 * (x[:, None, :] @ H @ x[:, :, None]).flatten() + (problem.g * x).sum(-1)


def piqp(problem: QPProblem):
    numpy = lambda t: None if t is None else t.numpy()  # noqa: E731
    H, g, lb, ub, G, h, A, b = (numpy(t) for t in (problem.dense_hessian, problem.g, problem.lb, problem.ub,
                                                   problem.G, problem.h, problem.A, problem.b))
    xs, ok = [], []
    for k in range(g.shape[0]):
        on = np.abs(A[k]).sum(-1) > 0
        qp = qpsolvers.Problem(H[k], g[k], None if G is None else G[k], None if h is None else h[k],
                               A[k][on] if on.any() else None, b[k][on] if on.any() else None, lb=lb[k], ub=ub[k])
        solution = qpsolvers.solve_problem(qp, solver="piqp", **TIGHT)
        ok.append(bool(solution.found))
        xs.append(solution.x if solution.found else np.full(g.shape[1], np.nan))
    return torch.tensor(np.array(xs)), torch.tensor(ok)


@pytest.mark.parametrize("name", ["human48", "icub"])  # iCub: with its coupled rows G x <= h too
def test_the_batched_solve_with_equality_rows_reaches_piqps_optimum_and_holds_them(name):
    model = load_model(name)
    problem = with_equalities(step_problems(model, TRACKED_LINKS[name], 60, seed=11, structured=False), 4, seed=3)
    solution = BatchedBackend().solve(problem)
    x_ref, found = piqp(problem)
    compare = solution.solved & found
    assert compare.sum() >= 50, (int(solution.solved.sum()), int(found.sum()))
    A, b = problem.equalities
    held = (A @ solution.x.unsqueeze(-1)).squeeze(-1) - b
    assert held[solution.solved].abs().max() <= 1e-9
    f, f_ref = objective(problem, solution.x), objective(problem, x_ref)
    assert ((f - f_ref).abs() / (1 + f_ref.abs()))[compare].max() <= 1e-8
    # the subjects whose rows are zero solve the problem without them
    free = BatchedBackend().solve(QPProblem(problem.H, problem.g, problem.lb, problem.ub, problem.G, problem.h))
    both = solution.solved[::3] & free.solved[::3]
    f_free = objective(problem, free.x)
    assert ((f - f_free).abs() / (1 + f_free.abs()))[::3][both].max() <= 1e-10


def test_piqp_backend_holds_the_equality_rows():
    model = load_model("human48")
    problem = with_equalities(step_problems(model, TRACKED_LINKS["human48"], 12, seed=5, structured=False), 3, seed=4)
    solution = PiqpBackend().solve(problem)
    A, b = problem.equalities
    assert bool(solution.solved.all())
    assert ((A @ solution.x.unsqueeze(-1)).squeeze(-1) - b).abs().max() <= 1e-7

"""qp: PIQP's solutions are optimal (KKT) for box-constrained problems; failures fall back to a feasible velocity."""

import torch

from torchik.method.qp import PiqpBackend, QPProblem, clipped_fallback, unconstrained


def random_problem(B: int, N: int, seed: int) -> QPProblem:
    g = torch.Generator().manual_seed(seed)
    J = torch.randn(B, N + 4, N, generator=g, dtype=torch.float64)
    H = J.transpose(1, 2) @ J + 1e-6 * torch.eye(N, dtype=torch.float64)
    q = torch.randn(B, N, generator=g, dtype=torch.float64) * 5
    lb = -torch.rand(B, N, generator=g, dtype=torch.float64)
    ub = torch.rand(B, N, generator=g, dtype=torch.float64)
    lb[:, :2], ub[:, :2] = -torch.inf, torch.inf
    return QPProblem(H, q, lb, ub)


def test_piqp_solutions_satisfy_the_kkt_conditions_of_a_box_constrained_qp():
    problem = random_problem(5, 12, 0)
    solution = PiqpBackend().solve(problem)
    assert bool(solution.solved.all())
    x = solution.x
    assert bool((x >= problem.lb - 1e-9).all() and (x <= problem.ub + 1e-9).all())
    grad = (problem.H @ x.unsqueeze(-1)).squeeze(-1) + problem.g
    # stationarity with bound multipliers: free variables have zero gradient, those at a bound push outwards
    free = (x > problem.lb + 1e-7) & (x < problem.ub - 1e-7)
    assert float(grad[free].abs().max()) < 1e-6
    assert bool((grad[(x <= problem.lb + 1e-7)] >= -1e-6).all()) and bool((grad[(x >= problem.ub - 1e-7)] <= 1e-6).all())


def test_an_infeasible_problem_is_flagged_and_gets_the_clipped_fallback():
    problem = random_problem(3, 6, 1)
    G = torch.zeros(3, 2, 6, dtype=torch.float64)
    G[:, 0, 3], G[:, 1, 3] = 1.0, -1.0  # x3 <= -1 and x3 >= 1
    h = torch.tensor([[-1.0, -1.0]] * 3, dtype=torch.float64)
    infeasible = QPProblem(problem.H, problem.g, problem.lb, problem.ub, G, h)
    solution = PiqpBackend().solve(infeasible)
    assert not bool(solution.solved.any())
    assert bool(torch.isfinite(solution.x).all())
    assert bool((solution.x >= problem.lb).all() and (solution.x <= problem.ub).all())


def test_the_fallback_respects_linear_limits_with_nonnegative_right_hand_side():
    problem = random_problem(4, 6, 2)
    G = torch.randn(4, 3, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    h = torch.rand(4, 3, dtype=torch.float64) * 0.1
    x = clipped_fallback(QPProblem(problem.H, problem.g, problem.lb, problem.ub, G, h))
    assert bool(((G @ x.unsqueeze(-1)).squeeze(-1) <= h + 1e-12).all())


def test_a_feasible_unconstrained_minimiser_is_returned_without_the_solver_and_equals_piqp():
    import qpsolvers

    problem = random_problem(6, 10, 4)
    wide = QPProblem(problem.H, problem.g, torch.full_like(problem.lb, -1e3), torch.full_like(problem.ub, 1e3))
    start = unconstrained(wide)
    assert bool(start.feasible.all())
    for b in range(6):
        reference = qpsolvers.solve_qp(wide.H[b].numpy(), wide.g[b].numpy(), lb=wide.lb[b].numpy(), ub=wide.ub[b].numpy(),
                                       solver="piqp", eps_abs=1e-10, eps_rel=1e-11)
        assert torch.allclose(start.x[b], torch.tensor(reference), atol=1e-7)
    # with tight bounds the minimiser is infeasible for some rows, which then go to PIQP
    assert not bool(unconstrained(problem).feasible.all())
    solution = PiqpBackend().solve(problem)
    assert bool((solution.x >= problem.lb - 1e-9).all() and (solution.x <= problem.ub + 1e-9).all())

"""A batched QP solver in torch: the primal-dual active-set method, exact at convergence, with an
interior-point rescue.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h,   A x = b

Equality rows A x = b join the rows G x <= h as rows always held, their multipliers of either
sign (`rows.optimal_rows`); the interior point takes each as two opposite inequalities.

Each active-set iteration guesses which bounds are active, factorises H on the free variables,
finds the optimal active rows of G in their Schur complement with that factorisation, and moves to
the bounds that the solution's multipliers and violations point to (`active_set.py`, `rows.py`).
When the guess stops changing, the KKT conditions hold to rounding: primal feasibility,
multiplier signs, complementarity. Near a tracker's previous step the active set barely changes,
so the last solve's active set (bounds and rows) is the first guess and one iteration usually
suffices.

The subjects not done within the budget (nearly singular Hessians far from any guess: random
problems, a first step) get a primal-dual interior-point method (`interior_point.py`), whose
active set the active-set iterations then try to confirm exactly; where they cannot (a bound with
a vanishing multiplier flipping back and forth), the interior point's own solution is kept when
its KKT error is below `kkt_tolerance`.

All subjects iterate together as tensor operations; the host synchronises once per iteration, to
check which subjects have converged. A subject that has not converged within the budget (or is
infeasible, or has non-finite data) is flagged and gets the clipped fallback; the others are
unaffected.

The linear solves use the step's tree structure when the problem carries it (`TreeHessian`,
O(N) per subject) and a batched dense Cholesky factorisation otherwise (and for small gathered
batches, where the tree's fixed cost per level dominates).
"""

from __future__ import annotations

import dataclasses
from typing import cast

import torch

from .active_set import ActiveSetResult, Sets, active_set, any_last, take
from .base import QPBackend, QPProblem, QPSolution, Unconstrained, clipped_fallback
from .dense import DenseHessian
from .interior_point import interior_point
from .tree import TreeHessian


class BatchedBackend(QPBackend):
    """The primal-dual active-set method for a whole batch, with an interior-point rescue.

    The active-set iterations start from the last solve's active set (when the batch shape is the
    same) and usually finish in one or two iterations. The subjects not done after
    `active_set_iterations` are solved by the interior-point method (`interior_point_iterations`),
    whose active set the active-set iterations then confirm (`polish_iterations`), else whose
    solution is kept where its KKT error is below `kkt_tolerance` (relative; 1e-4 in float32).
    tolerance: how far (relative) a free variable may pass a bound, or a multiplier have the
    wrong sign, before the active set changes (1e-12; 100 float32 epsilons in float32).
    After a solve, `iterations` holds the active-set iterations it ran (the guesses of the held
    bounds, each one factorisation of H; the batch's most; with `start`, start's guess counts as the
    first), `row_steps` the changes of the active rows made in their Schur complement and `rescued`
    how many subjects needed the interior point.
    """

    name = "batched"

    def __init__(self, active_set_iterations: int = 8, interior_point_iterations: int = 40,
                 polish_iterations: int = 2, tolerance: float = 1e-12, kkt_tolerance: float = 1e-10):
        self.active_set_iterations = active_set_iterations
        self.kkt_tolerance = kkt_tolerance
        self.interior_point_iterations = interior_point_iterations
        self.polish_iterations = polish_iterations
        self.tolerance = tolerance
        self._last: Sets | None = None
        self.iterations = 0  # active-set iterations of the last solve, for diagnostics and benchmarks
        self.row_steps = 0  # the rows' Schur-complement steps of the last solve
        self.rescued = 0  # subjects of the last solve that needed the interior-point method

    def solve(self, problem: QPProblem, warm_start: torch.Tensor | None = None,
              start: Unconstrained | None = None) -> QPSolution:
        H = problem.tree if problem.tree is not None else DenseHessian(problem.dense_hessian)
        problem, equality = _with_equalities(problem)
        if start is None:
            result = active_set(H, problem, self._initial_sets(problem, equality), self.active_set_iterations,
                                self.tolerance, equality=equality)
        else:
            result = self._continued(H, problem, start, equality)
        x, nu, eta, sets, done = result.x, result.nu, result.eta, result.sets, result.done
        self.iterations, self.row_steps, self.rescued = result.iterations, result.row_steps, 0
        if not bool(done.all()):
            rest = (~done).nonzero().flatten()
            self.rescued = len(rest)
            sub_H, sub = take(H, problem, rest)
            ip_x, ip_nu, ip_eta, ip_done, guess = _interior_point(sub_H, sub, equality, self.interior_point_iterations,
                                                                  self._kkt_tolerance(problem.g.dtype))
            # the active set the interior point points to, confirmed exactly where the active-set
            # iterations agree; elsewhere (degenerate or nearly singular problems, where a bound
            # with a vanishing multiplier flips back and forth) the interior point's own solution
            polish = active_set(sub_H, sub, guess, self.polish_iterations, self.tolerance, equality=equality)
            pol_done = polish.done
            pick = lambda a, b: None if a is None else torch.where(pol_done[:, None], a, b)  # noqa: E731
            x = x.index_copy(0, rest, torch.where(pol_done[:, None], polish.x, ip_x))
            nu = nu.index_copy(0, rest, torch.where(pol_done[:, None], polish.nu, ip_nu))
            if eta is not None and polish.eta is not None:
                eta = eta.index_copy(0, rest, torch.where(pol_done[:, None], polish.eta, ip_eta))
            sub_sets = tuple(pick(a, b) for a, b in zip(polish.sets, guess))
            sets = tuple(None if a is None else a.index_copy(0, rest, b) for a, b in zip(sets, sub_sets))  # type: ignore
            done = done.index_copy(0, rest, pol_done | ip_done)
        solved = done & torch.isfinite(x.sum(-1))  # NaN and Inf propagate through the sum
        self._last = sets
        if not bool(solved.all()):
            x = torch.where(solved[:, None], x, clipped_fallback(problem))
        if equality is not None and eta is not None:  # the rows' multipliers as the problem gave them: G's only
            eta = eta[:, int(equality.sum()):]
            eta = None if eta.shape[1] == 0 else eta
        return QPSolution(x, solved, nu, eta)

    def _continued(self, H, problem: QPProblem, start: Unconstrained, equality=None) -> ActiveSetResult:
        """The active-set iterations for the subjects that `start`'s minimiser does not satisfy (the
        others are solved, with nothing active), from the last solve's active set. start's guess,
        no bound held, is the first iteration; where those subjects hold no bound in the last
        solve's set, it goes on with start's factorisation (the rows found in their Schur complement
        with it; a few subjects' H factorised again densely on that guess, which costs less than
        the tree's solves, is no other iteration). Where one does, start's guess was not theirs:
        their first iteration factorises on it and counts as a second. Only those subjects are
        gathered: in tracking, a few of the batch."""
        upper, lower, rows = self._initial_sets(problem, equality)
        none = torch.zeros_like(upper)
        no_rows = None if rows is None else torch.zeros_like(rows)
        live = (~start.feasible).nonzero().flatten()
        if len(live) == 0:  # handed over for another reason (the invariant, the rotation): nothing to solve
            # (None without rows: ActiveSetResult's module is type-checked without strict optionals)
            eta = cast(torch.Tensor, None if rows is None else problem.g.new_zeros(rows.shape))
            return ActiveSetResult(start.x, torch.zeros_like(start.x), eta, (none, none.clone(), no_rows),
                                   torch.ones_like(start.feasible), 1, 0)
        sub_H, sub = take(H, problem, live)
        sets: Sets = (upper.index_select(0, live), lower.index_select(0, live),
                      None if rows is None else rows.index_select(0, live))
        held = bool(any_last(sets[0] | sets[1]).any())
        factor = start.factor
        if held or not isinstance(sub_H, TreeHessian):  # gathered densely (`take`): refactorised densely
            factor = None
        result = active_set(sub_H, sub, sets, self.active_set_iterations, self.tolerance,
                            factor=None if factor is None else factor.select(live), equality=equality)

        def scatter(whole, part):
            return None if whole is None else whole.index_copy(0, live, part)

        return ActiveSetResult(scatter(start.x, result.x), scatter(torch.zeros_like(start.x), result.nu),
                               scatter(None if rows is None else problem.g.new_zeros(rows.shape), result.eta),
                               (scatter(none, result.sets[0]), scatter(none.clone(), result.sets[1]),
                                scatter(no_rows, result.sets[2])),
                               scatter(torch.ones_like(start.feasible), result.done), result.iterations + held,
                               result.row_steps)

    def _kkt_tolerance(self, dtype) -> float:
        """The KKT error at which an interior-point solution is accepted: `kkt_tolerance` in
        float64, 1e-4 in float32 (its rounding, 1e-7, times the conditioning of the step's Hessian)."""
        return self.kkt_tolerance if dtype == torch.float64 else max(self.kkt_tolerance, 1e-4)

    def _initial_sets(self, problem: QPProblem, equality: torch.Tensor | None = None):
        """The last solve's active set (same batch shape), else none but the equality rows: the first
        iteration then solves the unconstrained problem (on those rows)."""
        B, N = problem.g.shape
        m = 0 if problem.G is None else problem.G.shape[1]
        if self._last is not None:
            upper, lower, rows = self._last
            if upper.shape == (B, N) and upper.device == problem.g.device and (rows is None) == (m == 0) \
                    and (rows is None or rows.shape == (B, m)):
                # (never an infinite bound: |bound| < inf is isfinite, at a third of its cost on a CPU)
                return upper & (problem.ub.abs() < torch.inf), lower & (problem.lb.abs() < torch.inf) & ~upper, rows
        none = torch.zeros(B, N, dtype=torch.bool, device=problem.g.device)
        rows = None if m == 0 else torch.zeros(B, m, dtype=torch.bool, device=problem.g.device)
        return none, none.clone(), rows if rows is None or equality is None else rows | equality


def _with_equalities(problem: QPProblem) -> tuple[QPProblem, torch.Tensor | None]:
    """The problem with its equality rows A x = b put before its rows G x <= h, and which rows of
    the result are equalities ([e + m] bool; None without any)."""
    if (equal := problem.equalities) is None:
        return problem, None
    A, b = equal
    e = A.shape[1]
    G = A if problem.G is None else torch.cat((A, problem.G.expand(A.shape[0], -1, -1)), 1)
    h = b if problem.h is None else torch.cat((b, problem.h), 1)
    equality = torch.zeros(G.shape[1], dtype=torch.bool, device=G.device)
    equality[:e] = True
    return dataclasses.replace(problem, G=G, h=h, A=None, b=None), equality


def _interior_point(H, problem: QPProblem, equality: torch.Tensor | None, iterations: int, tolerance: float):
    """`interior_point` on the problem with each equality row as two opposite inequalities; the
    active set it points to in the problem's rows (its equality rows held)."""
    if equality is None:
        return interior_point(H, problem, iterations, tolerance)
    assert problem.G is not None and problem.h is not None  # the equalities are among the rows
    G, h = problem.G, problem.h
    split = dataclasses.replace(problem, G=torch.cat((G, -G[:, equality]), 1), h=torch.cat((h, -h[:, equality]), 1))
    x, nu, eta, done, (upper, lower, rows) = interior_point(H, split, iterations, tolerance)
    m = G.shape[1]
    eta = eta[:, :m].index_add(1, equality.nonzero().flatten(), -eta[:, m:])
    return x, nu, eta, done, (upper, lower, (rows[:, :m] | equality))

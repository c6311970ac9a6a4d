"""The batched QP's active-set iterations: bounds by the primal-dual active-set method, linear
rows in their Schur complement.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h

Each iteration takes a guess of which bounds are active, holds those variables at their bounds and
factorises H on the others once. The rows' optimal active set for these held bounds is then found
in the rows' Schur complement, with that factorisation (`rows.py`: a change of the active rows
costs an [m,m] factorisation, not a new one of H). The bounds' guess is then updated as in
Hintermueller, Ito and Kunisch (SIAM J. Optim. 2002): a held bound whose multiplier has the wrong
sign is released, a free variable past a bound is held. When the bounds' guess stops changing the
KKT conditions hold to rounding. Near a tracker's previous step the guess barely changes, so the
last solve's active set is the first guess and one iteration usually suffices; after the first
iteration only the subjects still changing are carried on, gathered into a smaller batch.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import torch

from .base import QPProblem
from .dense import DenseHessian
from .rows import optimal_rows, row_forces, row_values
from .tree import TreeHessian

Sets = tuple[torch.Tensor, torch.Tensor, "torch.Tensor | None"]  # (upper [B,N], lower [B,N], rows [B,m] or None)


class Tolerances(NamedTuple):
    """How far a free variable may pass a bound (bound [B,N]), a multiplier have the wrong sign
    (multiplier [B,1]) or a row be violated (row [B,m], None without rows) before the active set
    changes: `tolerance` relative to the bounds', the gradient's and the rows' sizes."""

    bound: torch.Tensor
    multiplier: torch.Tensor
    row: torch.Tensor | None

    @classmethod
    def of(cls, problem: QPProblem, tolerance: float) -> "Tolerances":
        g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
        bound = tolerance * (1 + torch.nan_to_num(lb.abs(), posinf=0.0) + torch.nan_to_num(ub.abs(), posinf=0.0))
        row = None
        if G is not None:
            assert h is not None  # a problem's G comes with its h
            row = tolerance * (1 + h.abs() + (G[0] if G.stride(0) == 0 else G).abs().sum(-1))
        return cls(bound, tolerance * (1 + g.abs().amax(-1, keepdim=True)), row)

    def pick(self, subjects: torch.Tensor | None) -> "Tolerances":
        """The tolerances of the subjects [k] (all without)."""
        return Tolerances(*(select(subjects, t) for t in self))


def any_last(mask: torch.Tensor) -> torch.Tensor:
    """mask [..., k] bool -> [...]: any entry True. On its bytes: a bool reduction is several
    times slower on a CPU."""
    return mask.view(torch.uint8).amax(-1) != 0


@dataclass
class ActiveSetResult:
    """x [B,N], bound multipliers nu [B,N], row multipliers eta [B,m] (None without rows), the final
    sets, done [B], the iterations run (factorisations of H) and the rows' Schur-complement steps."""

    x: torch.Tensor
    nu: torch.Tensor
    eta: torch.Tensor | None
    sets: Sets
    done: torch.Tensor
    iterations: int
    row_steps: int


def active_set(H, problem: QPProblem, sets: Sets, budget: int, tolerance: float,
               factor=None, equality: torch.Tensor | None = None) -> ActiveSetResult:
    """Active-set iterations from `sets`, at most `budget`. tolerance: how far (relative) a free
    variable may pass a bound, or a multiplier have the wrong sign, before the active set changes.
    factor: H's factorisation with every variable free, made already: the first iteration's, whose
    sets then hold no bound (rows may be active). equality [m] bool: the rows of G that hold with
    equality (rows.optimal_rows).

    After the first iteration only the subjects not yet done are carried on (gathered into a
    smaller batch): in tracking most subjects keep their active set and finish at once."""
    g, G = problem.g, problem.G
    tolerances = Tolerances.of(problem, max(tolerance, 100 * torch.finfo(g.dtype).eps))  # float32 cannot resolve 1e-12
    upper, lower, rows = sets
    done = torch.zeros(g.shape[0], dtype=torch.bool, device=g.device)
    x, nu = torch.zeros_like(g), torch.zeros_like(g)
    eta = None if G is None else g.new_zeros(G.shape[:2])
    live, sub_H, sub = None, H, problem
    iteration, row_steps = 0, 0
    for iteration in range(1, budget + 1):  # noqa: B007  (the count is returned)
        pick = functools.partial(select, live)
        u, l, r, tol = pick(upper), pick(lower), pick(rows), tolerances.pick(live)
        x_new, nu_new, eta_new, new_r, rows_done, steps = solve_on(sub_H, sub, u, l, r, tol,
                                                                   factor if iteration == 1 else None, equality)
        row_steps += steps
        new_u, new_l, same = next_bounds(sub, x_new, nu_new, u, l, tol)
        same &= rows_done
        if live is None:
            x, nu, eta, upper, lower, rows, done = x_new, nu_new, eta_new, new_u, new_l, new_r, same
        else:
            x, nu = x.index_copy(0, live, x_new), nu.index_copy(0, live, nu_new)
            upper, lower = upper.index_copy(0, live, new_u), lower.index_copy(0, live, new_l)
            if G is not None:
                eta, rows = eta.index_copy(0, live, eta_new), rows.index_copy(0, live, new_r)
            done = done.index_copy(0, live, same)
        if bool(done.all()):  # the one host synchronisation per iteration
            break
        live = (~done).nonzero().flatten()
        sub_H, sub = take(H, problem, live)
    return ActiveSetResult(x, nu, eta, (upper, lower, rows), done, iteration, row_steps)


def solve_on(H, problem: QPProblem, upper, lower, rows, tol: Tolerances, factor=None, equality=None):
    """The bounds `upper`, `lower` [B,N] held, the rows' optimal active set from `rows` [B,m].
    factor: H's factorisation on the free variables, if made already.
    Returns x [B,N], the bound multipliers nu [B,N] (nu > 0 pushes against an upper bound, nu < 0
    against a lower one; 0 on free variables), eta [B,m] and the active rows (None without G),
    whether the rows' part is solved [B] and the rows' Schur-complement steps."""
    g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
    held = upper | lower
    value = torch.where(upper, ub, torch.where(lower, lb, torch.zeros_like(g)))
    factor = H.factor(~held) if factor is None else factor
    x = factor.solve(-g.unsqueeze(-1), value.unsqueeze(-1)).squeeze(-1)
    eta, rows_done, steps = None, torch.ones_like(held[:, 0]), 0
    if G is not None:
        assert h is not None and rows is not None  # a problem's G comes with its h, and the sets with rows
        eta = torch.zeros_like(h)
        violation = row_values(G, x) - h  # at eta = 0
        # only the subjects with an active or a violated row enter the rows' Schur complement
        off = violation > tol.row if equality is None else torch.where(equality, violation.abs(), violation) > tol.row
        involved = any_last(rows | off).nonzero().flatten()
        if len(involved):
            pick = functools.partial(select, involved)
            sub_H = H.select(involved)
            if gathered_densely(sub_H, len(involved)):
                # the rows' Schur complement takes m + 2 solves: with the tree's factorisation each
                # pays a fixed time per level; a few subjects' H factorised densely costs less
                sub_H = DenseHessian(sub_H.dense())
                sub_factor = sub_H.factor(~pick(held))
            else:
                sub_factor = factor.select(involved)
            solved = _with_rows(sub_H, sub_factor, pick(g), pick(G), pick(h), pick(x),
                                pick(violation), pick(rows), pick(held), tol.pick(involved), equality)
            x, eta = x.index_copy(0, involved, solved[0]), eta.index_copy(0, involved, solved[1])
            rows = rows.index_copy(0, involved, solved[2])
            rows_done = rows_done.index_copy(0, involved, solved[3])
            steps = solved[4]
    return x, _bound_multipliers(H, g, G, x, eta, held), eta, rows, rows_done, steps


def _bound_multipliers(H, g, G, x, eta, held):
    """-(H x + g + G^T eta) on the held variables, 0 on the free ones. -> [B,N]. Only the subjects
    that hold a bound need the product with H: in tracking, few do."""
    nu = torch.zeros_like(x)
    holding = any_last(held).nonzero().flatten()
    if len(holding):
        pick = functools.partial(select, holding)
        gradient = H.select(holding).matvec(pick(x).unsqueeze(-1)).squeeze(-1) + pick(g)
        if G is not None:
            gradient = gradient + row_forces(pick(G), eta.index_select(0, holding))
        nu = nu.index_copy(0, holding, torch.where(pick(held), -gradient, torch.zeros_like(gradient)))
    return nu


def _with_rows(H, factor, g, G, h, x, violation, rows, held, tol: Tolerances, equality=None):
    """The rows' part for the subjects that have rows to hold: their Schur complement with the
    bounds' factorisation, the optimal active rows in it (`optimal_rows`), and one step of
    iterative refinement (on a nearly singular H the Schur complement is ill-conditioned and the
    first solve leaves a stationarity residual well above rounding).
    Returns x [k,N], eta [k,m], the active rows [k,m], done [k] and the rows' steps."""
    Z = factor.solve(G.transpose(1, 2))  # [k,N,m]: H_F^-1 G^T, zero on the held variables
    S = Z.transpose(1, 2) @ G[0].T if G.stride(0) == 0 else G @ Z  # G H_F^-1 G^T = (H_F^-1 G^T)^T G^T
    S = (S + S.transpose(1, 2)) / 2
    eta, active, done, steps = optimal_rows(S, violation, rows, tol.row, tol.multiplier, budget=3 * G.shape[1] + 2,
                                            equality=equality)
    x = x - (Z @ eta.unsqueeze(-1)).squeeze(-1)
    a = active.to(x.dtype)
    free = (~held).to(x.dtype)
    r_x = free * -(H.matvec(x.unsqueeze(-1)).squeeze(-1) + g + row_forces(G, eta))
    r_rows = a * (h - row_values(G, x))
    dx = factor.solve(r_x.unsqueeze(-1)).squeeze(-1)
    schur = S * (a[:, :, None] * a[:, None, :]) + torch.diag_embed(1 - a)
    d_eta = a * torch.cholesky_solve((a * (row_values(G, dx) - r_rows)).unsqueeze(-1),
                                     torch.linalg.cholesky_ex(schur)[0]).squeeze(-1)
    return x + dx - (Z @ d_eta.unsqueeze(-1)).squeeze(-1), eta + d_eta, active, done, steps


def next_bounds(problem: QPProblem, x, nu, upper, lower, tol: "Tolerances"):
    """The bounds a solution points to: held bounds whose multiplier has the wrong sign are
    released, free variables past a bound are held (never an infinite one: x is not past it).
    Returns the new upper [B,N], lower [B,N] and whether nothing changed and x is finite [B]
    (NaN and Inf propagate through the sum)."""
    new_upper = torch.where(upper, nu > -tol.multiplier, x > problem.ub + tol.bound)
    new_lower = torch.where(lower, nu < tol.multiplier, x < problem.lb - tol.bound) & ~new_upper
    same = ~any_last((new_upper ^ upper) | (new_lower ^ lower)) & torch.isfinite(x.sum(-1))
    return new_upper, new_lower, same


def select(rows: torch.Tensor | None, t: torch.Tensor | None) -> torch.Tensor | None:
    """t's batch rows `rows` (all without rows; None stays None). A tensor expanded over the batch
    (the same G for every subject) stays expanded."""
    if rows is None or t is None:
        return t
    if t.stride(0) == 0:
        return t[:1].expand(len(rows), *t.shape[1:])
    return t.index_select(0, rows)


DENSE_BELOW = 32  # gathered batches smaller than this are solved densely: the tree's level-by-level
                 # elimination costs a fixed time per level, a dense Cholesky of a few matrices less


def gathered_densely(H, k: int) -> bool:
    """Whether k subjects gathered from H (a TreeHessian or a DenseHessian) are solved densely."""
    return isinstance(H, TreeHessian) and k < DENSE_BELOW


def take(H, problem: QPProblem, rows: torch.Tensor):
    """The Hessian operator and problem of the subjects `rows` [k]."""
    pick = functools.partial(select, rows)
    sub_H = H.select(rows)
    if gathered_densely(sub_H, len(rows)):
        sub_H = DenseHessian(sub_H.dense())
    tree = sub_H if isinstance(sub_H, TreeHessian) else None
    dense = sub_H.H if isinstance(sub_H, DenseHessian) else None
    sub = QPProblem(dense, pick(problem.g), pick(problem.lb), pick(problem.ub), pick(problem.G), pick(problem.h), tree)
    return sub_H, sub

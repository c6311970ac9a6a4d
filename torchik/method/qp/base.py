"""The QP every backend solves, its solution, and the fallback when a solver fails."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch

from .rows import row_values
from .tree import TreeFactor, TreeHessian


@dataclass(frozen=True)
class QPProblem:
    """min 1/2 x^T H x + g^T x  s.t.  lb <= x <= ub,  G x <= h,  A x = b, for a batch.

    H: [B,N,N] symmetric positive definite, or None when `tree` gives it in structured form
    (a TreeHessian, which the batched backend solves in O(N)); g: [B,N]; lb, ub: [B,N] (+-inf
    where free); G: [B,m,N] or None; h: [B,m] or None; A: [B,e,N] or None; b: [B,e] or None (a zero
    row of A with b = 0 is no constraint: a contact switched off for a subject).
    """

    H: torch.Tensor | None
    g: torch.Tensor
    lb: torch.Tensor
    ub: torch.Tensor
    G: torch.Tensor | None = None
    h: torch.Tensor | None = None
    tree: "TreeHessian | None" = None
    A: torch.Tensor | None = None
    b: torch.Tensor | None = None

    @property
    def equalities(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """(A [B,e,N], b [B,e]) of the equality rows A x = b, or None without any."""
        return _pair(self.A, self.b, "A")

    @property
    def dense_hessian(self) -> torch.Tensor:
        """H as a dense [B,N,N] matrix (formed from `tree` when H is None)."""
        if self.H is not None:
            return self.H
        assert self.tree is not None, "a QPProblem needs H or tree"
        return self.tree.dense()

    @property
    def rows(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """(G [B,m,N], h [B,m]) of the linear rows G x <= h, or None without any."""
        return _pair(self.G, self.h, "G")

    def active(self, x: torch.Tensor, tolerance: float = 1e-9) -> torch.Tensor:
        """[B] bounds (lower or upper) and linear rows that x [B,N] touches (infinite bounds never)."""
        count = ((x <= self.lb + tolerance) | (x >= self.ub - tolerance)).sum(-1)
        if (rows := self.rows) is not None:
            G, h = rows
            count = count + (row_values(G, x) >= h - tolerance).sum(-1)
        return count


def _pair(rows: torch.Tensor | None, rhs: torch.Tensor | None, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(rows, right-hand side), or None without rows: a problem's rows come with theirs."""
    if rows is None:
        return None
    assert rhs is not None, f"a QPProblem's {name} comes with its right-hand side"
    return rows, rhs


@dataclass(frozen=True)
class QPSolution:
    """x: [B,N]; solved: [B] bool, False where the solver failed and x is the clipped fallback.

    Where the backend reports them, the KKT multipliers: bound_multipliers [B,N] (positive
    against an upper bound, negative against a lower one, 0 where free) and row_multipliers [B,m]
    (>= 0), with H x + g + G^T row + bound = 0.
    """

    x: torch.Tensor
    solved: torch.Tensor
    bound_multipliers: torch.Tensor | None = None
    row_multipliers: torch.Tensor | None = None


@dataclass(frozen=True)
class Unconstrained:
    """A problem's unconstrained minimiser x = -H^-1 g [B,N], where it is already the QP's solution
    (feasible [B]) and, on the tree, the factorisation of H with every variable free that gave it
    (None for a dense H: a few subjects' is cheap to make again): the first iteration of an
    active-set method that starts with no bound held, done already (by the captured step, which
    hands it to the backend with its QP)."""

    x: torch.Tensor
    feasible: torch.Tensor
    factor: "TreeFactor | None"


class QPBackend(ABC):
    """Solves a batch of QPs. `warm_start` [B,N] is the previous step's solution, or None. `start`:
    the problem's unconstrained minimiser and factorisation, where already computed (the subjects
    it satisfies are solved; a backend need not compute it again)."""

    name: str = "abstract"

    @abstractmethod
    def solve(self, problem: QPProblem, warm_start: torch.Tensor | None = None,
              start: Unconstrained | None = None) -> QPSolution:
        ...


def unconstrained(problem: QPProblem) -> Unconstrained:
    """The unconstrained minimiser -H^-1 g, where it is already the QP's solution, and H's factorisation.

    For a convex QP, a minimiser of the objective alone that satisfies every bound and linear limit
    (strictly, no tolerance) is the constrained optimum too; a solver is needed only elsewhere.
    feasible is False also where H is not numerically positive definite.
    """
    factor = None
    if problem.tree is not None:
        factor = problem.tree.factor(torch.ones_like(problem.g, dtype=torch.bool))
        x, positive = factor.solve(-problem.g.unsqueeze(-1)).squeeze(-1), factor.positive
    else:
        # LAPACK's upper factor: torch makes the lower one from a transposed copy and clears it
        # above the diagonal (slower for one subject's [72,72] H: experiments/speed_history.md). Two
        # triangular solves: cholesky_solve does the same with copies and checks that cost, for
        # one subject, twice as much again
        U, info = torch.linalg.cholesky_ex(problem.dense_hessian, upper=True)
        x = torch.linalg.solve_triangular(U.transpose(-1, -2), -problem.g.unsqueeze(-1), upper=False)
        x, positive = torch.linalg.solve_triangular(U, x, upper=True).squeeze(-1), info == 0
    # within every bound, and finite: Inf - Inf and NaN are not 0
    feasible = positive & (x.clamp(problem.lb, problem.ub) - x == 0).all(-1)
    if (rows := problem.rows) is not None:
        G, h = rows
        feasible &= (row_values(G, x) <= h).all(-1)
    if (equal := problem.equalities) is not None:  # a minimiser that ignored them holds them only by chance
        A, b = equal
        feasible &= (row_values(A, x) == b).all(-1)
    return Unconstrained(x, feasible, factor)


def clipped_fallback(problem: QPProblem) -> torch.Tensor:
    """The nearest feasible velocity a failed solve can fall back to. -> [B,N]

    The unconstrained minimiser clipped to the bounds, then shrunk towards zero until G x <= h
    holds (zero joint rates satisfy it whenever the state is within its linear limits).
    """
    if problem.tree is not None:
        free = torch.ones_like(problem.g, dtype=torch.bool)
        x = problem.tree.factor(free).solve(-problem.g.unsqueeze(-1)).squeeze(-1)
    else:
        x = torch.linalg.solve(problem.dense_hessian, -problem.g.unsqueeze(-1)).squeeze(-1)
    x = torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
    x = torch.minimum(torch.maximum(x, problem.lb), problem.ub)
    if (rows := problem.rows) is not None:
        G, h = rows
        Gx = row_values(G, x)
        # largest alpha in [0, 1] with alpha G x <= h on every row where G x > h
        tiny = torch.finfo(Gx.dtype).tiny
        ratio = torch.where(Gx > h, h.clamp(min=0) / Gx.clamp(min=tiny), torch.ones_like(Gx))
        x = x * ratio.min(dim=-1, keepdim=True).values.clamp(0.0, 1.0)
    return x

"""PIQP through qpsolvers, one subject at a time. Box limits go in as lb/ub (about twice as fast
as writing them into G x <= h). PIQP is an interior-point method and takes no warm start
(qpsolvers ignores `initvals` for it), so `warm_start` is accepted for the interface and unused.
Subjects whose unconstrained minimiser already satisfies every limit skip the solver (exactly)."""

from __future__ import annotations

import numpy as np
import torch

from .base import QPBackend, QPProblem, QPSolution, Unconstrained, clipped_fallback, unconstrained


class PiqpBackend(QPBackend):
    """PIQP (proximal interior point) per subject. eps_abs, eps_rel: PIQP's tolerances, on the
    residuals and the duality gap alike."""

    name = "piqp"

    def __init__(self, eps_abs: float = 1e-9, eps_rel: float = 1e-10):
        import qpsolvers

        if "piqp" not in qpsolvers.available_solvers:
            from ...errors import TorchikError

            raise TorchikError("PIQP is not available to qpsolvers: pip install piqp")
        self._qpsolvers = qpsolvers
        self.eps_abs, self.eps_rel = eps_abs, eps_rel

    def solve(self, problem: QPProblem, warm_start: torch.Tensor | None = None,
              start: Unconstrained | None = None) -> QPSolution:
        # Where the unconstrained minimiser already satisfies every limit it is the exact solution;
        # PIQP is called for the other subjects only.
        start = unconstrained(problem) if start is None else start
        x, done = start.x.clone(), start.feasible  # x: PIQP's subjects are written into it below
        if bool(done.all()):
            return QPSolution(x, done)
        rows = (~done).nonzero().flatten().tolist()
        numpy = lambda t: t.detach().cpu().double().numpy()  # noqa: E731
        H, g, lb, ub = (numpy(t) for t in (problem.dense_hessian, problem.g, problem.lb, problem.ub))
        G, h = (None, None) if problem.rows is None else (numpy(t) for t in problem.rows)
        A, b_eq = (None, None) if problem.equalities is None else (numpy(t) for t in problem.equalities)
        solved = torch.ones_like(done)
        for b in rows:  # PIQP solves one problem per call; the batched backend removes this loop
            A_b = b_b = None
            if A is not None and b_eq is not None:
                on = np.abs(A[b]).sum(-1) > 0  # a zero row is no constraint (a contact off)
                A_b, b_b = (A[b][on], b_eq[b][on]) if on.any() else (None, None)
            qp = self._qpsolvers.Problem(H[b], g[b], None if G is None else G[b], None if h is None else h[b],
                                         A_b, b_b, lb=lb[b], ub=ub[b])
            # the duality gap needs its own tolerances: at PIQP's defaults a solve can stop with a bound
            # held loosely and the step off by 1e-3 on these nearly singular Hessians
            # a failed solve's NaN duals make qpsolvers' arithmetic warn; the failure is caught below and counted
            with np.errstate(invalid="ignore", over="ignore"):
                solution = self._qpsolvers.solve_problem(qp, solver="piqp", eps_abs=self.eps_abs, eps_rel=self.eps_rel,
                                                         eps_duality_gap_abs=self.eps_abs,
                                                         eps_duality_gap_rel=self.eps_rel)
            if solution.found and solution.x is not None and np.all(np.isfinite(solution.x)):
                x[b] = torch.tensor(solution.x, dtype=x.dtype, device=x.device)
            else:
                solved[b] = False
        if not bool(solved.all()):
            x = torch.where(solved[:, None], x, clipped_fallback(problem))
        return QPSolution(x, solved)

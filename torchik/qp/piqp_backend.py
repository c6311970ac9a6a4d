"""PIQP through qpsolvers, one subject at a time. Box limits go in as lb/ub (about twice as fast
as writing them into G x <= h). PIQP is an interior-point method and takes no warm start
(qpsolvers ignores `initvals` for it), so `warm_start` is accepted for the interface and unused."""

from __future__ import annotations

import numpy as np
import torch

from .base import QPBackend, QPProblem, QPSolution, clipped_fallback


class PiqpBackend(QPBackend):
    """PIQP (proximal interior point) per subject. eps_abs, eps_rel: PIQP's tolerances."""

    name = "piqp"

    def __init__(self, eps_abs: float = 1e-9, eps_rel: float = 1e-10):
        import qpsolvers

        if "piqp" not in qpsolvers.available_solvers:
            from ..errors import TorchikError

            raise TorchikError("PIQP is not available to qpsolvers: pip install piqp")
        self._qpsolvers = qpsolvers
        self.eps_abs, self.eps_rel = eps_abs, eps_rel

    def solve(self, problem: QPProblem, warm_start: torch.Tensor | None = None) -> QPSolution:
        H, g = problem.H.detach().cpu().double().numpy(), problem.g.detach().cpu().double().numpy()
        lb, ub = problem.lb.detach().cpu().double().numpy(), problem.ub.detach().cpu().double().numpy()
        G = None if problem.G is None else problem.G.detach().cpu().double().numpy()
        h = None if problem.h is None else problem.h.detach().cpu().double().numpy()
        B, N = g.shape
        x = np.zeros((B, N))
        solved = np.zeros(B, dtype=bool)
        for b in range(B):  # PIQP solves one problem per call; the batched backend removes this loop
            qp = self._qpsolvers.Problem(H[b], g[b], None if G is None else G[b], None if h is None else h[b],
                                         lb=lb[b], ub=ub[b])
            solution = self._qpsolvers.solve_problem(
                qp, solver="piqp", eps_abs=self.eps_abs, eps_rel=self.eps_rel)
            if solution.found and solution.x is not None and np.all(np.isfinite(solution.x)):
                x[b], solved[b] = solution.x, True
        out = torch.from_numpy(x).to(dtype=problem.g.dtype, device=problem.g.device)
        ok = torch.from_numpy(solved).to(problem.g.device)
        if not bool(ok.all()):
            out = torch.where(ok[:, None], out, clipped_fallback(problem))
        return QPSolution(out, ok)

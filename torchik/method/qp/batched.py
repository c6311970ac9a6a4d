"""A batched QP solver in torch: the primal-dual active-set method, exact at convergence, with an
interior-point rescue.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h

Each active-set iteration guesses which bounds and rows are active, solves the equality-
constrained problem they define (held variables at their bounds, active rows of G as equalities
through their Schur complement), and moves to the active set that the solution's multipliers and
violations point to (Hintermueller, Ito and Kunisch, SIAM J. Optim. 2002). When the guess stops
changing, the KKT conditions hold to rounding: primal feasibility, multiplier signs,
complementarity. Near a tracker's previous step the active set barely changes, so the last
solve's active set is the first guess and one iteration usually suffices; after the first
iteration only the subjects still changing are carried on, gathered into a smaller batch.

On nearly singular Hessians far from any guess (random problems, a first step) the active-set
iterations can cycle. The subjects not done within their budget get a primal-dual interior-point
method (Mehrotra's predictor-corrector), whose active set the active-set iterations then try to
confirm exactly; where they cannot (a bound with a vanishing multiplier flipping back and forth),
the interior point's own solution is kept when its KKT error is below `kkt_tolerance`.

All subjects iterate together as tensor operations; the host synchronises once per iteration, to
check which subjects have converged. A subject that has not converged within the budget (or is
infeasible, or has non-finite data) is flagged and gets the clipped fallback; the others are
unaffected.

The linear solves use the step's tree structure when the problem carries it (`TreeHessian`,
O(N) per subject) and a batched dense Cholesky factorisation otherwise (and for small gathered
batches, where the tree's fixed cost per level dominates).

`_interior_point` is longer than this project's 80 lines on purpose: Mehrotra's method read top to
bottom as textbooks write it (start, residuals, predictor, corrector, step length); split, its
dozen shared quantities would travel through every call.
"""

from __future__ import annotations

import functools

import torch

from .base import QPBackend, QPProblem, QPSolution, clipped_fallback
from .dense import DenseHessian
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
    After a solve, `iterations` holds the active-set iterations it ran and `rescued` how many
    subjects needed the interior point.
    """

    name = "batched"

    def __init__(self, active_set_iterations: int = 8, interior_point_iterations: int = 40,
                 polish_iterations: int = 2, tolerance: float = 1e-12, kkt_tolerance: float = 1e-10):
        self.active_set_iterations = active_set_iterations
        self.kkt_tolerance = kkt_tolerance
        self.interior_point_iterations = interior_point_iterations
        self.polish_iterations = polish_iterations
        self.tolerance = tolerance
        self._last: tuple[torch.Tensor, torch.Tensor, torch.Tensor | None] | None = None
        self.iterations = 0  # active-set iterations of the last solve, for diagnostics and benchmarks
        self.rescued = 0  # subjects of the last solve that needed the interior-point method

    def solve(self, problem: QPProblem, warm_start: torch.Tensor | None = None) -> QPSolution:
        H = problem.tree if problem.tree is not None else DenseHessian(problem.H)
        sets = self._initial_sets(problem)
        x, nu, eta, sets, done, self.iterations = self._active_set(H, problem, sets, self.active_set_iterations)
        self.rescued = 0
        if not bool(done.all()):
            rest = (~done).nonzero().flatten()
            self.rescued = len(rest)
            sub_H, sub = _take(H, problem, rest)
            ip_x, ip_nu, ip_eta, ip_done, guess = _interior_point(sub_H, sub, self.interior_point_iterations,
                                                                  self._kkt_tolerance(problem.g.dtype))
            # the active set the interior point points to, confirmed exactly where the active-set
            # iterations agree; elsewhere (degenerate or nearly singular problems, where a bound
            # with a vanishing multiplier flips back and forth) the interior point's own solution
            pol_x, pol_nu, pol_eta, pol_sets, pol_done, _ = self._active_set(sub_H, sub, guess, self.polish_iterations)
            pick = lambda a, b: None if a is None else torch.where(pol_done[:, None], a, b)  # noqa: E731
            sub_x, sub_nu, sub_eta = pick(pol_x, ip_x), pick(pol_nu, ip_nu), pick(pol_eta, ip_eta)
            sub_sets = tuple(pick(a, b) for a, b in zip(pol_sets, guess))
            x, nu = x.index_copy(0, rest, sub_x), nu.index_copy(0, rest, sub_nu)
            eta = None if eta is None else eta.index_copy(0, rest, sub_eta)
            sets = tuple(None if a is None else a.index_copy(0, rest, b) for a, b in zip(sets, sub_sets))
            done = done.index_copy(0, rest, pol_done | ip_done)
        solved = done & torch.isfinite(x).all(-1)
        self._last = sets
        if not bool(solved.all()):
            x = torch.where(solved[:, None], x, clipped_fallback(problem))
        return QPSolution(x, solved, nu, eta)

    def _active_set(self, H, problem: QPProblem, sets, budget: int):
        """Active-set iterations from `sets` = (upper, lower, rows). Returns x [B,N], nu [B,N],
        eta [B,m] or None, the final sets, done [B] and the iterations run.

        After the first iteration only the subjects not yet done are carried on (gathered into a
        smaller batch): in tracking most subjects keep their active set and finish at once."""
        g, G = problem.g, problem.G
        B, N = g.shape
        tolerance = max(self.tolerance, 100 * torch.finfo(g.dtype).eps)  # float32 cannot resolve 1e-12
        upper, lower, rows = (None if t is None else t.clone() for t in sets)
        done = torch.zeros(B, dtype=torch.bool, device=g.device)
        x = torch.zeros_like(g)
        nu = torch.zeros_like(g)
        eta = None if G is None else g.new_zeros(G.shape[:2])
        live, sub_H, sub = None, H, problem
        iteration = 0
        for iteration in range(1, budget + 1):  # noqa: B007  (the count is returned)
            pick = functools.partial(_select, live)
            u, l, r = pick(upper), pick(lower), pick(rows)
            x_new, eta_new, nu_new, r, degenerate = self._solve_on(sub_H, sub.g, sub.lb, sub.ub, sub.G, sub.h, u, l, r)
            new_u, new_l, new_r, same = _next_active_set(sub, x_new, nu_new, eta_new, u, l, r, tolerance)
            same &= ~degenerate
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
            sub_H, sub = _take(H, problem, live)
        return x, nu, eta, (upper, lower, rows), done, iteration

    def _kkt_tolerance(self, dtype) -> float:
        """The KKT error at which an interior-point solution is accepted: `kkt_tolerance` in
        float64, 1e-4 in float32 (its rounding, 1e-7, times the conditioning of the step's Hessian)."""
        return self.kkt_tolerance if dtype == torch.float64 else max(self.kkt_tolerance, 1e-4)

    def _initial_sets(self, problem: QPProblem):
        """The last solve's active set (same batch shape), else none: the first iteration then
        solves the unconstrained problem."""
        B, N = problem.g.shape
        m = 0 if problem.G is None else problem.G.shape[1]
        if self._last is not None:
            upper, lower, rows = self._last
            if upper.shape == (B, N) and upper.device == problem.g.device and (rows is None) == (m == 0) \
                    and (rows is None or rows.shape == (B, m)):
                return upper & torch.isfinite(problem.ub), lower & torch.isfinite(problem.lb) & ~upper, rows
        none = torch.zeros(B, N, dtype=torch.bool, device=problem.g.device)
        return none, none.clone(), None if m == 0 else torch.zeros(B, m, dtype=torch.bool, device=problem.g.device)

    @staticmethod
    def _solve_on(H, g, lb, ub, G, h, upper, lower, rows):
        """The equality-constrained problem of one active set. Returns x [B,N], the row
        multipliers eta [B,m] (None without G), the bound multipliers nu [B,N] (nu > 0 pushes
        against an upper bound, nu < 0 against a lower one; 0 on free variables), the rows held
        [B,m] (those of `rows` that the free variables can hold) and whether the active rows were
        degenerate [B] (dependent: the solution is then no vertex to stop at)."""
        held = upper | lower
        value = torch.where(upper, ub, torch.where(lower, lb, torch.zeros_like(g)))
        factor = H.factor(~held)
        x = factor.solve(-g.unsqueeze(-1), value.unsqueeze(-1))  # [B,N,1]
        eta, degenerate = None, torch.zeros_like(g[:, 0], dtype=torch.bool)
        if G is not None:
            # x(eta) = x - Z eta with Z = H_free^-1 G_A^T; the active rows hold with equality
            # a row whose variables are all held cannot be held by the free ones: it stays out
            free_part = (G.abs() * (~held).to(g.dtype)[:, None, :]).sum(-1)
            rows = rows & (free_part > 1e-12 * G.abs().sum(-1))
            active = rows.to(g.dtype)
            G_active = G * active[..., None]
            Z = factor.solve(G_active.transpose(1, 2))  # [B,N,m]
            schur = G_active @ Z + torch.diag_embed(1 - active)
            L, info = torch.linalg.cholesky_ex(schur)
            # active rows dependent on each other and the held bounds make the Schur complement
            # singular: no unique multipliers, and this active set is not a vertex to stop at
            size = (schur.diagonal(dim1=1, dim2=2) * active).amax(-1, keepdim=True)
            small = (L.diagonal(dim1=1, dim2=2) ** 2 < 1e-10 * size) & rows
            degenerate = (info != 0) | small.any(-1)
            residual = active * ((G_active @ x).squeeze(-1) - h)
            eta = torch.cholesky_solve(residual.unsqueeze(-1), L)
            x = x - Z @ eta
            # one step of iterative refinement: on a nearly singular H the Schur complement is
            # ill-conditioned and the first solve leaves a stationarity residual well above rounding
            free = (~held).to(g.dtype).unsqueeze(-1)
            r_x = free * -(H.matvec(x) + g.unsqueeze(-1) + G_active.transpose(1, 2) @ eta)
            r_rows = active.unsqueeze(-1) * (h.unsqueeze(-1) - G_active @ x)
            dx = factor.solve(r_x)
            d_eta = torch.cholesky_solve(G_active @ dx - r_rows, L)
            x, eta = x + dx - Z @ d_eta, (eta + d_eta).squeeze(-1)
        gradient = H.matvec(x).squeeze(-1) + g
        if G is not None:
            gradient = gradient + (G.transpose(1, 2) @ eta.unsqueeze(-1)).squeeze(-1)
        nu = torch.where(held, -gradient, torch.zeros_like(gradient))
        return x.squeeze(-1), eta, nu, rows, degenerate


def _next_active_set(problem: QPProblem, x, nu, eta, upper, lower, rows, tolerance: float):
    """The active set a solution points to: held bounds whose multiplier has the wrong sign are
    released, free variables past a bound are held, and likewise for the rows. Returns the new
    (upper [B,N], lower [B,N], rows [B,m] or None) and whether nothing changed [B]."""
    g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
    # sizes that make the tolerances relative: bounds, gradient, rows of G
    x_tol = tolerance * (1 + torch.where(torch.isfinite(lb), lb.abs(), 0) + torch.where(torch.isfinite(ub), ub.abs(), 0))
    nu_tol = tolerance * (1 + g.abs().amax(-1, keepdim=True))
    new_upper = torch.where(upper, nu > -nu_tol, x > ub + x_tol) & torch.isfinite(ub)
    new_lower = torch.where(lower, nu < nu_tol, x < lb - x_tol) & torch.isfinite(lb) & ~new_upper
    same = (new_upper == upper).all(-1) & (new_lower == lower).all(-1) & torch.isfinite(x).all(-1)
    new_rows = None
    if G is not None:
        h_tol = tolerance * (1 + h.abs() + G.abs().sum(-1))
        Gx = (G @ x.unsqueeze(-1)).squeeze(-1)
        new_rows = torch.where(rows, eta > -nu_tol, Gx > h + h_tol)
        same &= (new_rows == rows).all(-1)
    return new_upper, new_lower, new_rows, same


def _select(rows: torch.Tensor | None, t: torch.Tensor | None) -> torch.Tensor | None:
    """t's batch rows `rows` (all without rows; None stays None)."""
    return t if rows is None or t is None else t.index_select(0, rows)


DENSE_BELOW = 32  # gathered batches smaller than this are solved densely: the tree's level-by-level
                 # elimination costs a fixed time per level, a dense Cholesky of a few matrices less


def _take(H, problem: QPProblem, rows: torch.Tensor):
    """The Hessian operator and problem of the subjects `rows` [k]."""
    pick = functools.partial(_select, rows)
    sub_H: DenseHessian | TreeHessian
    if isinstance(H, DenseHessian):
        sub_H = DenseHessian(pick(H.H))
    else:
        sub_tree = TreeHessian(H.tree, pick(H.axes), pick(H.node_weight), pick(H.position_weight), H.damping)
        sub_H = DenseHessian(sub_tree.dense()) if len(rows) < DENSE_BELOW else sub_tree
    tree = sub_H if isinstance(sub_H, TreeHessian) else None
    dense = sub_H.H if isinstance(sub_H, DenseHessian) else None
    sub = QPProblem(dense, pick(problem.g), pick(problem.lb), pick(problem.ub), pick(problem.G), pick(problem.h), tree)
    return sub_H, sub


def _interior_point(H, problem: QPProblem, iterations: int, tolerance: float):
    """Mehrotra's predictor-corrector on the QP, batched; returns the active set it points to,
    (upper [B,N], lower [B,N], rows [B,m] or None), for the active-set iterations to confirm.

    Slacks s and multipliers z for each finite bound and each row; each iteration factorises
    H + diag(z/s) (bounds) and handles the rows' G^T diag(z/s) G by the Woodbury identity, so the
    tree structure of H is kept."""
    g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
    dtype = g.dtype
    has_l, has_u = torch.isfinite(lb), torch.isfinite(ub)
    f_l, f_u = has_l.to(dtype), has_u.to(dtype)
    lb0, ub0 = torch.where(has_l, lb, 0), torch.where(has_u, ub, 0)
    everything = torch.ones_like(g, dtype=torch.bool)
    # start: the unconstrained minimiser pulled inside the bounds, unit slacks and multipliers
    x = H.factor(everything).solve(-g.unsqueeze(-1)).squeeze(-1)
    x = torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
    x = torch.where(has_l & has_u, torch.minimum(torch.maximum(x, lb0), ub0), x)
    scale = 1.0 + g.abs().amax(-1, keepdim=True)
    s_l = torch.where(has_l, (x - lb0).clamp(min=1.0), 1.0)
    s_u = torch.where(has_u, (ub0 - x).clamp(min=1.0), 1.0)
    z_l, z_u = f_l.clone(), f_u.clone()
    if G is not None:
        s_g = (h - (G @ x.unsqueeze(-1)).squeeze(-1)).clamp(min=1.0)
        z_g = torch.ones_like(h)
    count = (f_l.sum(-1) + f_u.sum(-1) + (0 if G is None else G.shape[1])).clamp(min=1)
    tiny = torch.finfo(dtype).tiny
    polish = max(1e-3 * tolerance, 10 * torch.finfo(dtype).eps)  # iterate on to this, stop where rounding takes over
    moving = torch.ones(g.shape[0], dtype=torch.bool, device=g.device)

    for _ in range(iterations):
        Gx = None if G is None else (G @ x.unsqueeze(-1)).squeeze(-1)
        r_d = H.matvec(x.unsqueeze(-1)).squeeze(-1) + g - z_l + z_u
        if G is not None:
            r_d = r_d + (G.transpose(1, 2) @ z_g.unsqueeze(-1)).squeeze(-1)
        r_l = f_l * (x - lb0 - s_l)
        r_u = f_u * (ub0 - x - s_u)
        r_g = None if G is None else h - Gx - s_g
        gap = (f_l * s_l * z_l).sum(-1) + (f_u * s_u * z_u).sum(-1) + (0 if G is None else (s_g * z_g).sum(-1))
        mu = (gap / count)[:, None]
        D_l, D_u = f_l * z_l / s_l, f_u * z_u / s_u
        factor = H.factor(everything, D_l + D_u)
        K = M = None
        if G is not None:
            K = factor.solve(G.transpose(1, 2))  # [B,N,m]
            M = G @ K + torch.diag_embed(s_g / z_g)  # the rows' Schur complement [B,m,m]

        def direction(c_l, c_u, c_g):
            # the rows stay in the system as [H' G^T; G -S/Z] [dx; dz_g]: eliminating dz_g first
            # would divide by the vanishing slacks of the active rows and lose dx to cancellation
            rhs = -r_d + f_l * (c_l - z_l * r_l) / s_l - f_u * (c_u - z_u * r_u) / s_u
            dx = factor.solve(rhs.unsqueeze(-1))
            ds_g = dz_g = None
            if G is not None:
                dz_g = torch.linalg.solve_ex(M, G @ dx + (c_g / z_g - r_g).unsqueeze(-1))[0]
                dx = dx - K @ dz_g
                dz_g = dz_g.squeeze(-1)
            dx = dx.squeeze(-1)
            ds_l, ds_u = f_l * (dx + r_l), f_u * (-dx + r_u)
            dz_l, dz_u = f_l * (c_l - z_l * ds_l) / s_l, f_u * (c_u - z_u * ds_u) / s_u
            if G is not None:
                ds_g = r_g - (G @ dx.unsqueeze(-1)).squeeze(-1)
            return dx, ds_l, ds_u, dz_l, dz_u, ds_g, dz_g

        def step_length(pairs):
            alpha = torch.ones_like(mu)
            for v, dv in pairs:
                if v is not None:
                    ratio = torch.where(dv < 0, -v / dv.clamp(max=-tiny), torch.full_like(v, torch.inf))
                    alpha = torch.minimum(alpha, ratio.amin(-1, keepdim=True))
            return alpha

        # predictor (affine scaling), then the corrector with centring sigma = (mu_aff / mu)^3
        c_l0, c_u0 = -f_l * s_l * z_l, -f_u * s_u * z_u
        c_g0 = None if G is None else -s_g * z_g
        dx, ds_l, ds_u, dz_l, dz_u, ds_g, dz_g = direction(c_l0, c_u0, c_g0)
        a = step_length([(s_l, ds_l), (s_u, ds_u), (z_l, dz_l), (z_u, dz_u), (s_g if G is not None else None, ds_g),
                         (z_g if G is not None else None, dz_g)])
        gap_aff = (f_l * (s_l + a * ds_l) * (z_l + a * dz_l)).sum(-1) + (f_u * (s_u + a * ds_u) * (z_u + a * dz_u)).sum(-1)
        if G is not None:
            gap_aff = gap_aff + ((s_g + a * ds_g) * (z_g + a * dz_g)).sum(-1)
        sigma = ((gap_aff / count)[:, None] / mu.clamp(min=tiny)).clamp(0, 1) ** 3
        target = sigma * mu
        c_l = f_l * (target - s_l * z_l - ds_l * dz_l)
        c_u = f_u * (target - s_u * z_u - ds_u * dz_u)
        c_g = None if G is None else target - s_g * z_g - ds_g * dz_g
        dx, ds_l, ds_u, dz_l, dz_u, ds_g, dz_g = direction(c_l, c_u, c_g)
        a = 0.99 * step_length([(s_l, ds_l), (s_u, ds_u), (z_l, dz_l), (z_u, dz_u),
                                (s_g if G is not None else None, ds_g), (z_g if G is not None else None, dz_g)])
        a = torch.where(moving[:, None], a.clamp(max=1.0), torch.zeros_like(a))
        x = x + a * dx
        s_l, s_u, z_l, z_u = s_l + a * ds_l, s_u + a * ds_u, z_l + a * dz_l, z_u + a * dz_u
        s_l, s_u = torch.where(has_l, s_l, 1.0), torch.where(has_u, s_u, 1.0)
        z_l, z_u = f_l * z_l, f_u * z_u
        if G is not None:
            s_g, z_g = s_g + a * ds_g, z_g + a * dz_g
        # a subject that has converged stops moving: iterating on would divide its vanishing
        # slacks and multipliers by each other and lose them to rounding
        # (or once complementarity is far below rounding and the residuals no longer fall)
        moving = ~_converged(x, z_l, z_u, z_g if G is not None else None, s_l, s_u, H, problem, polish) \
            & (mu.squeeze(-1) > 1e-3 * torch.finfo(dtype).eps * scale.squeeze(-1))
        if not bool(moving.any()):
            break
    converged = _converged(x, z_l, z_u, z_g if G is not None else None, s_l, s_u, H, problem, tolerance)
    x = torch.minimum(torch.maximum(x, lb), ub)  # the iterates meet the bounds only in the limit
    # a constraint is active where its multiplier exceeds its slack (strict complementarity)
    upper = has_u & (z_u > s_u)
    lower = has_l & (z_l > s_l) & ~upper
    rows = None if G is None else z_g > s_g
    return x, z_u - z_l, None if G is None else z_g, converged, (upper, lower, rows)


def _converged(x, z_l, z_u, z_g, s_l, s_u, H, problem: QPProblem, tolerance: float) -> torch.Tensor:
    """Whether an interior-point iterate satisfies the KKT conditions to `tolerance`, relative to
    the problem's scale: stationarity, the bounds and rows, and complementarity. -> [B] bool"""
    g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
    has_l, has_u = torch.isfinite(lb), torch.isfinite(ub)
    scale = 1.0 + g.abs().amax(-1)
    stationarity = H.matvec(x.unsqueeze(-1)).squeeze(-1) + g - z_l + z_u
    primal = torch.maximum(torch.where(has_l, lb - x, 0), torch.where(has_u, x - ub, 0)).clamp(min=0)
    bound_scale = 1.0 + torch.where(has_l, lb.abs(), 0).amax(-1) + torch.where(has_u, ub.abs(), 0).amax(-1)
    gap = torch.where(has_l, z_l * (x - lb).abs(), 0) + torch.where(has_u, z_u * (ub - x).abs(), 0)
    error = torch.maximum(primal.amax(-1) / bound_scale, gap.amax(-1) / (scale * bound_scale))
    if G is not None:
        stationarity = stationarity + (G.transpose(1, 2) @ z_g.unsqueeze(-1)).squeeze(-1)
        Gx = (G @ x.unsqueeze(-1)).squeeze(-1)
        row_scale = 1.0 + h.abs() + G.abs().sum(-1) * x.abs().amax(-1, keepdim=True)
        error = torch.maximum(error, ((Gx - h).clamp(min=0) / row_scale).amax(-1))
        error = torch.maximum(error, (z_g * (h - Gx).abs() / (scale[:, None] * row_scale)).amax(-1))
    error = torch.maximum(error, stationarity.abs().amax(-1) / scale)
    return error <= tolerance

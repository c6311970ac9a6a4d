"""The interior-point rescue of the batched QP solver: Mehrotra's primal-dual predictor-corrector,
batched, for the subjects the active-set iterations did not finish.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h

`interior_point` is longer than this project's 80 lines on purpose: Mehrotra's method read top to
bottom as textbooks write it (start, residuals, predictor, corrector, step length); split, its
dozen shared quantities would travel through every call.
"""

from __future__ import annotations

import torch

from .base import QPProblem


def interior_point(H, problem: QPProblem, iterations: int, tolerance: float):
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
        moving = ~kkt_converged(x, z_l, z_u, z_g if G is not None else None, s_l, s_u, H, problem, polish) \
            & (mu.squeeze(-1) > 1e-3 * torch.finfo(dtype).eps * scale.squeeze(-1))
        if not bool(moving.any()):
            break
    converged = kkt_converged(x, z_l, z_u, z_g if G is not None else None, s_l, s_u, H, problem, tolerance)
    x = torch.minimum(torch.maximum(x, lb), ub)  # the iterates meet the bounds only in the limit
    # a constraint is active where its multiplier exceeds its slack (strict complementarity)
    upper = has_u & (z_u > s_u)
    lower = has_l & (z_l > s_l) & ~upper
    rows = None if G is None else z_g > s_g
    return x, z_u - z_l, None if G is None else z_g, converged, (upper, lower, rows)


def kkt_converged(x, z_l, z_u, z_g, s_l, s_u, H, problem: QPProblem, tolerance: float) -> torch.Tensor:
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

"""The linear rows G x <= h of the batched QP, solved in their Schur complement.

With the bounds' active set fixed (the held variables eliminated from the factorisation of H), the
rows are a small problem of their own. Let x_F be the solution without rows and Z = H_F^-1 G^T
([N,m]); a multiplier eta >= 0 on the rows moves the solution to x = x_F - Z eta and the rows'
slacks to

    w = h - G x = S eta - b,     S = G Z  [m,m],   b = G x_F - h,

so the rows' optimal active set is found in this m-dimensional space, with no factorisation of H
repeated: the dual active-set method of Goldfarb and Idnani (Math. Programming 27, 1983). From a
dual-feasible set (the last step's, less the rows whose multiplier turned negative) it adds the
most violated row, increasing its multiplier until the row holds, and drops the rows whose
multiplier reaches zero on the way. It keeps the active rows linearly independent: a row that
depends on them (a shoulder at a vertex of its coupled limits, or a row on held joints) is reached
by a pure dual step, never by a singular system, and the solve cannot cycle. Each change costs a
Cholesky factorisation of an [m,m] matrix; on iCub m = 18 and a tracked step changes one or two
rows of the few subjects whose rows are active.
"""

from __future__ import annotations

import torch


def row_values(G: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """G x for G [B,m,N], x [B,N] -> [B,m]; one matrix product when every subject has the same G
    (the tracker's coupled limits, expanded over the batch)."""
    if G.stride(0) == 0:
        return x @ G[0].T
    return (G @ x.unsqueeze(-1)).squeeze(-1)


def row_forces(G: torch.Tensor, eta: torch.Tensor) -> torch.Tensor:
    """G^T eta for G [B,m,N], eta [B,m] -> [B,N]; one matrix product when G is expanded over the batch."""
    if G.stride(0) == 0:
        return eta @ G[0]
    return (G.transpose(1, 2) @ eta.unsqueeze(-1)).squeeze(-1)


def _dependence(dtype) -> float:
    """A row's curvature left by the active rows, relative to its own, below which it depends on them."""
    return max(1e-10, 1e3 * torch.finfo(dtype).eps)


def _masked(S: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
    """S on the active rows [B,m], the identity on the others. -> [B,m,m]"""
    a = active.to(S.dtype)
    return S * (a[:, :, None] * a[:, None, :]) + torch.diag_embed(1 - a)


def _independent(S: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
    """The active rows [B,m] less those that depend on the ones before them (held bounds can make a
    row of the last active set dependent): its Cholesky pivot, the curvature it adds, is below
    `_dependence` of its own diagonal. One row dropped per subject and pass."""
    m = S.shape[1]
    index = torch.arange(m, device=S.device)
    for _ in range(m):
        L, info = torch.linalg.cholesky_ex(_masked(S, active))
        pivot = L.diagonal(dim1=1, dim2=2) ** 2
        valid = (info == 0)[:, None] | (index < (info - 1)[:, None])  # cholesky_ex stops at the first failure
        bad = active & ((valid & (pivot <= _dependence(S.dtype) * S.diagonal(dim1=1, dim2=2)))
                        | (index == (info - 1)[:, None]))
        if not bool(bad.any()):
            break
        first = torch.where(bad, index, m).amin(-1, keepdim=True)
        active = active & (index != first)
    return active


def _multipliers(S: torch.Tensor, b: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
    """The multipliers that make the active rows hold exactly: S_AA eta_A = b_A, 0 elsewhere. -> [B,m]"""
    a = active.to(S.dtype)
    L = torch.linalg.cholesky_ex(_masked(S, active))[0]
    return a * torch.cholesky_solve((a * b).unsqueeze(-1), L).squeeze(-1)


def optimal_rows(S: torch.Tensor, b: torch.Tensor, active: torch.Tensor, slack_tolerance: torch.Tensor,
                 multiplier_tolerance: torch.Tensor, budget: int, equality: torch.Tensor | None = None):
    """The rows' optimal active set and multipliers by Goldfarb and Idnani's method, from `active`.

    S [B,m,m] (symmetric positive semidefinite), b [B,m]: the rows' Schur complement and violations
    at eta = 0 (see the module's docstring); active [B,m] bool: the first guess; slack_tolerance
    [B,m], multiplier_tolerance [B,1]: how far a slack or a multiplier may be negative; equality
    [m] bool: rows that hold with equality (always active, their multipliers of either sign; a zero
    row, S's diagonal 0 there, is no constraint and stays out).
    Returns eta [B,m], active [B,m], done [B] (every row holds, every inequality's multiplier >= 0;
    False where the rows are infeasible with the held bounds or the budget ran out) and the changes made.
    """
    steps = 0
    free_sign = torch.zeros_like(active) if equality is None else equality.expand_as(active)
    active = active & ~free_sign | free_sign & (S.diagonal(dim1=1, dim2=2) > 0)
    # a dual-feasible start: the last active set less its dependent rows and, one pass at a time,
    # the rows whose multiplier is negative (releasing one can turn another negative)
    for steps in range(1, budget + 1):  # noqa: B007  (the count is returned)
        active = _independent(S, active)
        eta = _multipliers(S, b, active)
        negative = active & (eta < -multiplier_tolerance) & ~free_sign
        if not bool(negative.any()):
            break
        active = active & ~negative
    eta = torch.where(free_sign, eta, eta.clamp(min=0))
    stuck = torch.zeros_like(active[:, 0])
    pending = torch.full_like(stuck, -1, dtype=torch.long)
    for step in range(steps + 1, budget + 1):
        steps = step
        slack = (S @ eta.unsqueeze(-1)).squeeze(-1) - b
        violated = (slack < -slack_tolerance) & ~active & ~stuck[:, None]
        if not bool(violated.any()):
            break
        eta, active, stuck, pending = _step(S, eta, slack, active, violated, stuck, pending, free_sign)
    # the multipliers of the final set, exactly (the steps' updates drift by rounding)
    eta = _multipliers(S, b, active)
    slack = (S @ eta.unsqueeze(-1)).squeeze(-1) - b
    # an active equality holds by its solve (to the rounding of S, which a nearly singular H makes
    # large: iterative refinement follows, _with_rows); one left out must hold as it is
    holds = torch.where(free_sign, active | (slack.abs() <= slack_tolerance), slack >= -slack_tolerance)
    signed = free_sign | (eta >= -multiplier_tolerance)
    done = ~stuck & holds.all(-1) & signed.all(-1) & torch.isfinite(eta).all(-1)
    return eta, active, done, steps


def _step(S, eta, slack, active, violated, stuck, pending, free_sign):
    """One step of Goldfarb and Idnani's method for each subject with a violated row: row p's
    multiplier grows by t while the active rows' multipliers change to keep them holding, t the
    full step (row p holds: it joins the active set) or the partial step at which an active row's
    multiplier reaches zero (that row leaves; p stays `pending`), whichever is shorter. p is the
    pending row, else the most violated. Subjects with neither step (the rows are infeasible with
    the held bounds) are `stuck`. Equality rows (free_sign) never leave: their multipliers may
    take either sign."""
    B, m = slack.shape
    batch = torch.arange(B, device=S.device)
    moving = violated.any(-1)
    keep = (pending >= 0) & violated[batch, pending.clamp(min=0)]
    p = torch.where(keep, pending, torch.where(violated, slack, torch.inf).argmin(-1))  # [B]
    a = active.to(S.dtype)
    column = S[batch, :, p]  # [B,m]: S e_p
    L = torch.linalg.cholesky_ex(_masked(S, active))[0]
    r = a * torch.cholesky_solve((a * column).unsqueeze(-1), L).squeeze(-1)  # the active rows' multipliers fall by t r
    sigma = column[batch, p] - (column * r).sum(-1)  # the curvature row p adds to the active rows'
    tiny = torch.finfo(S.dtype).tiny
    full = torch.where(sigma > _dependence(S.dtype) * column[batch, p], -slack[batch, p] / sigma.clamp(min=tiny), torch.inf)
    partial, blocking = torch.where(active & (r > 0) & ~free_sign, eta / r.clamp(min=tiny), torch.inf).min(-1)
    t = torch.minimum(full, partial)
    blocked = moving & ~torch.isfinite(t)
    go = moving & ~blocked
    t = torch.where(go, t, torch.zeros_like(t))
    one_p = torch.nn.functional.one_hot(p, m).to(torch.bool)
    dropped = (go & (partial < full))[:, None] & torch.nn.functional.one_hot(blocking, m).to(torch.bool)
    eta = eta - t[:, None] * r + t[:, None] * one_p
    eta = torch.where(dropped, 0.0, torch.where(free_sign, eta, eta.clamp(min=0)))
    active = (active | ((go & (full <= partial))[:, None] & one_p)) & ~dropped
    pending = torch.where(go & (partial < full), p, -1)
    return eta, active, stuck | blocked, pending

"""The QP's Hessian as a dense batch [B,N,N]: the batched solver's operator where the step's tree
structure is not available (position targets off the base) or does not pay (small gathered batches)."""

from __future__ import annotations

import torch


class DenseHessian:
    """H as a dense batch [B,N,N], with the two operations the active-set method needs."""

    def __init__(self, H: torch.Tensor):
        self.H = H

    def matvec(self, x: torch.Tensor) -> torch.Tensor:
        """x: [B,N,k] -> H x [B,N,k]."""
        return self.H @ x

    def factor(self, free: torch.Tensor, extra: torch.Tensor | None = None) -> "DenseFactor":
        """H + diag(extra) restricted to the `free` variables [B,N] (bool), Cholesky-factorised."""
        return DenseFactor(self.H if extra is None else self.H + torch.diag_embed(extra), free)

    def select(self, subjects: torch.Tensor) -> "DenseHessian":
        """The Hessians of the subjects [k] (indices)."""
        return DenseHessian(self.H.index_select(0, subjects))


class DenseFactor:
    """H [B,N,N] restricted to the free variables [B,N], Cholesky-factorised (L, info [B]: 0 where
    it exists)."""

    def __init__(self, H: torch.Tensor, free: torch.Tensor):
        self.H, self.free = H, free.to(H.dtype)
        f = self.free
        reduced = H * (f[:, :, None] * f[:, None, :]) + torch.diag_embed(1 - f)
        self.L, self.info = torch.linalg.cholesky_ex(reduced)

    def select(self, subjects: torch.Tensor) -> "DenseFactor":
        """The factorisation of the subjects [k] (indices), without factorising again."""
        picked = object.__new__(DenseFactor)
        picked.H, picked.free = self.H.index_select(0, subjects), self.free.index_select(0, subjects)
        picked.L, picked.info = self.L.index_select(0, subjects), self.info.index_select(0, subjects)
        return picked

    def solve(self, rhs: torch.Tensor, held: torch.Tensor | None = None) -> torch.Tensor:
        """x with (H x)_i = rhs_i on the free variables, x_i = held_i on the others. [B,N,k] -> [B,N,k]."""
        f = self.free[..., None]
        c = torch.zeros_like(rhs) if held is None else (1 - f) * held
        b = f * (rhs - self.H @ c) + c
        z = torch.linalg.solve_triangular(self.L, b, upper=False)
        return torch.linalg.solve_triangular(self.L.transpose(-1, -2), z, upper=True)

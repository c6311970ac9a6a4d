"""The step's Hessian on a kinematic tree, solved in O(n) by eliminating joints leaves first.

With orientation targets on links and one position target on the base, the step's normal matrix is

    H = J^T W J + lambda I,    target t's angular velocity  omega_t = omega_B + sum_j M_tj a_j s_dot_j

and the base's linear velocity is its own block. Write omega_j for the angular velocity of joint
j's child frame: omega_j = omega_parent(j) + a_j s_dot_j. A subtree's cost is a quadratic in the
angular velocity of the frame it hangs from, so the joints can be eliminated from the leaves up,
one tree level at a time, carrying a 3x3 matrix P_j per joint (the subtree's "articulated"
weight, as in the articulated-body algorithm):

    S_j = (weight of the targets on j) I + sum_children P_c,   u_j = S_j a_j,
    sigma_j = a_j^T u_j + lambda + d_j,                         P_j = S_j - u_j u_j^T / sigma_j

This is the Cholesky factorisation of H in a fill-free order, with 3x3 and scalar operations per
joint instead of a dense [6+n, 6+n] factorisation: at large batches it is several times faster.
A joint held at a bound (an active constraint) is simply not eliminated (P_j = S_j), so one
factorisation per active set serves every right-hand side. The joints' levels, and which rows of
which level each sum comes from, are compiled once per model in `joint_tree.py`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..capture import tracing
from .joint_tree import JointTree


@dataclass(frozen=True)
class TreeHessian:
    """H = J^T W J + damping I of the step, in structured form. N = 6 + n.

    axes: [B,n,3] the joints' world axes; node_weight: [B,n+1] summed weights of the orientation
    targets on each joint's frame (last: the base's); position_weight: [B] summed weights of the
    position targets on the base link; damping: lambda.
    """

    tree: JointTree
    axes: torch.Tensor
    node_weight: torch.Tensor
    position_weight: torch.Tensor
    damping: float

    @classmethod
    def from_targets(cls, tree: JointTree, axes: torch.Tensor, damping: float, n_position: int, *,
                     w_position: torch.Tensor | None = None, w_orientation: torch.Tensor | None = None) -> "TreeHessian":
        """w_position [B,n_p], w_orientation [B,n_o]: target weights (None: all 1), by keyword and in
        the order `task.normal_equations` takes them."""
        B = axes.shape[0]
        if w_orientation is None:
            node_weight = tree.attach.sum(0).expand(B, -1)
        else:
            node_weight = w_orientation @ tree.attach.to(w_orientation.dtype)
        if w_position is None:
            position_weight = axes.new_full((B,), float(n_position))
        else:
            position_weight = w_position.sum(-1)
        return cls(tree, axes, node_weight, position_weight, damping)

    def dense(self) -> torch.Tensor:
        """The matrix itself: [B,N,N]."""
        B, n = self.axes.shape[:2]
        D = self.tree.ancestors.to(self.axes.dtype)  # [n+1,n] (a no-op unless the model was compiled in another precision)
        H = self.axes.new_zeros(B, 6 + n, 6 + n)
        H.diagonal(dim1=1, dim2=2)[:, :3] += self.position_weight[:, None]
        H.diagonal(dim1=1, dim2=2)[:, 3:6] += self.node_weight.sum(-1, keepdim=True)
        columns = self.node_weight @ D  # [B,n]: weight of the targets each joint moves
        coupling = columns[..., None] * self.axes
        H[:, 6:, 3:6] = coupling
        H[:, 3:6, 6:] = coupling.transpose(1, 2)
        pairs = (D.T * self.node_weight[:, None, :]) @ D  # [B,n,n]
        H[:, 6:, 6:] = pairs * (self.axes @ self.axes.transpose(1, 2))
        H.diagonal(dim1=1, dim2=2).add_(self.damping)
        return H

    def matvec(self, x: torch.Tensor) -> torch.Tensor:
        """H x without forming H. x: [B,N,k] -> [B,N,k]."""
        D = self.tree.ancestors.to(self.axes.dtype)  # [n+1,n] (a no-op unless the model was compiled in another precision)
        n, (B, _, k) = D.shape[1], x.shape
        xT = x.permute(1, 2, 0)  # [N,k,B], batch last: the tree sums become single matrix products
        axes = self.axes.permute(1, 2, 0)[:, :, None]  # [n,3,1,B]
        spin = axes * xT[6:, None]  # [n,3,k,B]
        omega = xT[None, 3:6] + (D @ spin.reshape(n, -1)).view(n + 1, 3, k, B)  # each joint's frame, then the base's
        weighted = self.node_weight.T[:, None, None] * omega
        below = (D.T @ weighted.reshape(n + 1, -1)).view(n, 3, k, B)  # summed over the targets each joint moves
        out = torch.empty_like(xT)
        out[:3] = self.position_weight * xT[:3]
        out[3:6] = weighted.sum(0)
        out[6:] = (axes * below).sum(1)
        return (out + self.damping * xT).permute(2, 0, 1)

    def factor(self, free: torch.Tensor, extra: torch.Tensor | None = None) -> "TreeFactor":
        """Factorise H + diag(extra) restricted to the `free` variables [B,N] (bool); the others are
        held at given values in `TreeFactor.solve`. extra: [B,N] or None."""
        return TreeFactor(self, free, extra)

    def select(self, subjects: torch.Tensor) -> "TreeHessian":
        """The Hessians of the subjects [k] (indices)."""
        pick = lambda t: t.index_select(0, subjects)  # noqa: E731
        return TreeHessian(self.tree, pick(self.axes), pick(self.node_weight), pick(self.position_weight), self.damping)


class TreeFactor:
    """H restricted to the free variables, factorised leaves first (see the module's docstring).

    Internally batch-last ([joint, ..., B]) and one tensor per tree level (`JointTree.levels`):
    every level's work is a few elementwise operations on its own rows. The factor (gain, u) is
    kept whole as well, each level a view of it, so that `select` takes one gather per tensor
    rather than one per level (the active set selects subjects at every iteration)."""

    def __init__(self, hessian: TreeHessian, free: torch.Tensor, extra: torch.Tensor | None):
        tree = hessian.tree
        n, B = hessian.axes.shape[1], hessian.axes.shape[0]
        dtype = hessian.axes.dtype
        self.tree = tree
        self.free = free.to(dtype).T.contiguous()  # [N,B]
        diagonal = torch.full((6 + n, B), hessian.damping, dtype=dtype, device=free.device)
        if extra is not None:
            diagonal.add_(extra.T)  # in place: the sum would take extra.T's transposed layout
        # per joint, in level order
        axes = hessian.axes.index_select(1, tree.order).permute(1, 2, 0).contiguous()  # [n,3,B]
        joint_free = self.free[6:].index_select(0, tree.order)
        joint_diagonal = diagonal[6:].index_select(0, tree.order)
        weight = hessian.node_weight.T.index_select(0, tree.node_order)  # [n+1,B], the base last
        eye = torch.eye(3, dtype=dtype, device=free.device)[:, :, None]
        gains: list[torch.Tensor] = []  # [m,B] per level; 0: held, not eliminated
        us: list[torch.Tensor] = []  # [m,3,B] per level: S_j a_j
        passed: list[torch.Tensor] = []  # [m,3,3,B] per level: P_j, what each joint passes to its parent
        for h, (start, stop) in enumerate(tree.levels + ((n, n + 1),)):
            S = _gathered(weight[start:stop, None, None, :] * eye, passed, tree.up[h], stop - start)  # [m,3,3,B]
            assert S is not None  # the targets' weights start every level's sum
            if h == len(tree.levels):
                break
            a = axes[start:stop]  # [m,3,B]
            column = S.unbind(2)  # S_j's columns [m,3,B]: u = S_j a without an [m,3,3,B] product
            u = (column[0] * a[:, 0:1]).addcmul_(column[1], a[:, 1:2]).addcmul_(column[2], a[:, 2:3])
            gain = joint_free[start:stop] / (a * u).sum(1).add_(joint_diagonal[start:stop])
            passed.append(torch.addcmul(S, (gain[:, None] * u)[:, :, None], u[:, None], value=-1.0))
            gains.append(gain)
            us.append(u)
        # kept whole, [n,B] and [n,3,B], the levels views of them: `select` picks subjects in one call each
        self._whole = (torch.cat(gains) if gains else axes.new_zeros(0, B), torch.cat(us) if us else axes, axes)
        self._levels()
        # the base: omega_B's 3x3 block and p_dot_B's diagonal, held components replaced by identity
        f = self.free[3:6].T  # [B,3]
        assert S is not None  # the last level's: the base's
        self.base_weight = S[0].permute(2, 0, 1)  # [B,3,3]
        base = self.base_weight * (f[:, :, None] * f[:, None, :]) + torch.diag_embed(f * diagonal[3:6].T + (1 - f))
        # a Cholesky factor, not an inverse: this block can be nearly singular (targets that the
        # joints alone can match leave the base only the damping), and only a factorisation keeps
        # the solve backward stable there
        self.base_factor, self.positive = _cholesky3(base)
        self.linear = (hessian.position_weight[None, :] + diagonal[:3])  # [3,B]

    def select(self, subjects: torch.Tensor) -> "TreeFactor":
        """The factorisation of the subjects [k] (indices), without factorising again."""
        last = lambda t: t.index_select(-1, subjects)  # noqa: E731  (batch-last tensors)
        first = lambda t: t.index_select(0, subjects)  # noqa: E731
        free, linear, gain, u, axes, base_weight, base_factor, positive = self.parts()
        return TreeFactor.from_parts(self.tree, (last(free), last(linear), last(gain), last(u), last(axes),
                                                 first(base_weight), first(base_factor), first(positive)))

    def parts(self) -> tuple[torch.Tensor, ...]:
        """The factorisation as tensors (a captured step returns them): free [N,B], linear [3,B],
        gain [n,B], u and axes [n,3,B] in level order, base_weight and base_factor [B,3,3], positive [B]."""
        return (self.free, self.linear, *self._whole, self.base_weight, self.base_factor, self.positive)

    @classmethod
    def from_parts(cls, tree: JointTree, parts) -> "TreeFactor":
        """The factorisation of `parts()` on `tree`, without factorising again."""
        factor = object.__new__(cls)
        factor.tree = tree
        factor.free, factor.linear, gain, u, axes, factor.base_weight, factor.base_factor, factor.positive = parts
        factor._whole = (gain, u, axes)
        factor._levels()
        return factor

    def _levels(self) -> None:
        """gain [m,B], u and axes [m,3,B] per level, as views of the whole tensors."""
        self.gain, self.u, self.axes = ([t[start:stop] for start, stop in self.tree.levels] for t in self._whole)

    def solve(self, rhs: torch.Tensor, held: torch.Tensor | None = None) -> torch.Tensor:
        """x with (H x)_i = rhs_i on the free variables and x_i = held_i on the others.
        rhs, held: [B,N,k] (held None: zeros) -> x [B,N,k]."""
        tree = self.tree
        L = len(tree.levels)
        r = rhs.permute(1, 2, 0)  # [N,k,B]
        c = None if held is None else held.permute(1, 2, 0) * (1 - self.free[:, None])
        # leaves to root: each level's values and y_j, the linear term each subtree passes to its parent's frame
        r_joint = r[6:].index_select(0, tree.order)
        c_joint = None if c is None else c[6:].index_select(0, tree.order)
        values: list[torch.Tensor] = []  # [m,k,B] per level
        passed: list[torch.Tensor] = []  # [m,3,k,B] per level
        for h, (start, stop) in enumerate(tree.levels):
            y = _gathered(None, passed, tree.up[h], stop - start)  # [m,3,k,B], None at the leaves
            a3, u3, gain2 = self.axes[h][:, :, None], self.u[h][:, :, None], self.gain[h][:, None]
            beta = r_joint[start:stop] if y is None else (a3 * y).sum(1).add_(r_joint[start:stop])  # [m,k,B]
            value = gain2 * beta if c_joint is None else torch.addcmul(c_joint[start:stop], gain2, beta)
            passed.append(-u3 * value[:, None] if y is None else torch.addcmul(y, u3, value[:, None], value=-1.0))
            values.append(value)
        y_base = _gathered(None, passed, tree.up[L], 1)
        f = self.free[3:6].T[..., None]  # [B,3,1]
        omega_rhs = r[3:6].permute(2, 0, 1) + (0 if y_base is None else y_base[0].permute(2, 0, 1))
        if c is not None:
            c_B = c[3:6].permute(2, 0, 1)  # [B,3,k]
            omega_rhs = f * (omega_rhs - self.base_weight @ c_B) + c_B
        else:
            omega_rhs = f * omega_rhs
        omega_B = _cholesky3_solve(omega_rhs, self.base_factor).permute(1, 2, 0)  # [3,k,B]
        linear = self.free[:3, None] * r[:3] / self.linear[:, None] + (0 if c is None else c[:3])
        # root to leaves: each joint's rate from its parent frame's angular velocity
        omega: list[torch.Tensor | None] = [None] * L + [omega_B[None]]  # [m,3,k,B] per level, the base last
        rates: list[torch.Tensor] = [values[0]] * L  # placeholders, each level's replaced below
        for h in reversed(range(L)):
            sources, permutation = tree.down[h]
            parts = [_rows(omega[level], rows) for level, rows in sources]
            omega_p = parts[0] if len(parts) == 1 else torch.cat(parts)
            if permutation is not None:
                omega_p = omega_p.index_select(0, permutation)
            u3, gain2 = self.u[h][:, :, None], self.gain[h][:, None]
            rates[h] = torch.addcmul(values[h], gain2, (u3 * omega_p).sum(1), value=-1.0)
            omega[h] = torch.addcmul(omega_p, self.axes[h][:, :, None], rates[h][:, None])
        joints = torch.cat(rates).index_select(0, tree.position) if L else r[6:]
        return torch.cat((linear, omega_B, joints)).permute(2, 0, 1).contiguous()


def _cholesky3(A: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The Cholesky factor L [B,3,3] of A [B,3,3] and where it exists [B] (the joints' pivots are
    positive with a positive damping; this block can be nearly singular). Captured, written out
    element by element: LAPACK's call through the dispatcher costs a small batch more than the
    whole step's fused loops."""
    if not tracing():
        L, info = torch.linalg.cholesky_ex(A)
        return L, info == 0
    a = A.unbind(-1)
    a00, a10, a20, a11, a21, a22 = a[0][:, 0], a[0][:, 1], a[0][:, 2], a[1][:, 1], a[1][:, 2], a[2][:, 2]
    l00 = a00.sqrt()
    l10, l20 = a10 / l00, a20 / l00
    l11 = (a11 - l10 * l10).sqrt()
    l21 = (a21 - l20 * l10) / l11
    d22 = a22 - l20 * l20 - l21 * l21
    l22 = d22.sqrt()
    zero = torch.zeros_like(l00)
    L = torch.stack((l00, zero, zero, l10, l11, zero, l20, l21, l22), -1).view(-1, 3, 3)
    positive = (a00 > 0) & (a11 - l10 * l10 > 0) & (d22 > 0)  # False for NaN too
    return L, positive


def _cholesky3_solve(b: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    """x with L L^T x = b, for b [B,3,k] and L [B,3,3] lower triangular (`_cholesky3`)."""
    if not tracing():
        return torch.cholesky_solve(b, L)
    l = L.unbind(-1)
    l00, l10, l20, l11, l21, l22 = l[0][:, 0:1], l[0][:, 1:2], l[0][:, 2:3], l[1][:, 1:2], l[1][:, 2:3], l[2][:, 2:3]
    b0, b1, b2 = b.unbind(1)  # [B,k] each
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return torch.stack((x0, x1, x2), 1)


def _rows(t: torch.Tensor | None, rows: torch.Tensor | None) -> torch.Tensor:
    assert t is not None  # the levels above are done first
    return t if rows is None else t.index_select(0, rows)


def _gathered(start: torch.Tensor | None, passed: list[torch.Tensor], sources, size: int) -> torch.Tensor | None:
    """`start` plus what the levels below pass to this level's `size` rows: sources as in `JointTree.up`
    (child level, its rows that feed this level or None for all, this level's rows or None for the
    same rows). None where both are nothing (a level of leaves with no start)."""
    total = start
    for child, rows, into in sources:
        part = _rows(passed[child], rows)
        if into is None:
            total = part if total is None else total + part
        else:
            base = part.new_zeros((size,) + part.shape[1:]) if total is None else total
            total = base.index_add(0, into, part)
    return total

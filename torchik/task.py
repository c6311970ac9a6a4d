"""The tracking task's normal equations, assembled from the tree's structure.

The step's objective ||v* - J nu||^2 + lambda ||nu||^2 needs H = J^T W J + lambda I and
g = -J^T W v*. For orientation targets the rows of J are known in closed form: target t's angular
velocity is omega_B + sum_j M_tj a_j s_dot_j, with a_j joint j's world axis and M_tj = 1 when
joint j moves target t. So, with target weights w (1, or 0 for a dropped target):

    H[omega, omega] = (sum_t w_t) I
    H[omega, j]     = (sum_t w_t M_tj) a_j
    H[j, k]         = (sum_t w_t M_tj M_tk) (a_j . a_k)          (a count times a dot product)
    g[omega]        = -sum_t w_t v*_t
    g[j]            = -a_j . (sum_t w_t M_tj v*_t)

Only the joints' world axes are needed, never the [B,n_o,3,6+n] Jacobian itself, which at a
large batch costs more to build and multiply than the rest of the step. Position targets (few:
the base, perhaps hands) add their dense J_p^T W J_p; one on the base link has J_p = (I 0 0) and
adds (sum w) I to H's first block, so the step computes no Jacobian for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .kinematics import KinematicModel, LinkSelection


@dataclass(frozen=True)
class TaskStructure:
    """Which joints move which targets, compiled once for a model and target links.

    orientation_mask: [n_o,n] M; orientation_pairs: [n,n] M^T M (targets moved by both joints);
    orientation_columns: [n] M^T 1; position: the selection of the position links off the base,
    whose Jacobians the equations need (None when every position target is on the base link);
    on_base: [n_p] bool, position targets on the base link; all_on_base: every one is.
    """

    orientation_mask: torch.Tensor
    orientation_pairs: torch.Tensor
    orientation_columns: torch.Tensor
    position: LinkSelection | None
    on_base: torch.Tensor
    all_on_base: bool
    _diagonals: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def build(cls, model: KinematicModel, orientation_links, position_links) -> "TaskStructure":
        M = model.select(tuple(orientation_links)).ancestor_mask if len(orientation_links) else \
            torch.zeros(0, model.n_dof, dtype=model.dtype, device=model.device)
        on_base = torch.tensor([name == model.base_link for name in position_links], dtype=torch.bool,
                               device=model.device)
        off_base = tuple(name for name in position_links if name != model.base_link)
        return cls(M, M.T @ M, M.sum(0), model.select(off_base) if off_base else None, on_base, bool(on_base.all()))

    def diagonal(self, N: int, damping: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        """H's diagonal with every target weighted 1: [N] = (targets on the base (x3), orientation
        targets (x3), 0 per joint) + damping; the joints' share of it is added with their pairs."""
        key = (N, damping, dtype, torch.device(device))
        if key not in self._diagonals:
            counts = torch.zeros(N, dtype=dtype, device=device)
            counts[0:3], counts[3:6] = float(self.on_base.sum()), float(self.orientation_mask.shape[0])
            self._diagonals[key] = counts + damping
        return self._diagonals[key]


def normal_equations(structure: TaskStructure, joint_axes: torch.Tensor, position_jacobian: torch.Tensor | None,
                     v_position: torch.Tensor, v_orientation: torch.Tensor, damping: float,
                     w_position: torch.Tensor | None = None, w_orientation: torch.Tensor | None = None,
                     hessian: bool = True):
    """H [B,N,N] and g [B,N] of min ||v* - J nu||^2 + damping ||nu||^2, N = 6 + n.

    joint_axes: [B,n,3] world axes; position_jacobian: [B,n_j,6,N] the Jacobians of
    `structure.position`, the position links off the base (its linear rows are used; ignored when
    every position target is on the base link);
    v_position: [B,n_p,3], v_orientation: [B,n_o,3] the corrected velocities v*;
    w_position [B,n_p], w_orientation [B,n_o]: target weights (None: all 1).
    hessian: False to skip H (returned as None) when a structured solver builds its own.
    """
    B, n = joint_axes.shape[0], joint_axes.shape[1]
    N = 6 + n
    M = structure.orientation_mask
    kw = dict(dtype=joint_axes.dtype, device=joint_axes.device)
    # g = -(sum of the base's position targets' v*, sum of the orientation v*, a_j . (M^T v*)_j),
    # and H's diagonal (the target counts on the base blocks, plus damping) as one vector each
    weighted_o = v_orientation if w_orientation is None else w_orientation[..., None] * v_orientation
    weighted_p = v_position if w_position is None else w_position[..., None] * v_position
    on_base = weighted_p if structure.all_on_base else weighted_p[:, structure.on_base]
    g = -torch.cat((on_base.sum(1), weighted_o.sum(1), (joint_axes * (M.T @ weighted_o)).sum(-1)), dim=1)
    H = None
    if hessian:
        if w_position is None and w_orientation is None:
            diagonal = structure.diagonal(N, damping, **kw)  # [N], made once
        else:
            count_p = on_base.new_full((B, 1), float(on_base.shape[1])) if w_position is None else \
                w_position[:, structure.on_base].sum(-1, keepdim=True)
            count_o = weighted_o.new_full((B, 1), float(M.shape[0])) if w_orientation is None else \
                w_orientation.sum(-1, keepdim=True)
            diagonal = torch.cat((count_p.expand(B, 3), count_o.expand(B, 3), weighted_o.new_zeros(B, n)), dim=1) + damping
        columns = structure.orientation_columns if w_orientation is None else w_orientation @ M  # [n] or [B,n]
        pairs = structure.orientation_pairs if w_orientation is None else (M.T * w_orientation[:, None, :]) @ M
        coupling = columns[..., None] * joint_axes  # [B,n,3]: H[joint j, omega] = (targets j moves) a_j
        H = torch.zeros(B, N, N, **kw)
        H.diagonal(dim1=1, dim2=2).copy_(diagonal)
        H[:, 6:, 3:6] = coupling
        H[:, 3:6, 6:] = coupling.transpose(1, 2)
        H[:, 6:, 6:] += pairs * (joint_axes @ joint_axes.transpose(1, 2))
    if structure.position is not None:  # position targets off the base: their dense J_p^T W J_p
        names = len(structure.position.names)
        if position_jacobian is None or position_jacobian.shape[1] != names:
            raise ValueError(f"position_jacobian: expected the Jacobians of the {names} position links off the base")
        off_base = ~structure.on_base
        Jp = position_jacobian[:, :, :3].flatten(1, 2)  # [B,3n_j,N]
        if w_position is not None:  # zero rows for dropped targets (weights are 0 or 1)
            Jp = Jp * w_position[:, off_base].repeat_interleave(3, dim=1)[..., None]
        if hessian:
            H = H + Jp.transpose(1, 2) @ Jp
        g = g - (Jp.transpose(1, 2) @ weighted_p[:, off_base].flatten(1).unsqueeze(-1)).squeeze(-1)
    return H, g

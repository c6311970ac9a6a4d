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
the base, perhaps hands) add their dense J_p^T W J_p.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .kinematics import KinematicModel, LinkSelection


@dataclass(frozen=True)
class TaskStructure:
    """Which joints move which targets, compiled once for a model and target links.

    orientation_mask: [n_o,n] M; orientation_pairs: [n,n] M^T M (targets moved by both joints);
    orientation_columns: [n] M^T 1; position: the position links' selection (for their Jacobians).
    """

    orientation_mask: torch.Tensor
    orientation_pairs: torch.Tensor
    orientation_columns: torch.Tensor
    position: LinkSelection

    @classmethod
    def build(cls, model: KinematicModel, orientation_links, position_links) -> "TaskStructure":
        M = model.select(tuple(orientation_links)).ancestor_mask if len(orientation_links) else \
            torch.zeros(0, model.n_dof, dtype=model.dtype, device=model.device)
        return cls(M, M.T @ M, M.sum(0), model.select(tuple(position_links)) if len(position_links) else None)


def normal_equations(structure: TaskStructure, joint_axes: torch.Tensor, position_jacobian: torch.Tensor | None,
                     v_position: torch.Tensor, v_orientation: torch.Tensor, damping: float,
                     w_position: torch.Tensor | None = None, w_orientation: torch.Tensor | None = None,
                     hessian: bool = True):
    """H [B,N,N] and g [B,N] of min ||v* - J nu||^2 + damping ||nu||^2, N = 6 + n.

    joint_axes: [B,n,3] world axes; position_jacobian: [B,n_p,6,N] (its linear rows are used);
    v_position: [B,n_p,3], v_orientation: [B,n_o,3] the corrected velocities v*;
    w_position [B,n_p], w_orientation [B,n_o]: target weights (None: all 1).
    hessian: False to skip H (returned as None) when a structured solver builds its own.
    """
    B, n = joint_axes.shape[0], joint_axes.shape[1]
    N = 6 + n
    M = structure.orientation_mask
    H = joint_axes.new_zeros(B, N, N) if hessian else None
    g = joint_axes.new_zeros(B, N)
    if M.shape[0]:
        weighted_v = v_orientation if w_orientation is None else w_orientation[..., None] * v_orientation
        if hessian:
            if w_orientation is None:
                total = torch.full((B,), float(M.shape[0]), dtype=H.dtype, device=H.device)
                columns = structure.orientation_columns.expand(B, n)
                pairs = structure.orientation_pairs
            else:
                total = w_orientation.sum(-1)
                columns = w_orientation @ M  # [B,n]
                pairs = (M.T * w_orientation[:, None, :]) @ M  # [B,n,n]
            H.diagonal(dim1=1, dim2=2)[:, 3:6] += total[:, None]
            coupling = columns[..., None] * joint_axes  # [B,n,3]
            H[:, 6:, 3:6] = coupling
            H[:, 3:6, 6:] = coupling.transpose(1, 2)
            H[:, 6:, 6:] = pairs * (joint_axes @ joint_axes.transpose(1, 2))
        g[:, 3:6] = -weighted_v.sum(1)
        g[:, 6:] = -(joint_axes * (M.T @ weighted_v)).sum(-1)
    if position_jacobian is not None and position_jacobian.shape[1]:
        Jp = position_jacobian[:, :, :3].flatten(1, 2)  # [B,3n_p,N]
        vp = v_position.flatten(1)
        if w_position is not None:
            rows = w_position.repeat_interleave(3, dim=1)
            Jp, vp = Jp * rows[..., None], vp * rows  # zero rows for dropped targets (weights are 0 or 1)
        if hessian:
            H = H + Jp.transpose(1, 2) @ Jp
        g = g - (Jp.transpose(1, 2) @ vp.unsqueeze(-1)).squeeze(-1)
    if not hessian:
        return None, g
    H.diagonal(dim1=1, dim2=2).add_(damping)
    return H, g

"""The tracking task's normal equations, assembled from the tree's structure.

The step's objective ||v* - J nu||^2 + lambda ||nu||^2 needs H = J^T W J + lambda I and
g = -J^T W v*. For the paper's targets the rows of J are known in closed form. Give every
coordinate i of nu a direction phi_i: e_1..e_3 for the base's linear velocity, e_1..e_3 for its
angular velocity, joint j's world axis a_j for its rate. A target then sees nu through the
coordinates that move it, M_ti = 1 (a position target on the base link: the three linear ones;
an orientation target: the three angular ones and the joints between it and the base), as
sum_i M_ti phi_i nu_i: the base's linear velocity, or omega_B + sum_j M_tj a_j s_dot_j. So, with
target weights w (1, or 0 for a dropped target):

    H_ik = (sum_t w_t M_ti M_tk) (phi_i . phi_k) + lambda delta_ik     (a count times a dot product)
    g_i  = -phi_i . (sum_t w_t M_ti v*_t)

Only the joints' world axes are needed, never the [B,n_o,3,6+n] Jacobian itself, which at a
large batch costs more to build and multiply than the rest of the step, and at a small batch the
whole of H is three operations. Position targets off the base (hands, say) add their dense
J_p^T W J_p from their Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import torch

from .kinematics import KinematicModel, LinkSelection
from .so3 import sum3


class Objective(NamedTuple):
    """The step's objective 1/2 nu^T H nu + g^T nu: H [B,N,N] (None when a structured solver builds
    its own) and g [B,N]."""

    H: torch.Tensor | None
    g: torch.Tensor


@dataclass(frozen=True)
class TargetStructure:
    """Which coordinates of nu move which targets, compiled once for a model and target links.

    target_mask: [n_p+n_o,N] M, position targets then orientation targets, N = 6 + n (a position
    target off the base link has a zero row: its Jacobian carries it); target_pairs: [N,N] M^T M;
    base_directions: [6,3] phi of the base's coordinates; position: the selection of the position links off the
    base, whose Jacobians the equations need (None when every position target is on the base
    link); on_base: [n_p] bool, position targets on the base link; all_on_base: every one is.
    """

    target_mask: torch.Tensor
    target_pairs: torch.Tensor
    base_directions: torch.Tensor
    position: LinkSelection | None
    on_base: torch.Tensor
    all_on_base: bool
    _damping: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def build(cls, model: KinematicModel, orientation_links, position_links) -> "TargetStructure":
        kw: dict[str, Any] = dict(dtype=model.dtype, device=model.device)
        M_o = model.select(tuple(orientation_links)).ancestor_mask if len(orientation_links) else \
            torch.zeros(0, model.n_dof, **kw)
        on_base = torch.tensor([name == model.base_link for name in position_links], dtype=torch.bool,
                               device=model.device)
        n_p, n_o, N = len(position_links), len(orientation_links), 6 + model.n_dof
        M = torch.zeros(n_p + n_o, N, **kw)
        M[:n_p, 0:3] = on_base.to(model.dtype)[:, None]
        M[n_p:, 3:6] = 1.0
        M[n_p:, 6:] = M_o
        eye = torch.eye(3, **kw)
        off_base = tuple(name for name in position_links if name != model.base_link)
        return cls(M, M.T @ M, torch.cat((eye, eye)), model.select(off_base) if off_base else None,
                   on_base, bool(on_base.all()))

    def damping_matrix(self, damping: float) -> torch.Tensor:
        """lambda I [N,N], made once per value (the step adds H's other terms to it)."""
        if damping not in self._damping:
            N = self.target_pairs.shape[0]
            self._damping[damping] = damping * torch.eye(N, dtype=self.target_pairs.dtype, device=self.target_pairs.device)
        return self._damping[damping]


def normal_equations(structure: TargetStructure, joint_axes: torch.Tensor, position_jacobian: torch.Tensor | None,
                     v_position: torch.Tensor, v_orientation: torch.Tensor, damping: float, *,
                     w_position: torch.Tensor | None = None, w_orientation: torch.Tensor | None = None,
                     hessian: bool = True) -> Objective:
    """H [B,N,N] and g [B,N] of min ||v* - J nu||^2 + damping ||nu||^2, N = 6 + n.

    joint_axes: [B,n,3] world axes; position_jacobian: [B,n_j,6,N] the Jacobians of
    `structure.position`, the position links off the base (its linear rows are used; ignored when
    every position target is on the base link);
    v_position: [B,n_p,3], v_orientation: [B,n_o,3] the corrected velocities v*;
    w_position [B,n_p], w_orientation [B,n_o]: target weights, 1 to use a target, 0 to drop it
    (None: all 1); other values are not a weighted least squares for position targets off the base.
    hessian: False to skip H (returned as None) when a structured solver builds its own.
    """
    B = joint_axes.shape[0]
    M = structure.target_mask
    phi = torch.cat((structure.base_directions.expand(B, -1, -1), joint_axes), 1)  # [B,N,3]
    v = torch.cat((v_position, v_orientation), 1)  # [B,n_t,3]
    weighted = w_position is not None or w_orientation is not None
    if weighted:
        w = torch.cat((v_position.new_ones(v_position.shape[:2]) if w_position is None else w_position,
                       v_orientation.new_ones(v_orientation.shape[:2]) if w_orientation is None else w_orientation), 1)
        v = w[..., None] * v
    # sum_t M_ti v_t as one matrix product over the batch ([N,n_t] @ [n_t,B*3]), then the dot
    # product with phi_i by slices (a reduction over a last dimension of 3 is slow on a CPU)
    B_v, n_t = v.shape[:2]
    moved = (M.T @ v.transpose(0, 1).reshape(n_t, B_v * 3)).view(-1, B_v, 3).transpose(0, 1)  # [B,N,3]
    g = -sum3(phi * moved)
    H: torch.Tensor | None = None
    if hessian:
        pairs = (M.T * w[:, None, :]) @ M if weighted else structure.target_pairs  # [B,N,N] or [N,N]
        H = torch.addcmul(structure.damping_matrix(damping), pairs, phi @ phi.transpose(1, 2))
    if structure.position is not None:  # position targets off the base: their dense J_p^T W J_p
        names = len(structure.position.names)
        if position_jacobian is None or position_jacobian.shape[1] != names:
            raise ValueError(f"position_jacobian: expected the Jacobians of the {names} position links off the base")
        off_base = ~structure.on_base
        Jp = position_jacobian[:, :, :3].flatten(1, 2)  # [B,3n_j,N]
        if w_position is not None:  # zero rows for dropped targets (weights are 0 or 1)
            Jp = Jp * w_position[:, off_base].repeat_interleave(3, dim=1)[..., None]
        if H is not None:
            H = H + Jp.transpose(1, 2) @ Jp
        weighted_p = v[:, : v_position.shape[1]]
        g = g - (Jp.transpose(1, 2) @ weighted_p[:, off_base].flatten(1).unsqueeze(-1)).squeeze(-1)
    return Objective(H, g)

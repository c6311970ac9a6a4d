"""Floating-base inverse dynamics: the generalized forces that produce a motion, batched over
configurations (float64 or float32, any device).

Conventions are the kinematics': configuration q = (p_B, R_B, s); velocity nu = (p_dot_B, omega_B,
s_dot), the base's linear and angular velocity in world axes (iDynTree's MIXED representation);
acceleration nu_dot its time derivative. The result tau [B,6+n] is dual to nu (tau . nu is the
power the forces deliver):

- tau[:6] = (f_B; n_B): the force, and the moment about the base's origin p_B, in world axes, that a
  six-DoF joint from the world to the base would have to exert. Nothing exerts it on a free body:
  it is the residual that contacts (the external wrenches) leave unexplained, zero when they
  explain the motion. Standing still without contacts, f_B = -M g (up) and n_B = (c - p_B) x f_B.
- tau[6:]: each joint's torque, exerted by the joint's parent on its child about its axis.

External wrenches w_l = (f_l; n_l) act on links l: force and moment about the link's origin, both
in world axes (what a force plate or a contact at a foot gives, moved to the foot's origin). They
enter as tau = M(q) nu_dot + h(q, nu) - sum_l J_l^T w_l, J_l the link's MIXED Jacobian.

The method (Featherstone's spatial notation, every spatial vector in world axes about the base's
origin O = p_B, linear part first as in the Jacobians). Joint j, of world axis a_j through the origin
o_j of its frame, has the motion subspace S_j = (r_j x a_j; a_j), r_j = o_j - p_B. Every frame's
velocity and acceleration are sums over the joints above it, D[f,j] = 1 when joint j moves frame f
(the tree's ancestor matrix):

    V_f = V_B + sum_j D[f,j] S_j s_dot_j,                          V_B = (p_dot_B; omega_B)
    A_f = A_B + sum_j D[f,j] (S_j s_ddot_j + V_f(j) x S_j s_dot_j),  A_B = (p_ddot_B - omega_B x p_dot_B; omega_dot_B)

with f(j) the frame joint j moves and (v; w) x (u; a) = (w x u + v x a; w x a). A spatial
acceleration (alpha_O; w_dot) is the derivative of the velocity field at the fixed point O, not the
classical acceleration of the body's point at O: hence A_B's -omega_B x p_dot_B.
Each frame carries one rigid body, its links lumped (`tensors.frame_bodies`): mass m, first moment
h = m (c - o) and inertia I about the frame's origin o, turned to world axes. With r = o - p_B,
(v_O; w) = V_f, (alpha_O; w_dot) = A_f, the origin's velocity v_o = v_O + w x r and classical
acceleration a_o = alpha_O + w_dot x r + w x v_o, the wrench the body needs, F_f = (f; n_O), is
Newton-Euler's about its origin, moved to O:

    f = m (a_o - g) + w_dot x h + w x (w x h),   n_o = I w_dot + w x I w + h x (a_o - g),   n_O = n_o + r x f

less the external wrenches on its links (moments moved to O). The joints carry the wrenches of the
bodies below them, tau_j = S_j . sum_f D[f,j] F_f, and the base all of them, tau_B = sum_f F_f.
The three sums over the tree (velocities, accelerations, forces) are products with D [F,n], dense:
a human's 67 frames make it a small matrix, and there is no loop over links or tree levels.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import torch

from ...errors import InputError
from ..kinematics.compose import SMALL_BATCH, frame_poses, link_poses, matmul_soa, matvec_soa, world_axes
from ..kinematics.model import KinematicModel
from ..kinematics.tensors import TreeTensors

GRAVITY = (0.0, 0.0, -9.81)  # m/s^2, world frame


class InverseDynamics(NamedTuple):
    """forces [B,6+n] dual to nu: base_wrench [B,6] (force; moment about the base's origin, world
    axes: the residual no contact explains) then joint_torques [B,n] (views of forces);
    joint_powers [B,n] = joint_torques * s_dot (W), what each joint delivers to its child."""

    forces: torch.Tensor
    base_wrench: torch.Tensor
    joint_torques: torch.Tensor
    joint_powers: torch.Tensor


def inverse_dynamics(model: KinematicModel, base_position: torch.Tensor, base_rotation: torch.Tensor,
                     joint_positions: torch.Tensor, velocity: torch.Tensor, acceleration: torch.Tensor,
                     external_wrenches: torch.Tensor | None = None, wrench_links: Sequence[str] | None = None,
                     gravity: Sequence[float] | torch.Tensor = GRAVITY) -> InverseDynamics:
    """The generalized forces that produce the motion (q, nu, nu_dot) under gravity and the external
    wrenches (recursive Newton-Euler, as sums over the tree; the module's docstring has the equations).

    base_position [B,3]; base_rotation [B,3,3] base-to-world; joint_positions [B,n] (order
    `model.joint_names`); velocity, acceleration [B,6+n] (MIXED: base linear and angular velocity in
    world axes); external_wrenches [B,L,6] (force; moment about the link's origin, world axes) on
    wrench_links (L names; default every link, `model.link_names`); gravity [3] (world, m/s^2).
    All in the model's dtype on its device. Returns InverseDynamics: forces [B,6+n] and its parts.
    """
    B = base_position.shape[0] if isinstance(base_position, torch.Tensor) and base_position.dim() else -1
    n = model.n_dof
    for name, x, shape in (("base_position", base_position, (B, 3)), ("base_rotation", base_rotation, (B, 3, 3)),
                           ("joint_positions", joint_positions, (B, n)), ("velocity", velocity, (B, 6 + n)),
                           ("acceleration", acceleration, (B, 6 + n))):
        model.check_input(name, x, shape)
    if model.n_subjects not in (1, B):
        raise InputError(f"this model holds {model.n_subjects} subjects; the batch has {B} rows")
    t = model._tensors
    R, p = frame_poses(t, base_position, base_rotation, joint_positions)  # [F,3,3,B], [F,3,B]
    assert p is not None  # positions were asked for
    r = p - base_position.T  # [F,3,B] frame origins from the base's
    nu, nu_dot = velocity.T, acceleration.T  # [6+n,B]
    axis = world_axes(t, R)  # [n,3,B]
    S = torch.cat((cross(r.index_select(0, t.joint_frame), axis), axis), 1)  # [n,6,B]
    s_dot, s_ddot = nu[6:, None], nu_dot[6:, None]  # [n,1,B]
    V = nu[:6] + _sum_above(t, S * s_dot)  # [F,6,B]
    A_B = torch.cat((nu_dot[:3] - cross(nu[3:6], nu[:3]), nu_dot[3:6]))
    A = A_B + _sum_above(t, S * s_ddot + motion_cross(V.index_select(0, t.joint_frame), S) * s_dot)
    g = torch.as_tensor(gravity, dtype=model.dtype, device=model.device).reshape(3, 1)
    wrench = body_wrenches(t, R, r, V, A, g)  # [F,6,B]
    if external_wrenches is not None:
        wrench = wrench - _external(model, R, p, base_position.T, external_wrenches, wrench_links)
    # each joint carries the bodies below it; the base, all of them
    below = (t.ancestor.T @ wrench.reshape(t.n_frames, 6 * B)).reshape(n, 6, B)
    forces = torch.cat((wrench.sum(0), (S * below).sum(1))).T.contiguous()  # [B,6+n]
    torques = forces[:, 6:]
    return InverseDynamics(forces, forces[:, :6], torques, torques * velocity[:, 6:])


def body_wrenches(t: TreeTensors, R, r, V, A, g) -> torch.Tensor:
    """[F,6,B] the wrench (force; moment about the base's origin) each frame's body needs for its
    spatial velocity V and acceleration A [F,6,B] under gravity g [3,1]. R [F,3,3,B] frame
    rotations, r [F,3,B] frame origins from the base's."""
    w, w_dot = V[:, 3:], A[:, 3:]
    v_o = V[:, :3] + cross(w, r)  # each frame origin's velocity
    a_o = A[:, :3] + cross(w_dot, r) + cross(w, v_o) - g  # ... its acceleration, less gravity
    m = t.body_mass[:, None]  # [F,1,S]
    h = matvec_soa(R, t.body_first_moment)  # [F,3,B] m (c - o), world axes
    I = matmul_soa(matmul_soa(R, t.body_inertia.expand_as(R)), R.transpose(1, 2))  # about o, world axes
    f = m * a_o + cross(w_dot, h) + cross(w, cross(w, h))
    n_o = matvec_soa(I, w_dot) + cross(w, matvec_soa(I, w)) + cross(h, a_o)
    return torch.cat((f, n_o + cross(r, f)), 1)


def _external(model: KinematicModel, R, p, p_B, wrenches: torch.Tensor, links: Sequence[str] | None) -> torch.Tensor:
    """[F,6,B] the external wrenches [B,L,6] on `links` (force; moment about each link's origin,
    world axes) summed on the frames the links are fixed to, moments about the base's origin p_B
    [3,B]. R [F,3,3,B], p [F,3,B] the frame poses."""
    links = model.link_names if links is None else tuple(links)
    selection = model.select(links)
    model.check_input("external_wrenches", wrenches, (p.shape[-1], len(links), 6))
    w = wrenches.permute(1, 2, 0)  # [L,6,B]
    lever = link_poses(R, p, selection, None) - p_B  # [L,3,B] link origins from the base's
    moved = torch.cat((w[:, :3], w[:, 3:] + cross(lever, w[:, :3])), 1)
    return p.new_zeros(p.shape[0], 6, p.shape[-1]).index_add_(0, selection.anchor, moved)


def _sum_above(t: TreeTensors, X: torch.Tensor) -> torch.Tensor:
    """[F,6,B] each frame's sum of X [n,6,B] over the joints that move it (the ancestor matrix)."""
    n, _, B = X.shape
    return (t.ancestor @ X.reshape(n, 6 * B)).reshape(t.n_frames, 6, B)


def cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross products along dimension -2, batch last: a, b [...,3,B] (broadcast) -> [...,3,B]."""
    if a.shape[-1] <= SMALL_BATCH:
        return torch.linalg.cross(a, b, dim=-2)
    # torch's cross along a middle dimension is slow for large batches: the three components
    out = torch.empty(torch.broadcast_shapes(a.shape, b.shape), dtype=a.dtype, device=a.device)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        torch.mul(a[..., j, :], b[..., k, :], out=out[..., i, :]).addcmul_(a[..., k, :], b[..., j, :], value=-1.0)
    return out


def motion_cross(V: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
    """Spatial motion cross product, linear part first: (v; w) x (u; a) = (w x u + v x a; w x a).
    V, M [...,6,B] -> [...,6,B]."""
    v, w, u, a = V[..., :3, :], V[..., 3:, :], M[..., :3, :], M[..., 3:, :]
    return torch.cat((cross(w, u) + cross(v, a), cross(w, a)), -2)

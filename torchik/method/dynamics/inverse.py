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

The three sums over the tree (velocities, accelerations, forces) are computed one of two ways, the
same sums (`down_the_tree`, `up_the_tree`). For many configurations on a CPU, one step per tree level
(Human48's 17, every frame of a level at once): V_f = V_parent(f) + S_f s_dot_f from the base down,
and the wrenches added into the parents' from the leaves up, which is the least arithmetic. For a
few, or on a GPU, where each operation's overhead outweighs its arithmetic, as three products with
D [F,n], dense (a human's 67 frames make it a small matrix). Neither loops over links.
The bodies' wrenches are computed for all frames at once, their inertia kept in the frame's axes,
where it is constant: w and w_dot are turned to those axes and I's products back, which is cheaper
than turning I (`body_wrenches`).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import torch

from ...errors import InputError
from ..capture import tracing
from ..kinematics.compose import SMALL_BATCH, frame_poses, link_poses
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
    # frames 1..F-1 are the joints' child frames: the joints' rows in frame order
    joint = t.frame_joint[1:]
    s_dot, s_ddot = nu[6:].index_select(0, joint)[:, None], nu_dot[6:].index_select(0, joint)[:, None]  # [n,1,B]
    a = rotate(R[1:], t.joint_axes.index_select(0, joint))  # [n,3,B] each joint's world axis
    r_x_a = cross(r[1:], a)
    u = a * s_dot
    X = torch.cat((r_x_a * s_dot, u), 1)  # S s_dot = (r x u; u), S = (r x a; a)
    V = down_the_tree(t, X, nu[:6])  # [F,6,B]
    # S s_ddot + V_f x S s_dot = (r x a s_ddot + w x (r x u) + v x u; a s_ddot + w x u), (v; w) = V_f
    v, w = V[1:, :3], V[1:, 3:]
    C = torch.cat((r_x_a * s_ddot + cross(w, X[:, :3]) + cross(v, u), a * s_ddot + cross(w, u)), 1)
    A_B = torch.cat((nu_dot[:3] + cross(nu[:3], nu[3:6]), nu_dot[3:6]))  # alpha_B = p_ddot_B - omega_B x p_dot_B
    A = down_the_tree(t, C, A_B)  # [F,6,B]
    g = torch.as_tensor(gravity, dtype=model.dtype, device=model.device).reshape(3, 1)
    wrench = body_wrenches(t, R, r, V, A, g)  # [F,6,B]
    if external_wrenches is not None:
        wrench = wrench - _external(model, R, p, base_position.T, external_wrenches, wrench_links)
    below = up_the_tree(t, wrench)  # [F,6,B] each frame's subtree: the base carries them all
    torques = ((r_x_a * below[1:, :3]).sum(1) + (a * below[1:, 3:]).sum(1)).index_select(0, t.joint_frame - 1)
    forces = torch.cat((below[0], torques)).T.contiguous()  # [B,6+n], torques in the model's joint order
    torques = forces[:, 6:]
    return InverseDynamics(forces, forces[:, :6], torques, torques * velocity[:, 6:])


def body_wrenches(t: TreeTensors, R, r, V, A, g) -> torch.Tensor:
    """[F,6,B] the wrench (force; moment about the base's origin, world axes) each frame's body needs
    for its spatial velocity V and acceleration A [F,6,B] under gravity g [3,1]. R [F,3,3,B] frame
    rotations, r [F,3,B] frame origins from the base's. The inertia stays in the frame's axes, where
    it is constant: I w = R (I_f (R^T w))."""
    w, w_dot = V[:, 3:], A[:, 3:]
    v_o = V[:, :3] + cross(w, r)  # each frame origin's velocity
    a_o = A[:, :3] + cross(w_dot, r) + cross(w, v_o) - g  # ... its acceleration, less gravity
    h = rotate(R, t.body_first_moment)  # [F,3,B] m (c - o), world axes
    f = t.body_mass[:, None] * a_o + cross(w_dot, h) + cross(w, cross(w, h))
    Rt = R.transpose(1, 2)
    w_f = rotate(Rt, w)  # in the frame's axes
    spin = rotate(t.body_inertia, rotate(Rt, w_dot)) + cross(w_f, rotate(t.body_inertia, w_f))  # I w_dot + w x I w
    n_o = rotate(R, spin) + cross(h, a_o)
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
    return p.new_zeros(p.shape[0], 6, p.shape[-1]).index_put_((selection.anchor,), moved, accumulate=True)


def down_the_tree(t: TreeTensors, X: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
    """[F,6,B] each frame's `base` [6,B] plus the sum of X [F-1,6,B] (frames 1..F-1, each its joint's
    term) over the joints that move the frame: level by level from the base, or with the ancestor
    matrix (the module's docstring says when)."""
    B = X.shape[-1]
    if not _by_levels(X):
        # the ancestor matrix's columns are the joints' in the model's order: X's rows taken to it
        X = X.index_select(0, t.joint_frame - 1)
        return base + (t.ancestor @ X.reshape(t.n_dof, 6 * B)).reshape(t.n_frames, 6, B)
    if tracing():  # a tensor per level, concatenated (`capture.tracing`)
        levels = [base[None]]
        for start, stop, parents in t.levels:
            levels.append(levels[-1].index_select(0, parents) + X[start - 1:stop - 1])
        return torch.cat(levels)
    out = X.new_empty(t.n_frames, 6, B)
    out[0] = base
    above = 0  # the first frame of the level above
    for start, stop, parents in t.levels:
        torch.add(out[above:start].index_select(0, parents), X[start - 1:stop - 1], out=out[start:stop])
        above = start
    return out


def up_the_tree(t: TreeTensors, X: torch.Tensor) -> torch.Tensor:
    """[F,6,B] each frame's sum of X [F,6,B] over itself and the frames below it (its subtree): level
    by level from the leaves, or with the ancestor matrix (the base's row the sum of all)."""
    B = X.shape[-1]
    if not _by_levels(X):
        joints = (t.ancestor.T @ X.reshape(t.n_frames, 6 * B)).reshape(t.n_dof, 6, B)  # the model's joint order
        return torch.cat((X.sum(0, keepdim=True), joints.index_select(0, t.frame_joint[1:])))
    aboves = [0] + [start for start, _, _ in t.levels[:-1]]  # each level's level above
    if tracing():  # a tensor per level, concatenated (`capture.tracing`)
        levels = [X[t.levels[-1][0]:]]
        for above, (start, _, parents) in zip(reversed(aboves), reversed(t.levels)):
            levels.append(X[above:start].index_put((parents,), levels[-1], accumulate=True))
        return torch.cat(levels[::-1])
    out = X.clone()
    for above, (start, stop, parents) in zip(reversed(aboves), reversed(t.levels)):
        # index_put_ rather than index_add_: on two threads torch's index_add_ took 50 ms here, not 0.02
        out[above:start].index_put_((parents,), out[start:stop], accumulate=True)
    return out


def _by_levels(X: torch.Tensor) -> bool:
    """Whether the sums over the tree go level by level (many configurations on a CPU) rather than
    through the ancestor matrix."""
    return X.device.type == "cpu" and X.shape[-1] > SMALL_BATCH


def rotate(M: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Matrix-vector products, batch last: M [...,3,3,B], v [...,3,B] (broadcast) -> [...,3,B], as
    three products and sums of [...,3,B] columns."""
    if max(v.shape[-1], M.shape[-1]) <= SMALL_BATCH:
        return torch.matmul(M.movedim(-1, -3), v.movedim(-1, -2).unsqueeze(-1)).squeeze(-1).movedim(-2, -1)
    out = M[..., :, 0, :] * v[..., 0:1, :]  # the broadcast shape: the sums add in place
    return out.addcmul_(M[..., :, 1, :], v[..., 1:2, :]).addcmul_(M[..., :, 2, :], v[..., 2:3, :])


def cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross products along dimension -2, batch last: a, b [...,3,B] (broadcast) -> [...,3,B]."""
    if max(a.shape[-1], b.shape[-1]) <= SMALL_BATCH:
        return torch.linalg.cross(a, b, dim=-2)
    # torch's cross along a middle dimension is slow for large batches: the three components
    shape = [max(x, y) for x, y in zip(a.shape, b.shape)] if a.dim() == b.dim() else torch.broadcast_shapes(a.shape, b.shape)
    out = torch.empty(shape, dtype=a.dtype, device=a.device)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        torch.mul(a[..., j, :], b[..., k, :], out=out[..., i, :]).addcmul_(a[..., k, :], b[..., j, :], value=-1.0)
    return out

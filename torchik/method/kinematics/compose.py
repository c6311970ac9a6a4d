"""The composition kernels: batch-last 3x3 products, the world poses of every skeleton frame (level
by level for large batches, by pointer jumping for small ones), the small-batch rotation-only
composition, link poses from their anchors, and the Jacobian fill. Tensor work only: no Python
loop over links, joints or subjects (the loops run over tree levels or jumping rounds).
"""

from __future__ import annotations

import torch

from .. import so3
from ..capture import tracing
from .selection import LinkKinematics, LinkSelection
from .tensors import TreeTensors

# Below this batch size, per-operation overhead dominates: use one matmul per product and
# compose frames by pointer jumping (fewer, larger operations). Above it, the work dominates:
# vectorise along the batch and compose level by level (least work).
SMALL_BATCH = 32


def matmul_soa(A: torch.Tensor, B: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """3x3 products in batch-last layout: A [...,3,3,b], B [...,3,3,b] -> [...,3,3,b]."""
    if A.shape[-1] <= SMALL_BATCH:
        C = torch.matmul(A.movedim(-1, -3), B.movedim(-1, -3)).movedim(-3, -1)
        return C if out is None else out.copy_(C)
    out = torch.mul(A[..., :, 0:1, :], B[..., 0:1, :, :], out=out)
    out.addcmul_(A[..., :, 1:2, :], B[..., 1:2, :, :])
    out.addcmul_(A[..., :, 2:3, :], B[..., 2:3, :, :])
    return out


def matvec_soa(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Matrix-vector products in batch-last layout: A [...,3,3,b], v [...,3,b] -> [...,3,b]."""
    if A.shape[-1] <= SMALL_BATCH:
        return torch.matmul(A.movedim(-1, -3), v.movedim(-1, -2).unsqueeze(-1)).squeeze(-1).movedim(-2, -1)
    return (A * v.unsqueeze(-3)).sum(-2)


def frame_poses(t: TreeTensors, p_B, R_B, s) -> tuple[torch.Tensor, torch.Tensor | None]:
    """World rotation [F,3,3,B] and position [F,3,B] of every skeleton frame (batch last);
    rotations only (position None) when p_B is None.

    p_B: [B,3] or None; R_B: [B,3,3] base-to-world; s: [B,n]."""
    g = t.geometry
    B = s.shape[0]
    rotations_only = p_B is None
    if t.n_dof:
        angle = s.T.index_select(0, t.frame_joint) * t.frame_is_joint  # [F,B]; the base has no joint
    else:  # a single rigid body
        angle = s.new_zeros(t.n_frames, B)
    if tracing() and B > SMALL_BATCH:
        # one tensor, which TorchInductor computes in a loop of its own, vectorised along the
        # batch; left to fuse into the rotations' loop, it took each sine and cosine one subject at
        # a time across the 9 entries, in twice the time (experiments/speed_history.md); at one
        # subject there is no batch to vectorise along, and the fused loop was faster
        both = torch.cat((torch.sin(angle), 1.0 - torch.cos(angle)))
        sin, one_minus_cos = both[:len(angle), None, None, :], both[len(angle):, None, None, :]
    else:
        sin = torch.sin(angle)[:, None, None, :]
        one_minus_cos = (1.0 - torch.cos(angle))[:, None, None, :]
    # R_parent->frame = R_off exp(hat(axis) angle) = R_off + sin R_off K + (1 - cos) R_off K^2
    R_local = torch.addcmul(g.offset_rotation, sin, g.rotation_sin_term).addcmul_(one_minus_cos, g.rotation_cos_term)
    p_local = g.offset_position.expand(-1, -1, B)
    R_base = R_B.permute(1, 2, 0)  # [3,3,B]
    if B <= SMALL_BATCH and t.jumps and not rotations_only:
        return compose_by_jumping(t, R_local, p_local, R_base, p_B.T)
    # the base frame's offset is the identity and it has no joint, so its pose is the base pose.
    # Each level written into one [F,...] tensor; while the step is traced for capture, a tensor
    # per level, concatenated at the end (`capture.tracing`)
    R_level, p_level = R_base[None], None if rotations_only else p_B.T[None]
    traced = tracing()
    R = None if traced else torch.empty_like(R_local)
    p = None if traced or rotations_only else torch.empty_like(p_local)
    R_levels, p_levels = [R_level], [p_level]  # while traced: each level's, concatenated at the end
    for start, stop, parents in t.levels:  # one step per tree level, not per link
        R_parent = R_level.index_select(0, parents)
        if p_level is not None:
            p_level = torch.add(p_level.index_select(0, parents), matvec_soa(R_parent, p_local[start:stop]),
                                out=None if p is None else p[start:stop])
        R_level = matmul_soa(R_parent, R_local[start:stop], out=None if R is None else R[start:stop])
        if traced:
            R_levels.append(R_level)
            p_levels.append(p_level)
    if R is None:
        return torch.cat(R_levels), None if rotations_only else torch.cat([x for x in p_levels if x is not None])
    R[0] = R_base  # the base frame's row, which the levels do not write
    if p is not None:
        p[0] = p_B.T
    return R, p


def compose_by_jumping(t: TreeTensors, R_local, p_local, R_base, p_base):
    """Pointer jumping for small batches: log2(depth) rounds, each one gather and one product of
    homogeneous transforms [B,F+1,4,4] over all frames (frame F is the world, its own parent).

    R_local [F,3,3,B], p_local [F,3,B] each frame in its parent; R_base [3,3,B], p_base [3,B].
    Returns the same batch-last views as the level-by-level composition."""
    F, B = R_local.shape[0], R_local.shape[-1]
    T = t.homogeneous_template.expand(B, -1, -1, -1).clone()
    T[:, :F, :3, :3] = R_local.permute(3, 0, 1, 2)
    T[:, :F, :3, 3] = p_local.permute(2, 0, 1)
    T[:, 0, :3, :3] = R_base.permute(2, 0, 1)  # the base frame's offset is the identity
    T[:, 0, :3, 3] = p_base.T
    for up in t.jumps:
        T = torch.matmul(T.index_select(1, up), T)
    # contiguous batch-last copies: the gathers that follow are several times faster on them
    return (T[:, :F, :3, :3].permute(1, 2, 3, 0).contiguous(), T[:, :F, :3, 3].permute(1, 2, 0).contiguous())


def frame_rotations_small(t: TreeTensors, R_B: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """World rotations of every skeleton frame, then the world's identity: [B,F+1,3,3].

    R_B: [B,3,3]; s: [B,n]. Pointer jumping on batch-first 3x3 rotations: a few large operations,
    which is what costs least when the batch is small and each operation's overhead dominates."""
    angle = s.index_select(1, t.small_angle_index)[:, :, None, None]  # [B,F-1,1,1]
    R_local = torch.addcmul(torch.addcmul(t.small_offset, torch.sin(angle), t.small_sin),
                            torch.cos(angle), t.small_cos, value=-1.0)
    # the base frame's offset is the identity; the world is its own parent in the jumps
    R = torch.cat((R_B.unsqueeze(1), R_local, t.world.expand(R_B.shape[0], 1, 3, 3)), 1)
    for up in t.jumps:
        R = torch.matmul(R.index_select(1, up), R)
    return R


def world_axes(t: TreeTensors, R: torch.Tensor) -> torch.Tensor:
    """Every joint's world axis from the frame rotations R [F,3,3,B] (batch last): [n,3,B]."""
    return matvec_soa(R.index_select(0, t.joint_frame), t.joint_axes)


def link_poses(R, p, sel: LinkSelection, out: LinkKinematics | None) -> torch.Tensor:
    """Link poses from the skeleton frames R [F,3,3,B], p [F,3,B]; written into `out` when given.
    Returns p [L,3,B]."""
    R_link, p_link = R.index_select(0, sel.anchor), p.index_select(0, sel.anchor)
    if not sel.offsets_are_identity:
        p_link = p_link + matvec_soa(R_link, sel.offset_position)
        R_link = matmul_soa(R_link, sel.offset_rotation.expand_as(R_link))
    if out is not None:
        out.rotation.copy_(R_link.permute(3, 0, 1, 2))
        assert out.position is not None  # forward's buffers hold positions
        out.position.copy_(p_link.permute(2, 0, 1))
    return p_link


def fill_jacobian(t: TreeTensors, p_B, axis, p, p_link, sel: LinkSelection, J: torch.Tensor) -> None:
    """Fill J [B,L,6,6+n]: base columns (I, -hat(p_L - p_B); 0, I), joint columns (a x (p_L - o); a).
    p_B: [B,3]; axis: [n,3,B] world joint axes; p: [F,3,B] frame positions; p_link: [L,3,B].
    The base's identity blocks and the structural zeros are already there (`empty_output`)."""
    B = J.shape[0]
    origin = p.index_select(0, t.joint_frame) - p_B.T  # [n,3,B] joint origins relative to the base
    d = p_link - p_B.T  # [L,3,B]
    J[:, :, 0:3, 3:6] = so3.hat(-d.permute(2, 0, 1))
    # the columns of every (link, ancestor joint) pair: (a x r; a), r = p_L - o, batch last
    columns = torch.empty(sel.pair_joint.shape[0], 6, B, dtype=J.dtype, device=J.device)
    torch.index_select(axis, 0, sel.pair_joint, out=columns[:, 3:6])
    r = d.index_select(0, sel.pair_link) - origin.index_select(0, sel.pair_joint)
    a = columns[:, 3:6]
    if B <= SMALL_BATCH:
        torch.linalg.cross(a, r, dim=1, out=columns[:, 0:3])
    else:  # torch's cross along a middle dimension is slow for large batches
        for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # the three components of a x r
            torch.mul(a[:, j], r[:, k], out=columns[:, i]).addcmul_(a[:, k], r[:, j], value=-1.0)
    if B <= SMALL_BATCH:
        J.view(B, -1).index_copy_(1, sel.pair_flat_index, columns.view(-1, B).T)
    else:  # large batches: write through the transposed view, without transposing the columns
        J.view(B, -1).T.index_copy_(0, sel.pair_flat_index, columns.view(-1, B))

"""The tensors a `KinematicModel` computes with, derived from its `KinematicTree`: the subjects'
dimensions (`Geometry`, batch-last) and the index and constant tensors of the composition
(`TreeTensors`), in one dtype on one device. `tensors(tree, geometry, dtype, device)` makes them;
a model derives them again to change dtype or device, or to stack subjects.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch

from .urdf import KinematicTree


@dataclass(frozen=True)
class Geometry:
    """Per-subject constants of the tree, batch-last: trailing dimension S (1, or one per batch row).

    Batch-last ("structure of arrays") so that each tree level is a contiguous slab and each
    3x3 product is vectorised along the batch, which is what makes large batches fast on CPU.
    """

    offset_rotation: torch.Tensor  # [F,3,3,S] joint frame (at zero angle) in the parent frame
    offset_position: torch.Tensor  # [F,3,S]
    rotation_sin_term: torch.Tensor  # [F,3,3,S] offset_rotation @ hat(axis)
    rotation_cos_term: torch.Tensor  # [F,3,3,S] offset_rotation @ hat(axis)^2
    link_rotation: torch.Tensor  # [N,3,3,S] every URDF link in its anchor frame
    link_position: torch.Tensor  # [N,3,S]
    link_mass: torch.Tensor  # [N,S] kg (0: no <inertial>)
    link_com: torch.Tensor  # [N,3,S] each link's centre of mass in its frame (m)
    link_inertia: torch.Tensor  # [N,3,3,S] each link's inertia about its centre of mass, link axes (kg m^2)

    def to(self, dtype=None, device=None) -> "Geometry":
        return Geometry(*(t.to(dtype=dtype, device=device) for t in vars(self).values()))

    @staticmethod
    def cat(geometries: Sequence["Geometry"]) -> "Geometry":
        """Subjects side by side: S is the sum of theirs (same dtype and device)."""
        return Geometry(*(torch.cat([vars(g)[k] for g in geometries], dim=-1) for k in vars(geometries[0])))


def tree_geometry(tree: KinematicTree) -> Geometry:
    """The tree's own dimensions (one subject, S = 1), float64 on CPU."""
    R_off = tree.frame_rotation
    K = np.stack([_hat(a) for a in tree.axes])
    return Geometry(
        offset_rotation=_soa(R_off),
        offset_position=_soa(tree.frame_position),
        rotation_sin_term=_soa(R_off @ K),
        rotation_cos_term=_soa(R_off @ K @ K),
        link_rotation=_soa(tree.link_rotation),
        link_position=_soa(tree.link_position),
        link_mass=_soa(tree.link_mass),
        link_com=_soa(tree.link_com),
        link_inertia=_soa(tree.link_inertia),
    )


def _soa(a: np.ndarray) -> torch.Tensor:
    """[F,...] -> [F,...,1], batch last (a writable copy: the tree's arrays are read-only)."""
    return torch.from_numpy(np.array(a, order="C"))[..., None]


def _hat(a: np.ndarray) -> np.ndarray:
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


@dataclass(frozen=True)
class TreeTensors:
    """Everything a call reads, in one dtype on one device. F frames, n joints, N links.

    levels: (start, stop, parents [level size] as rows of the level above) per depth; jumps: [F+1] per pointer-jumping round;
    homogeneous_template [F+1,4,4] (bottom rows, and the world's identity); frame_joint [F] (0 for
    the base) and frame_is_joint [F,1] (0 for the base); joint_frame [n]; joint_axes [n,3,1] and
    joint_axes_row [n,1,3] each joint's axis in its frame; link_anchor [N]; ancestor [F,n].
    The small-batch rotation-only composition's constants, batch-first [S,F-1,3,3] over frames
    1..F-1 (frame 0, the base, is the base rotation itself, and the world, frame F, the identity
    `world` [1,1,3,3]): small_sin = R_off hat(axis), small_cos = R_off hat(axis)^2 and small_offset
    = R_off + small_cos, so that R_local = small_offset + sin small_sin - cos small_cos;
    small_angle_index [F-1] the joint of each.
    Each frame's body, the links fixed to it lumped (`frame_bodies`), batch last: body_mass [F,S],
    body_first_moment [F,3,S] (mass times centre of mass, in the frame), body_inertia [F,3,3,S]
    (about the frame's origin, in its axes).
    """

    dtype: torch.dtype
    device: torch.device
    n_frames: int
    n_dof: int
    geometry: Geometry
    levels: list[tuple[int, int, torch.Tensor]]
    jumps: list[torch.Tensor]
    homogeneous_template: torch.Tensor
    frame_joint: torch.Tensor
    frame_is_joint: torch.Tensor
    joint_frame: torch.Tensor
    joint_axes: torch.Tensor
    joint_axes_row: torch.Tensor
    link_anchor: torch.Tensor
    ancestor: torch.Tensor
    small_offset: torch.Tensor
    small_sin: torch.Tensor
    small_cos: torch.Tensor
    small_angle_index: torch.Tensor
    world: torch.Tensor
    body_mass: torch.Tensor
    body_first_moment: torch.Tensor
    body_inertia: torch.Tensor


def tensors(tree: KinematicTree, geometry: Geometry, dtype, device) -> TreeTensors:
    """Derive the tensors of `tree` with dimensions `geometry`, in `dtype` on `device`."""
    device = torch.empty(0, device=device).device  # 'cuda' made explicit ('cuda:0'), as inputs' devices are
    g = geometry.to(dtype=dtype, device=device)
    long: dict[str, Any] = dict(dtype=torch.long, device=device)
    template = torch.zeros(tree.n_frames + 1, 4, 4, dtype=dtype, device=device)
    template[:, 3, 3] = 1.0
    template[-1] = torch.eye(4, dtype=dtype, device=device)
    frame_joint = torch.tensor([max(j, 0) for j in tree.frame_joint], **long)
    joint_frame = torch.tensor(tree.joint_frame, **long)
    axes = torch.from_numpy(np.array(tree.axes)).to(dtype=dtype, device=device)
    joint_axes = axes[joint_frame][:, :, None]  # [n,3,1] in each joint frame
    body_mass, body_first_moment, body_inertia = frame_bodies(g, torch.tensor(tree.link_anchor, **long), tree.n_frames)
    first = lambda t: t.permute(3, 0, 1, 2)[:, 1:].contiguous()  # noqa: E731  [F,3,3,S] -> [S,F-1,3,3]
    return TreeTensors(
        dtype=dtype,
        device=device,
        n_frames=tree.n_frames,
        n_dof=tree.n_dof,
        geometry=g,
        # each level's parents as rows of the level above (its first frame at that level's start)
        levels=[(a, b, torch.tensor(p, **long) - above) for (a, b, p), above in
                zip(tree.levels, [0] + [a for a, _, _ in tree.levels[:-1]])],
        jumps=[torch.tensor(j, **long) for j in tree.jumps],
        homogeneous_template=template,
        frame_joint=frame_joint,
        frame_is_joint=torch.tensor([[float(j >= 0)] for j in tree.frame_joint], dtype=dtype, device=device),
        joint_frame=joint_frame,
        joint_axes=joint_axes,
        joint_axes_row=joint_axes.transpose(1, 2),  # [n,1,3]
        link_anchor=torch.tensor(tree.link_anchor, **long),
        ancestor=torch.from_numpy(np.array(tree.ancestor)).to(dtype=dtype, device=device),
        small_offset=first(g.offset_rotation + g.rotation_cos_term),
        small_sin=first(g.rotation_sin_term),
        small_cos=first(g.rotation_cos_term),
        small_angle_index=frame_joint[1:],
        world=torch.eye(3, dtype=dtype, device=device)[None, None],  # [1,1,3,3]
        body_mass=body_mass,
        body_first_moment=body_first_moment,
        body_inertia=body_inertia,
    )


def frame_bodies(g: Geometry, link_anchor: torch.Tensor, n_frames: int):
    """The links fixed to each skeleton frame lumped into one rigid body: its mass [F,S], first
    moment [F,3,S] and rotational inertia about the frame's origin [F,3,3,S], in the frame's axes.

    Link l (mass m, centre of mass c_l and inertia I_l in its own frame, the frame's offset R_l,
    p_l) adds m, m c and R_l I_l R_l^T + m (|c|^2 E - c c^T), c = p_l + R_l c_l the centre in the
    frame (the parallel-axis theorem). A frame without mass has a zero body."""
    m = g.link_mass  # [N,S]
    c = g.link_position + torch.einsum("nijs,njs->nis", g.link_rotation, g.link_com)  # [N,3,S]
    rotated = torch.einsum("nijs,njks,nlks->nils", g.link_rotation, g.link_inertia, g.link_rotation)
    eye = torch.eye(3, dtype=m.dtype, device=m.device)[None, :, :, None]
    shifted = rotated + m[:, None, None] * ((c * c).sum(1)[:, None, None] * eye - c[:, :, None] * c[:, None, :])
    lump = lambda x: x.new_zeros((n_frames, *x.shape[1:])).index_add_(0, link_anchor, x)  # noqa: E731
    return lump(m), lump(m[:, None] * c), lump(shifted)

"""A list of links compiled for repeated calls (`LinkSelection`), and what a call returns for it
(`LinkKinematics`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from .tensors import TreeTensors


@dataclass(frozen=True)
class LinkKinematics:
    """Poses and Jacobians of a selection of links for a batch of configurations.

    rotation: [B,L,3,3] link-to-world; position: [B,L,3] world, or None (`rotations`);
    jacobian: [B,L_j,6,6+n] mixed representation, rows (linear; angular), or None if not asked;
    joint_axes: [B,n,3] every joint's axis in the world frame, or None if not asked.
    """

    rotation: torch.Tensor
    position: torch.Tensor | None
    jacobian: torch.Tensor | None
    joint_axes: torch.Tensor | None = None


@dataclass(frozen=True)
class LinkSelection:
    """A list of links compiled for repeated calls (indices, constant offsets, ancestor mask)."""

    names: tuple[str, ...]
    anchor: torch.Tensor  # [L] skeleton frame each link is fixed to
    offset_rotation: torch.Tensor  # [L,3,3,S] link frame in its anchor frame (batch last)
    offset_position: torch.Tensor  # [L,3,S]
    ancestor_mask: torch.Tensor  # [L,n] 1 where joint j moves link L
    pair_link: torch.Tensor  # [P] the (link, joint) pairs where the mask is 1 ...
    pair_joint: torch.Tensor  # [P]
    pair_flat_index: torch.Tensor  # [6P] ... and where their columns go in a flattened [L,6,6+n]
    offsets_are_identity: bool


def compile_selection(t: TreeTensors, names: tuple[str, ...], links: Sequence[int]) -> LinkSelection:
    """The selection of the links with indices `links` [L] (rows of the tree's link_names), named `names`."""
    idx = torch.tensor(links, dtype=torch.long, device=t.device)
    anchor = t.link_anchor[idx]
    R = t.geometry.link_rotation[idx]
    p = t.geometry.link_position[idx]
    eye = torch.eye(3, dtype=t.dtype, device=t.device)[..., None]
    mask = t.ancestor[anchor]  # [L,n]
    link_of_pair, joint_of_pair = mask.nonzero(as_tuple=True)
    width = 6 + t.n_dof
    # flat position of (link l, row r, column 6 + j) in a [L,6,6+n] Jacobian
    rows = torch.arange(6, device=t.device)
    flat = (link_of_pair[:, None] * 6 + rows) * width + 6 + joint_of_pair[:, None]
    return LinkSelection(
        names=names,
        anchor=anchor,
        offset_rotation=R,
        offset_position=p,
        ancestor_mask=mask,
        pair_link=link_of_pair,
        pair_joint=joint_of_pair,
        pair_flat_index=flat.reshape(-1),
        offsets_are_identity=bool((R - eye).abs().max() == 0 and p.abs().max() == 0),
    )

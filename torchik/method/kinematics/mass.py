"""The whole body's centre of mass and its Jacobian, from the masses the URDF gives its links.

With link i of mass m_i at position p_i, turned by R_i, its centre of mass at c_i in its own frame
(the URDF's <inertial> origin), the body's centre of mass and its Jacobian (MIXED, as every
Jacobian in torchik) are

    c = sum_i m_i (p_i + R_i c_i) / M,     J_c = sum_i m_i (J_v,i - [R_i c_i]x J_w,i) / M,

J_v,i and J_w,i the linear and angular rows of link i's Jacobian: the velocity of the point R_i c_i
away from the link's origin is v_i + w_i x R_i c_i. One kinematics call over the links that have a
mass, no loop over them.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from ...errors import ModelError
from .. import so3
from .model import KinematicModel


class CentreOfMass(NamedTuple):
    """position [B,3] (world, m) and jacobian [B,3,6+n] (MIXED; None when not asked for)."""

    position: torch.Tensor
    jacobian: torch.Tensor | None


def massive_links(model: KinematicModel) -> tuple[str, ...]:
    """The links with a mass (every subject's mass above zero for at least one of them)."""
    mass = model._tensors.geometry.link_mass  # [N,S]
    names = tuple(name for name, m in zip(model.link_names, mass.amax(-1).tolist()) if m > 0.0)
    if not names:
        raise ModelError(f"model {model.name!r}: no link has a mass (<inertial><mass value=...>): no centre of mass")
    return names


def total_mass(model: KinematicModel) -> torch.Tensor:
    """[S] each subject's mass (kg): 1 value for a model of one subject."""
    return model._tensors.geometry.link_mass.sum(0)


def centre_of_mass(model: KinematicModel, base_position: torch.Tensor, base_rotation: torch.Tensor,
                   joint_positions: torch.Tensor, jacobian: bool = True) -> CentreOfMass:
    """The centre of mass [B,3] of configurations (p_B [B,3], R_B [B,3,3], s [B,n]) and its MIXED
    Jacobian [B,3,6+n] (with `jacobian`). A model of several subjects (KinematicModel.stack) uses
    each row's own masses."""
    links = massive_links(model)
    selection = model.select(links)
    out = model(base_position, base_rotation, joint_positions, selection, jacobian=jacobian)
    index = torch.tensor([model.tree.link_index[name] for name in links], device=model.device)
    geometry = model._tensors.geometry
    mass = geometry.link_mass.index_select(0, index).T  # [S,L], S = 1 or B
    com = geometry.link_com.index_select(0, index).permute(2, 0, 1)  # [S,L,3] in each link's frame
    share = mass / mass.sum(-1, keepdim=True)  # [S,L]
    lever = (out.rotation @ com.unsqueeze(-1)).squeeze(-1)  # [B,L,3] R_i c_i
    assert out.position is not None  # a forward call gives positions
    position = ((out.position + lever) * share[..., None]).sum(1)
    if not jacobian:
        return CentreOfMass(position, None)
    assert out.jacobian is not None  # asked for
    J = out.jacobian[:, :, :3] - so3.hat(lever) @ out.jacobian[:, :, 3:]  # [B,L,3,6+n]
    return CentreOfMass(position, (J * share[..., None, None]).sum(1))

"""The kinematics one tracker step needs, from the fewest model calls: the target links' rotations
(and positions) at the state, the joints' world axes (and the Jacobians of position targets off the
base) where the scheme linearises the task."""

from __future__ import annotations

from typing import NamedTuple, TypeVar

import torch

from .kinematics import KinematicModel, LinkKinematics
from .scheme import Evaluation
from .state import State
from .structure import BatchSetup, StepStructure

_T = TypeVar("_T")


class StepKinematics(NamedTuple):
    """What a step needs of the kinematics: rotation [B,n_o,3,3] and position [B,n_p,3] (or the base
    position [B,1,3], which broadcasts) of the target links at the state; joint_axes [B,n,3] and the
    Jacobians of the position links off the base [B,n_j,6,6+n] (or None) where the task is linearised."""

    rotation: torch.Tensor
    position: torch.Tensor
    joint_axes: torch.Tensor
    position_jacobian: torch.Tensor | None


def step_kinematics(model: KinematicModel, structure: StepStructure, batch: BatchSetup, scheme: str, q: State,
                    R_B: torch.Tensor, at: Evaluation) -> StepKinematics:
    """The target links' rotations and positions at the state (q, its orthonormalised base
    rotation), and the joints' world axes and position Jacobians at `at`'s configuration (the
    same in the paper's scheme). Small batches cost per operation, not per row: both
    configurations then go in one call."""
    B = batch.size
    paper, stacked = scheme == "paper", scheme == "midpoint" and batch.stacked
    if structure.rotations_only:  # orientation targets and the base's position: no positions, no Jacobians
        p_hat, links = q.base_position.unsqueeze(1), structure.orientation_selection
        assert links is not None  # rotations_only: there are orientation targets
        if paper:
            now = model.rotations(R_B, q.joint_positions, links, joint_axes=True)
            return StepKinematics(now.rotation, p_hat, given(now.joint_axes), None)
        if stacked:
            both = model.rotations(torch.cat((R_B, at.base_rotation)),
                                   torch.cat((q.joint_positions, at.joint_positions)), links, joint_axes=True)
            return StepKinematics(both.rotation[:B], p_hat, given(both.joint_axes)[B:], None)
        # the axes alone: the mid-step call selects one link (its rotations are not used)
        mid_axes = model.rotations(at.base_rotation, at.joint_positions, structure.base_selection,
                                   joint_axes=True).joint_axes
        return StepKinematics(model.rotations(R_B, q.joint_positions, links).rotation, p_hat, given(mid_axes), None)
    # position targets off the base need link positions and their Jacobians
    jacobian, jacobian_links = structure.targets.position is not None, structure.targets.position
    base_position = given(at.base_position)  # the step asked for positions
    if paper:
        now = model(q.base_position, R_B, q.joint_positions, structure.selection, out=batch.buffers,
                    jacobian=jacobian, jacobian_links=jacobian_links, joint_axes=True)
        axes, position_jacobian = now.joint_axes, now.jacobian
    elif stacked:
        both = model(torch.cat((q.base_position, base_position)), torch.cat((R_B, at.base_rotation)),
                     torch.cat((q.joint_positions, at.joint_positions)), structure.selection, out=batch.buffers,
                     jacobian=jacobian, jacobian_links=jacobian_links, joint_axes=True)
        now = LinkKinematics(both.rotation[:B], given(both.position)[:B], None)
        axes = given(both.joint_axes)[B:]
        position_jacobian = None if both.jacobian is None else both.jacobian[B:]
    else:
        now = model(q.base_position, R_B, q.joint_positions, structure.selection, jacobian=False)
        mid = model(base_position, at.base_rotation, at.joint_positions, structure.selection, out=batch.buffers,
                    jacobian=jacobian, jacobian_links=jacobian_links, joint_axes=True)
        axes, position_jacobian = mid.joint_axes, mid.jacobian
    return StepKinematics(now.rotation.index_select(1, structure.orientation_index),
                          given(now.position).index_select(1, structure.position_index), given(axes),
                          position_jacobian)


def given(value: _T | None) -> _T:
    """value, which the call that made it was asked for (an optional output), or which the batch's
    setup guarantees (a structured batch's joint tree)."""
    assert value is not None
    return value

"""What one step asks of the QP, from the evaluation and the kinematics, and the tracking errors it
reports: the part of the step between the kinematics and the solve, shared by the tracker's step and
its captured replay (`captured.py`)."""

from __future__ import annotations

from typing import NamedTuple

import torch

from .constraints import stacked_rows
from .kinematics import KinematicModel
from .limits import LinearRows, linear_limit_bounds, velocity_bounds
from .metrics import orientation_error
from .qp import QPProblem, TreeHessian
from .residual import corrected_velocity, orientation_residual, position_residual
from .scheme import Evaluation
from .settings import TrackerSettings
from .step_kinematics import StepKinematics, given
from .structure import BatchSetup, StepStructure
from .target_equations import normal_equations
from .tasks import StepContext

Weights = tuple[torch.Tensor | None, torch.Tensor | None]  # position [B,n_p], orientation [B,n_o]; None: all 1


class StepProblem(NamedTuple):
    """The residuals r_p [B,n_p,3], r_o [B,n_o,3] the step corrects and the QP that does it."""

    r_p: torch.Tensor
    r_o: torch.Tensor
    problem: QPProblem


def step_problem(model: KinematicModel, structure: StepStructure, settings: TrackerSettings, batch: BatchSetup,
              s: torch.Tensor, at: Evaluation, kin: StepKinematics, dt: float | torch.Tensor,
              weights: Weights = (None, None), context: StepContext | None = None) -> StepProblem:
    """Residuals r against `at`'s targets, corrected velocities v* = v + K r, the normal equations of
    ||v* - J nu||^2 + lambda ||nu||^2 (H in the tree's structured form, and None, when the batch
    solves on it), the joint limits as velocity bounds and the coupled limits as rows, for the
    joints s [B,n] and the time step dt (a float or [B,1]); then each further task's normal
    equations added (structure.tasks) and each further limit's rows (structure.limits), which
    `context` (the state, dt and sample they read) is for."""
    x = at.residual_targets
    r_p = position_residual(x.position, kin.position)
    r_o = orientation_residual(x.rotation, kin.rotation)
    v_p = corrected_velocity(at.linear_velocity, r_p, structure.position_gain)
    v_o = corrected_velocity(at.angular_velocity, r_o, structure.orientation_gain)
    damping = settings.damping
    objective = normal_equations(structure.targets, kin.joint_axes, kin.position_jacobian, v_p, v_o, damping,
                                 w_position=weights[0], w_orientation=weights[1], hessian=not batch.structured)
    tree = TreeHessian.from_targets(given(structure.tree), kin.joint_axes, damping, r_p.shape[1],
                                    w_position=weights[0], w_orientation=weights[1]) if batch.structured else None
    bounds = velocity_bounds(s, model.lower, model.upper, settings.limits, dt, batch.base_bounds)
    rows = _coupled_rows(model, settings, batch, s, dt)
    H, g, equalities = objective.H, objective.g, None
    if structure.tasks or structure.limits:
        assert context is not None, "a step with tasks or limits of its own is given their context"
        for task in structure.tasks:  # one call per task, each batched: a handful, not one per link
            H_i, g_i = task.normal_equations(context)
            H, g = given(H) + H_i, g + g_i
        rows = stacked_rows(([rows] if rows else []) + [r for x in structure.limits if (r := x.rows(context))])
        equalities = stacked_rows([e for x in structure.limits if (e := x.equalities(context)) is not None])
    return StepProblem(r_p, r_o, QPProblem(H, g, bounds.lower, bounds.upper, rows.G if rows else None,
                                        rows.h if rows else None, tree, equalities.G if equalities else None,
                                        equalities.h if equalities else None))


def _coupled_rows(model: KinematicModel, settings: TrackerSettings, batch: BatchSetup, s: torch.Tensor,
                  dt) -> LinearRows | None:
    """The coupled limits A s <= b as rows on nu, G nu <= h (None when the model has none)."""
    if batch.linear_rows is None:
        return None
    limits = model.linear_limits
    assert limits is not None  # the rows exist
    return LinearRows(batch.linear_rows, linear_limit_bounds(s, limits.A, limits.b, settings.limits, dt))


def tracking_errors(at: Evaluation, kin: StepKinematics, task: StepProblem,
                    valid: tuple[torch.Tensor, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The step's mnte [B] (the state at the step's start against the targets at that instant, over the
    valid orientation targets) and residual norms [B,n_p+n_o] (0 for dropped targets); valid:
    (position [B,n_p], orientation [B,n_o]) bool, None when every target is."""
    error = orientation_error(at.start_targets.rotation, kin.rotation,
                              task.r_o if at.start_targets is at.residual_targets else None)  # [B,n_o]
    residual_norm = torch.linalg.vector_norm(torch.cat((task.r_p, task.r_o), dim=1), dim=-1)  # [B,n_p+n_o]
    if valid is None:
        return error.mean(-1), residual_norm
    weight = valid[1].to(error.dtype)
    mnte = (error * weight).sum(-1) / weight.sum(-1).clamp(min=1.0)  # 0 where no target is valid
    return mnte, residual_norm * torch.cat(valid, dim=1)

"""Instantaneous inverse kinematics: the paper's comparison methods, batched like the tracker.

`WholeBodyIK` solves, at each time step, min ||K_r r(q)||^2 over the whole configuration subject
to the joint limits, by constrained Gauss-Newton: each iteration is the tracker's QP (the same
normal equations, the same PIQP backend) for a configuration increment delta, with the exact
limits s_min - s <= delta_s <= s_max - s (and A (s + delta_s) <= b), then q <- q (+) delta (the
base rotation through the exponential map). It starts from the previous step's solution and
stops at a pose-error tolerance or an iteration cap; subjects that have converged are left alone.
(The paper used IPOPT; Gauss-Newton with the same QP is the fair counterpart here.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from . import so3
from .kinematics import KinematicModel
from .qp import QPProblem, make_backend
from .residual import orientation_error, orientation_residual
from .targets import Targets
from .task import TaskStructure, normal_equations
from .tracker import State


@dataclass(frozen=True)
class IKResult:
    """A solve: state (velocity zero), iterations [B], converged [B], mnte [B] at the solution, seconds."""

    state: State
    iterations: torch.Tensor
    converged: torch.Tensor
    mnte: torch.Tensor
    solve_time: float


class WholeBodyIK:
    """Iterate-to-convergence IK of all targets at once.

    tolerance: stop when the largest residual norm (m, or sin of the angle) is below it
    (default 1e-10); max_iterations: the cap (default 50); damping: lambda of the step's QP.
    """

    def __init__(self, model: KinematicModel, orientation_links, position_links=None, tolerance: float = 1e-10,
                 max_iterations: int = 50, damping: float = 1e-9, backend: str = "piqp"):
        self.model = model
        self.position_links = tuple(position_links if position_links is not None else (model.base_link,))
        self.orientation_links = tuple(orientation_links)
        links = tuple(dict.fromkeys(self.position_links + self.orientation_links))
        self._selection = model.select(links)
        index = {name: i for i, name in enumerate(links)}
        long = dict(dtype=torch.long, device=model.device)
        self._p = torch.tensor([index[n] for n in self.position_links], **long)
        self._o = torch.tensor([index[n] for n in self.orientation_links], **long)
        self._task = TaskStructure.build(model, self.orientation_links, self.position_links)
        self.tolerance, self.max_iterations, self.damping = tolerance, max_iterations, damping
        self.backend = make_backend(backend)

    @torch.inference_mode()
    def solve(self, targets: Targets, start: State) -> IKResult:
        """Solve for one instant's targets from `start` (the previous solution). Targets [B,...]."""
        began = time.perf_counter()
        model = self.model
        p, R, s = start.base_position.clone(), start.base_rotation.clone(), start.joint_positions.clone()
        B = p.shape[0]
        iterations = torch.zeros(B, dtype=torch.long, device=p.device)
        active = torch.ones(B, dtype=torch.bool, device=p.device)
        lower, upper = model.lower, model.upper
        for _ in range(self.max_iterations):  # Gauss-Newton iterations (the method), not links or subjects
            kin = model(p, R, s, self._selection, jacobian_links=self._task.position,
                        jacobian=self._task.position is not None, joint_axes=True)
            r_p = targets.position - kin.position.index_select(1, self._p)
            r_o = orientation_residual(targets.rotation, kin.rotation.index_select(1, self._o))
            error = torch.cat((r_p, r_o), 1).norm(dim=-1).amax(-1)
            active = active & (error > self.tolerance)
            if not bool(active.any()):
                break
            H, g = normal_equations(self._task, kin.joint_axes, kin.jacobian, r_p, r_o, self.damping)
            free = torch.full((B, 6), torch.inf, dtype=p.dtype, device=p.device)
            lb = torch.cat((-free, (lower - s).clamp(max=0.0)), 1)
            ub = torch.cat((free, (upper - s).clamp(min=0.0)), 1)
            G = h = None
            if model.linear_limits is not None:
                A, b = model.linear_limits.A, model.linear_limits.b
                G = torch.cat((A.new_zeros(A.shape[0], 6), A), 1).expand(B, -1, -1)
                h = (b - s @ A.T).clamp(min=0.0)
            delta = self.backend.solve(QPProblem(H, g, lb, ub, G, h)).x
            delta = delta * active[:, None]
            p = p + delta[:, :3]
            R = so3.exp(delta[:, 3:6]) @ R
            s = s + delta[:, 6:]
            iterations += active
        kin = model(p, R, s, self._selection, jacobian=False)
        mnte = orientation_error(targets.rotation, kin.rotation.index_select(1, self._o)).mean(-1)
        zero = torch.zeros(B, 6 + model.n_dof, dtype=p.dtype, device=p.device)
        return IKResult(State(p, R, s, zero), iterations, ~active, mnte, time.perf_counter() - began)

"""Tasks: what the step drives the configuration velocity towards, each a residual and its Jacobian.

A task i has a residual r_i(q) [B,m_i] (its target less where the body is, in the space of its
velocity), the Jacobian J_i [B,m_i,6+n] that maps nu (MIXED: base linear and angular velocity in
the world frame, then the joint rates) to that velocity, a feed-forward velocity v_i [B,m_i] (zero
unless the task's target moves), a gain K_i (1/s) and a weight w_i. The step solves

    minimise  sum_i w_i ||v_i + K_i r_i - J_i nu||^2 + lambda ||nu||^2   subject to the limits

whose normal equations are the sum of each task's H_i = w_i J_i^T J_i and g_i = -w_i J_i^T (v_i +
K_i r_i): a task gives `terms` (r, J, v), or, where it knows a cheaper form, its `normal_equations`
directly (a posture task's H is diagonal).

The paper's two tasks, `OrientationTask` and `PositionTask`, are declarations: the step builds their
normal equations from the tree's structure (target_equations.py) and solves them in O(n) on the joints' tree
(qp/tree.py), which no general task allows. Any other task makes the step dense (the same batch,
H formed and factorised densely). Tasks here are linearised at the step's start state (the paper's
at mid-step, second order: scheme.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import torch

from ..errors import InputError
from .kinematics import KinematicModel
from .kinematics.mass import centre_of_mass
from .state import State


@dataclass(frozen=True)
class StepContext:
    """What a task or a limit sees at a step: the model; the state at the step's start (its base
    rotation orthonormal); dt (a float, or [B,1]); sample: the index of the targets the step tracks
    (a run's sample k; the step's count since `reset` when stepping by hand)."""

    model: KinematicModel
    state: State
    dt: float | torch.Tensor
    sample: int


class TaskTerms(NamedTuple):
    """residual [B,m], jacobian [B,m,6+n], velocity [B,m] (feed-forward; None: zero), active [B,m]
    (1 where a row counts this step, 0 where not: a contact off; None: every row)."""

    residual: torch.Tensor
    jacobian: torch.Tensor
    velocity: torch.Tensor | None = None
    active: torch.Tensor | None = None


@dataclass
class Task:
    """A task of gain `gain` (1/s: the rate at which its residual closes) and weight `weight` (its
    share of the objective against the others; the paper's tasks weigh 1). Subclasses give `terms`
    or `normal_equations`; `name` labels it in reports."""

    gain: float = 20.0
    weight: float = 1.0
    name: str = field(default="task", kw_only=True)

    def terms(self, context: StepContext) -> TaskTerms:
        raise NotImplementedError(f"{type(self).__name__} gives neither terms nor normal_equations")

    def reset(self) -> None:
        """Forget what earlier steps left (the tracker's `reset` calls it): nothing, unless the task
        remembers (a contact's anchor)."""

    def rate(self, context: StepContext) -> float | torch.Tensor:
        """K (1/s; a float, or [B,1] where it follows a jittered dt): the gain."""
        assert self.gain is not None, "a task has a gain"
        return self.gain

    def normal_equations(self, context: StepContext) -> tuple[torch.Tensor, torch.Tensor]:
        """H [B,N,N] and g [B,N] of w ||v + K r - J nu||^2 (halved: 1/2 nu^T H nu + g^T nu)."""
        r, J, v, active = self.terms(context)
        K = self.rate(context)
        wanted = K * r if v is None else v + K * r
        w = torch.full_like(r, self.weight) if active is None else self.weight * active
        WJ = w.unsqueeze(-1) * J
        return J.transpose(1, 2) @ WJ, -(WJ.transpose(1, 2) @ wanted.unsqueeze(-1)).squeeze(-1)


@dataclass
class OrientationTask(Task):
    """The paper's orientation targets on `links` (their rotations and angular velocities come with
    each step's Targets): a declaration the step solves on the tree."""

    links: Sequence[str] = ()
    gain: float | None = None  # type: ignore[assignment]  # None: the settings' orientation_gain
    name: str = field(default="orientation", kw_only=True)


@dataclass
class PositionTask(Task):
    """The paper's position targets on `links` (default the base link): a declaration, as
    OrientationTask."""

    links: Sequence[str] = ()
    gain: float | None = None  # type: ignore[assignment]  # None: the settings' position_gain
    name: str = field(default="position", kw_only=True)


PAPER_TASKS = (OrientationTask, PositionTask)


def _series_at(series: torch.Tensor, sample: int, what: str) -> torch.Tensor:
    """series[sample] of a per-sample input [T,...], or the input itself when it has no time axis
    (given as [B,...] or [...])."""
    if sample >= series.shape[0]:
        raise InputError(f"{what}: {series.shape[0]} samples, the step tracks sample {sample}")
    return series[sample]


@dataclass
class PostureTask(Task):
    """The joints pulled towards a `posture` [n] (rad; or [B,n]) with a small weight: it fills the
    directions no other task sees (an untracked neck, the arms of a suit without arm sensors). Its
    normal equations are diagonal on the joints: H = w I, g = -w K (posture - s)."""

    posture: torch.Tensor | None = None  # None: the zero configuration
    weight: float = 1e-3
    name: str = field(default="posture", kw_only=True)

    def _reference(self, context: StepContext) -> torch.Tensor:
        s = context.state.joint_positions
        return torch.zeros_like(s) if self.posture is None else self.posture.to(s).expand_as(s)

    def terms(self, context: StepContext) -> TaskTerms:
        s = context.state.joint_positions
        B, n = s.shape
        J = torch.cat((s.new_zeros(n, 6), torch.eye(n, dtype=s.dtype, device=s.device)), 1).expand(B, n, 6 + n)
        return TaskTerms(self._reference(context) - s, J)

    def normal_equations(self, context: StepContext) -> tuple[torch.Tensor, torch.Tensor]:
        s = context.state.joint_positions
        B, n = s.shape
        diagonal = torch.cat((s.new_zeros(6), s.new_full((n,), self.weight)))
        g = torch.cat((s.new_zeros(B, 6), -self.weight * self.gain * (self._reference(context) - s)), 1)
        return torch.diag_embed(diagonal).expand(B, 6 + n, 6 + n), g


@dataclass
class CentreOfMassTask(Task):
    """The body's centre of mass (kinematics.mass) held at `target` [3] or [B,3] (m, world), or
    following a series [T,B,3] (sample by sample); `axes` the world axes it acts on (default x and
    y: over the feet, its height left free)."""

    target: torch.Tensor | None = None
    axes: tuple[int, ...] = (0, 1)
    name: str = field(default="centre of mass", kw_only=True)

    def terms(self, context: StepContext) -> TaskTerms:
        q = context.state
        com = centre_of_mass(context.model, q.base_position, q.base_rotation, q.joint_positions)
        assert com.jacobian is not None  # asked for
        if self.target is None:
            raise InputError("CentreOfMassTask: give a target (m, world)")
        target = self.target.to(com.position)
        if target.dim() == 3:
            target = _series_at(target, context.sample, "CentreOfMassTask.target")
        axes = list(self.axes)
        return TaskTerms((target.expand_as(com.position) - com.position)[:, axes], com.jacobian[:, axes])


@dataclass
class RelativePositionTask(Task):
    """Link `b`'s origin held at `offset` [3] from link `a`'s (world frame, m): hands together
    (offset zero), a tool held between them."""

    a: str = ""
    b: str = ""
    offset: torch.Tensor | None = None
    name: str = field(default="relative position", kw_only=True)

    def terms(self, context: StepContext) -> TaskTerms:
        q, model = context.state, context.model
        out = model(q.base_position, q.base_rotation, q.joint_positions, (self.a, self.b))
        assert out.position is not None and out.jacobian is not None  # a forward call gives both
        between = out.position[:, 1] - out.position[:, 0]
        offset = torch.zeros_like(between) if self.offset is None else self.offset.to(between).expand_as(between)
        return TaskTerms(offset - between, out.jacobian[:, 1, :3] - out.jacobian[:, 0, :3])


@dataclass
class ContactTask(Task):
    """A link's velocity held at zero while it is on the ground: its linear velocity (and, with
    `angular`, its angular velocity too), a stiff task (weight 100 by default) switched by `on`, a
    [T,B] per-sample bool (or [B], or a bool for all). The residual is the link's drift from where
    the contact began: zero velocity alone would let a foot creep by the solve's errors; its gain
    (default 1/dt) closes that drift in a step."""

    link: str = ""
    on: torch.Tensor | bool = True
    angular: bool = False
    weight: float = 100.0
    gain: float | None = None  # type: ignore[assignment]  # None: 1/dt, the drift closed in one step
    name: str = field(default="contact", kw_only=True)
    _anchor: torch.Tensor | None = field(default=None, repr=False)

    def reset(self) -> None:
        self._anchor = None

    def rate(self, context: StepContext) -> float | torch.Tensor:
        # a step's linearisation leaves the foot O(dt^2) off where J nu puts it; that drift, closed at
        # K, stands at drift / (K dt): at K = 1/dt it is one step's, at the paper's K dt = 0.2 five
        return 1.0 / context.dt if self.gain is None else self.gain

    def active(self, context: StepContext) -> torch.Tensor:
        """[B] bool: the contact is on at this step."""
        B = context.state.base_position.shape[0]
        on = torch.as_tensor(self.on, device=context.state.base_position.device)
        if on.dim() == 2:
            on = _series_at(on, context.sample, "ContactTask.on")
        return on.to(torch.bool).expand(B)

    def terms(self, context: StepContext) -> TaskTerms:
        q, model = context.state, context.model
        out = model(q.base_position, q.base_rotation, q.joint_positions, (self.link,))
        assert out.position is not None and out.jacobian is not None  # a forward call gives both
        p, J = out.position[:, 0], out.jacobian[:, 0]
        on = self.active(context)
        # where it touched down: the anchor moves with the link while the contact is off
        anchor = p if self._anchor is None or self._anchor.shape != p.shape else \
            torch.where(on[:, None], self._anchor, p)
        self._anchor = anchor
        r = anchor - p
        rows = 3
        if self.angular:
            r = torch.cat((r, torch.zeros_like(r)), 1)  # the angular part: no rotation, nothing to undo
            rows = 6
        return TaskTerms(r, J[:, :rows], None, on[:, None].to(r.dtype).expand(-1, rows))


def split_tasks(tasks: Sequence[Task]) -> tuple[OrientationTask | None, PositionTask | None, tuple[Task, ...]]:
    """The paper's orientation and position tasks (one of each at most) and the others."""
    orientation = [t for t in tasks if isinstance(t, OrientationTask)]
    position = [t for t in tasks if isinstance(t, PositionTask)]
    if len(orientation) > 1 or len(position) > 1:
        raise InputError("give at most one OrientationTask and one PositionTask (each takes a list of links)")
    others = tuple(t for t in tasks if not isinstance(t, PAPER_TASKS))
    for t in others:
        if not isinstance(t, Task):
            raise InputError(f"tasks: {t!r} is not a torchik.method.tasks.Task")
    return (orientation[0] if orientation else None, position[0] if position else None, others)

"""The tracker's step, captured once and replayed compiled (`TrackerSettings(compile=True)`).

After `reset` every shape of the step is fixed, and from one step to the next nothing but the
numbers changes. So the step's tensor work, from the targets to the next state and the diagnostics,
is captured once (`capture.py`) and replayed: one compiled call in place of the eager step's some
180 operations, each paying the dispatcher's overhead.

What depends on the data becomes two flags, read in the step's one synchronisation:

- solvable: the targets are finite and their rotations orthonormal (nothing to drop or project) and
  dt is positive, with no gap (at most max_gap nominal steps). Otherwise the eager step runs from
  the same inputs, which the captured one left untouched: those cases keep its semantics exactly.
- usual: besides, every subject's unconstrained minimiser is within its limits (then it is the QP's
  solution, as the PIQP backend finds it: no solver runs), the new base rotation is near enough to
  SO(3) for Newton-Schulz, and the invariant holds. Then the replayed step is complete. Otherwise
  (a bound active, mostly) the captured step hands its QP to the backend with its unconstrained
  solve (`qp.Unconstrained`: the minimiser, which subjects it satisfies, and on the tree of a model
  with coupled limits the factorisation): the backend solves only the other subjects, from that
  factorisation where they hold no bound (iCub's coupled rows, in their Schur complement). The
  tracker ends the step as the eager one does (integration, invariant).

The replay needs a settled history (two steps taken, no dropped target remembered). A replayed
step's results are the eager step's to rounding (fused sums in another order; 1e-12 on the states
over a walking run).

Opt-in, not automatic: the first capture of a model's step on a machine compiles C++ for tens of
seconds (later ones load it from TorchInductor's cache in seconds), which pays off on long runs
and live tracking, not in a test or a demo of a few hundred steps. From
`BatchSetup.CAPTURED_TREE_FROM` subjects it solves on the joints' tree, each tree level's tensors
made afresh rather than written into one buffer (`capture.tracing`): for Human66 on a CPU,
several times faster than the eager step at B = 128 and 1024 (the figures: docs/speed.md; the
runs: experiments/speed_history.md). It is made at the first settled
step of a batch size and kept for the tracker's later runs of that size, with the model's tensors
as they are then.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import Callable

import torch

from .capture import CaptureError, capture
from .integrate import integrate, orthonormalize_unsynchronised
from .invariant import invariant_measure
from .kinematics import KinematicModel
from .qp import QPProblem, TreeHessian, Unconstrained, unconstrained
from .qp.tree import TreeFactor
from .scheme import SchemeHistory, evaluation
from .settings import TrackerSettings
from .state import State
from .step_kinematics import step_kinematics
from .step_problem import step_problem, tracking_errors
from .structure import BatchSetup, StepStructure
from .targets import Targets, already_clean


@dataclasses.dataclass(frozen=True)
class Replayed:
    """A captured step's results: a copy of the step's targets for the history, the dt the history
    records, the diagnostics mnte [B] and residual_norm [B,n_p+n_o]; and either, for a usual step,
    the next state (its base rotation orthonormalised as `rotation`), the next velocity slope and
    active_constraints [B] (problem None), or, where a bound is active or the invariant is to be
    checked eagerly, the step's QP `problem` for the backend with its unconstrained minimiser and
    factorisation `start` (the others None)."""

    targets: Targets
    dt: float | torch.Tensor
    mnte: torch.Tensor
    residual_norm: torch.Tensor
    problem: QPProblem | None = None
    start: Unconstrained | None = None
    state: State | None = None
    rotation: torch.Tensor | None = None
    slope: torch.Tensor | None = None
    active_constraints: torch.Tensor | None = None


class CapturedStep:
    """The step of a tracker's model, targets and settings for one batch size, captured at its first
    call. Calling it returns the step's `Replayed` results, or None where the eager step must run
    instead (targets to drop or project, a gap; or no capture here: then a warning, once, and None
    from then on)."""

    def __init__(self, model: KinematicModel, structure: StepStructure, settings: TrackerSettings, batch: BatchSetup):
        self.model, self.structure, self.settings = model, structure, settings
        # no output buffers: the captured step makes its own tensors
        self.batch = dataclasses.replace(batch, buffers=None)
        kw: dict = dict(dtype=model.dtype, device=model.device)
        self.nominal = torch.full((batch.size, 1), float(settings.dt), **kw)
        self._compiled: Callable[..., list] | None = None
        self.unavailable = False
        self.compile_seconds: float | None = None  # how long the capture took, once made

    def __call__(self, q: State, rotation: torch.Tensor, history: SchemeHistory, targets: Targets,
                 dt: float | torch.Tensor | None) -> Replayed | None:
        """The step from q (its base rotation orthonormalised as `rotation`), a settled history, the
        step's targets and dt as `DynamicalIK.step` takes it."""
        if self.unavailable:
            return None
        step = self._time_step(dt)
        if step is None:
            return None
        previous, before = history.remembered()
        last = self.nominal if isinstance(history.last_dt, float) else history.last_dt
        inputs = [q.base_position, q.base_rotation, rotation, q.joint_positions, q.velocity, history.velocity_slope,
                  step, last, *vars(targets).values(), *vars(previous).values(), *vars(before).values()]
        if self._compiled is None and not self._capture(inputs):
            return None
        assert self._compiled is not None  # captured above
        p, R, R_o, s, nu, slope, mnte, residual_norm, active, flags, g, lb, ub, h, *rest = self._compiled(*inputs)
        # H [B,N,N], or the tree's form of H (axes, node and position weights) and, with coupled
        # rows, its factorisation's parts; then the targets' copies
        copies, rest = rest[-4:], rest[:-4]
        dense = not self.batch.structured
        hessian, factor = rest[:3], rest[3:]
        usual, solvable = flags[:2].tolist()
        if not solvable:
            return None
        done = dict(targets=Targets(*copies), dt=history.nominal_dt if dt is None else step, mnte=mnte,
                    residual_norm=residual_norm)
        if usual:
            return Replayed(**done, state=State(p, R, s, nu), rotation=R_o, slope=slope, active_constraints=active)
        G, tree = self.batch.linear_rows, self.structure.tree
        made: TreeFactor | None = None
        if dense:
            problem = QPProblem(hessian[0], g, lb, ub, G, None if G is None else h)
        else:
            assert tree is not None  # the step's H is in the tree's form only where the model has one
            problem = QPProblem(None, g, lb, ub, G, None if G is None else h,
                                TreeHessian(tree, hessian[0], hessian[1], hessian[2], self.settings.damping))
            made = TreeFactor.from_parts(tree, factor) if factor else None
        return Replayed(**done, problem=problem, start=Unconstrained(nu, flags[2:], made))

    def _time_step(self, dt) -> torch.Tensor | None:
        """dt as [B,1] (the nominal one for None); None for a dt of the wrong shape, which the eager
        step refuses with its message."""
        if dt is None:
            return self.nominal
        B = self.batch.size
        dt = torch.as_tensor(dt, dtype=self.model.dtype, device=self.model.device)
        if dt.dim() == 0:
            dt = dt.expand(B)
        return dt[:, None] if dt.shape == (B,) else None

    def _capture(self, inputs: list[torch.Tensor]) -> bool:
        start = time.perf_counter()
        try:
            self._compiled = capture(self._usual_step, inputs)
        except CaptureError as error:
            warnings.warn(f"the tracker's step runs eagerly: {error}", stacklevel=4)
            self.unavailable = True
            return False
        self.compile_seconds = time.perf_counter() - start
        return True

    def _usual_step(self, p, R, R_B, s, nu, slope, dt, last_dt, *targets) -> tuple:
        """The step's tensor work, traced once: the eager step's functions in its order, the
        branches on data replaced by the `usual` flag. dt, last_dt: [B,1]."""
        model, structure, settings, batch = self.model, self.structure, self.settings, self.batch
        x, previous, before = (Targets(*targets[i:i + 4]) for i in (0, 4, 8))
        q = State(p, R, s, nu)
        at = evaluation(settings.scheme, q, R_B, x, previous, before, dt, last_dt, slope,
                        positions=not structure.rotations_only)
        kin = step_kinematics(model, structure, batch, settings.scheme, q, R_B, at)
        task = step_problem(model, structure, settings, batch, s, at, kin, dt)
        start = unconstrained(task.problem)
        nu_next, feasible = start.x, start.feasible
        p_next, R_next, s_next = integrate(p, R, s, nu_next, dt, settings.rotation_integrator, settings.baumgarte_gain)
        R_o, near = orthonormalize_unsynchronised(R_next)
        kept = invariant_measure(State(p_next, R_next, s_next, nu_next), R_o, s, model.lower, model.upper) <= 1.0
        no_gap = (dt > 0) & (dt <= settings.max_gap * settings.dt)  # False for NaN
        solvable = already_clean(x) & no_gap.all()  # the QP is the eager step's: a backend can solve it
        usual = solvable & feasible.all() & near & kept.all()
        mnte, residual_norm = tracking_errors(at, kin, task)
        # d(nu)/dt between this step's midpoint and the last one's (SchemeHistory.advance)
        next_slope = (nu_next - nu) / (0.5 * (dt + last_dt))
        problem = task.problem
        h = problem.h if problem.h is not None else problem.g.new_zeros(())  # a placeholder: no coupled rows
        tree = problem.tree
        # the tree's factorisation is returned only where coupled rows make the backend's turn
        # frequent and its first iteration able to use it (iCub): returned, it cannot share its
        # memory with other intermediates, which slows Human66's step (experiments/speed_history.md)
        if tree is None:
            hessian: tuple = (problem.H,)
        elif batch.linear_rows is None:
            hessian = (tree.axes, tree.node_weight, tree.position_weight)
        else:
            assert isinstance(start.factor, TreeFactor)  # made from the tree
            hessian = (tree.axes, tree.node_weight, tree.position_weight, *start.factor.parts())
        return (p_next, R_next, R_o, s_next, nu_next, next_slope, mnte, residual_norm, problem.active(nu_next),
                torch.cat((torch.stack((usual, solvable)), feasible)), problem.g, problem.lb, problem.ub, h, *hessian,
                *(t.clone() for t in targets[:4]))

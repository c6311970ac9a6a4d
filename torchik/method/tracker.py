"""Dynamical inverse kinematics: one constrained velocity solve per time step.

Each step, for a batch of B subjects, is the method read top to bottom (`DynamicalIK.step`):

1. targets x_k (positions, rotations and their velocities) are cleaned: non-finite ones are
   dropped for the step, nearly orthonormal rotations projected (`targets.py`);
2. the discretisation says which targets the residual compares the state with, the feed-forward
   velocities, and where the task is linearised (`scheme.py`: 'midpoint' or the paper's);
3. kinematics: the target links' rotations (and positions) at the state, the joints' world axes
   (and the Jacobians of position targets off the base) where the task is linearised;
4. residuals r (position p* - p, orientation R_hat sk(R_hat^T R*)^vee, world frame) and corrected
   velocities v* = v + K r (`residual.py`);
5. the objective ||v* - J nu||^2 + lambda ||nu||^2 as normal equations (`target_equations.py`);
6. bounds: the joint limits as velocity bounds, coupled limits as rows A s_dot <= h (`limits.py`);
7. the QP (`qp/`);
8. integration of the configuration from nu over dt (`integrate.py`);
9. the invariant (`invariant.py`): every state the step returns is finite, its base rotation
   orthonormal to 1e-12 and its joints within their limits; a subject whose state breaks it
   restarts from the step's targets (as `initial_state`), its step marked failed.

A time step longer than `settings.max_gap` nominal steps (a suit that dropped out, a stream that
stalled) is not integrated: the subject restarts from the targets after the gap, a new segment.

Diagnostics: mnte compares the state at the start of the step with the targets at that instant;
residual_norm is the residual the step used (against x(t_k) in the paper's scheme).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Generator, Iterable, Sequence

import torch

from ..errors import InputError
from .captured import CapturedStep, Replayed
from .constraints import CoupledLimits, JointLimits, Limit, split_limits
from .integrate import integrate, orthonormalize
from .invariant import broken_subjects
from .kinematics import KinematicModel
from .qp import QPBackend, make_backend
from .scheme import Evaluation, SchemeHistory
from .sequence import run_parts
from .settings import SCHEMES, TrackerSettings, check_settings
from .state import State, StepDiagnostics, TargetSequence, Trajectory
from .step_kinematics import StepKinematics, step_kinematics
from .step_problem import step_problem, tracking_errors
from .structure import BatchSetup, StepStructure
from .targets import Targets, check_targets, clean_targets
from .tasks import OrientationTask, PositionTask, StepContext, Task, split_tasks


class DynamicalIK:
    """The tracker. Build it once for a model and a set of targets, `reset`, then `step` or `run`.

    model: a KinematicModel (or a stack of subjects); orientation_links, position_links: the
    links the targets belong to (default: one position target on the base link); settings: a
    TrackerSettings, and any of its fields as keywords to change them (`position_gain=30.0`,
    `dt=1/120`, `scheme="paper"`, `backend="batched"` or a configured QPBackend, ...).
    `step(..., dt=...)` may vary the time step (jittered timestamps).

    tasks: the step's tasks (tasks.py). The paper's, `OrientationTask(links)` and
    `PositionTask(links)`, may stand for orientation_links and position_links (their gains, when
    given, for the settings'); any other (a centre of mass, a contact, a posture, a relative
    position, one of your own) is added to them, and the step then solves densely. constraints:
    limits beyond the model's joint and coupled limits (constraints.py: a contact held exactly),
    which always hold (the settings' `limits` say how the joint limits slow the joints). `tasks` and
    `constraints` list them all afterwards, the paper's and the model's first.
    """

    def __init__(self, model: KinematicModel, orientation_links: Sequence[str] | None = None,
                 position_links: Sequence[str] | None = None, settings: TrackerSettings | None = None,
                 tasks: Sequence[Task] = (), constraints: Sequence[Limit] = (), **changes):
        orientation, position, extra_tasks = split_tasks(tasks)
        for task, name in ((orientation, "orientation_gain"), (position, "position_gain")):
            if task is not None and task.gain is not None:
                changes.setdefault(name, task.gain)
        try:
            settings = dataclasses.replace(settings or TrackerSettings(), **changes)
        except TypeError:
            valid = ", ".join(f.name for f in dataclasses.fields(TrackerSettings))
            raise InputError(f"unknown tracker setting among {sorted(changes)}; valid: {valid}") from None
        check_settings(settings)
        if orientation is not None and orientation_links is not None:
            raise InputError("give the orientation targets' links once: orientation_links or an OrientationTask")
        if position is not None and position_links is not None:
            raise InputError("give the position targets' links once: position_links or a PositionTask")
        orientation_links = orientation.links if orientation is not None else orientation_links
        position_links = position.links if position is not None else position_links
        if orientation_links is None:
            raise InputError("give the orientation targets' links (orientation_links, or an OrientationTask)")
        self.model, self.settings = model, settings
        self.position_links = tuple(position_links if position_links is not None else (model.base_link,))
        self.orientation_links = tuple(orientation_links)
        extra_limits = split_limits(constraints)
        self.tasks: tuple[Task, ...] = (orientation or OrientationTask(links=self.orientation_links),
                                        position or PositionTask(links=self.position_links)) + extra_tasks
        self.constraints: tuple[Limit, ...] = (JointLimits(), CoupledLimits()) + extra_limits
        self.structure = StepStructure.build(model, self.orientation_links, self.position_links, settings,
                                             extra_tasks, extra_limits)
        if settings.compile and (extra_tasks or extra_limits):
            warnings.warn("the captured step (compile=True) takes the paper's tasks and the model's limits only: "
                          "with other tasks or limits the tracker steps eagerly", stacklevel=2)
            self.settings = settings = dataclasses.replace(settings, compile=False)
        self._backends: dict[str, QPBackend] = {}
        self.backend = self._backend_for(1)
        self._history = SchemeHistory(settings.scheme, float(settings.dt))
        self._batch: BatchSetup | None = None
        self._state: State | None = None
        self._rotation: torch.Tensor | None = None
        self._captures: dict[int, CapturedStep] = {}  # per batch size, made at the first reset of that size
        self._captured: CapturedStep | None = None
        largest = float(torch.cat((self.structure.position_gain, self.structure.orientation_gain)).max()) * self.dt
        if largest >= SCHEMES[settings.scheme]:
            warnings.warn(f"K dt = {largest:.3g} is beyond the {settings.scheme} scheme's stability bound "
                          f"{SCHEMES[settings.scheme]}: the tracking error will grow; lower the gains or the time step",
                          stacklevel=2)

    @property
    def dt(self) -> float:
        """The nominal time step (s)."""
        return float(self.settings.dt)

    def _backend_for(self, batch: int) -> QPBackend:
        name = self.settings.backend
        if not isinstance(name, str):  # a configured QPBackend instance
            return name
        if name == "auto":
            name = "batched" if batch > 1 or self.model.device.type == "cuda" else "piqp"
        if name not in self._backends:
            self._backends[name] = make_backend(name)
        return self._backends[name]

    # ------------------------------------------------------------------ state
    def reset(self, state: State | None = None, batch: int = 1) -> State:
        """Start from `state` (default: the zero configuration, at rest) for `batch` subjects."""
        model = self.model
        if state is None:
            p, R, s = model.zero_configuration(batch)
            state = State(p, R, s, torch.zeros(batch, 6 + model.n_dof, dtype=p.dtype, device=p.device))
        B = state.base_position.shape[0]
        model.check_input("state.base_position", state.base_position, (B, 3))
        model.check_input("state.base_rotation", state.base_rotation, (B, 3, 3))
        model.check_input("state.joint_positions", state.joint_positions, (B, model.n_dof))
        model.check_input("state.velocity", state.velocity, (B, 6 + model.n_dof))
        self._state = state.clone()
        self._rotation = orthonormalize(self._state.base_rotation)
        self._history.reset(state.velocity)
        self.backend = self._backend_for(B)
        self._batch = BatchSetup.build(self.model, self.structure, self.settings, self.backend, B)
        self._no_restart = torch.zeros(B, dtype=torch.bool, device=state.base_position.device)
        self._captured = None
        self._steps = 0  # since this reset: the sample a step tracks, unless it is told
        for part in self.tasks + self.constraints:
            part.reset()
        if self.settings.compile:
            if B not in self._captures:
                self._captures[B] = CapturedStep(model, self.structure, self.settings, self._batch)
            self._captured = self._captures[B]
            # a replayed step's diagnostics that do not change: all solved, nothing dropped or projected
            self._usual = (~self._no_restart, self._no_restart.long())
        return self.state

    @property
    def state(self) -> State:
        """The current state, its base rotation orthonormalised (what leaves the library). The
        tracker replaces its state every step and never writes into it: these tensors stay valid."""
        s, rotation = self._require_state(), self._rotation
        assert rotation is not None  # set with the state
        return State(s.base_position, rotation, s.joint_positions, s.velocity)

    @property
    def captured(self) -> CapturedStep | None:
        """The captured step for the current batch size (with settings.compile; else None): its
        `compile_seconds` is how long the capture took (None before the first settled step), and
        `unavailable` is True where it could not be made here (the step then runs eagerly)."""
        return self._captured

    def _require_state(self) -> State:
        if self._state is None:
            raise InputError("call reset() before step()")
        return self._state

    # ------------------------------------------------------------------ the step
    @torch.inference_mode()  # no autograd bookkeeping: at small batches it is a fifth of the step
    def step(self, targets: Targets, dt: float | torch.Tensor | None = None,
             checked: bool = False, sample: int | None = None) -> tuple[State, StepDiagnostics]:
        """Advance by dt (default: the nominal dt; a scalar or [B]) towards `targets`.

        targets: Targets with n_p position and n_o orientation targets, batch B. checked: every
        target is known finite and every rotation orthonormal (`targets.clean_steps`, which a run
        applies to a whole sequence at once), so the step does not check them again. sample: the
        index of these targets in their sequence, for tasks and limits with inputs per sample (a
        contact's switch); default, the steps since `reset`.
        Returns the new State and the step's StepDiagnostics. Their tensors are inference tensors
        (torch.inference_mode): use them freely, but clone one before using it in autograd.
        """
        start = time.perf_counter()
        q, batch, structure, model = self._require_state(), self._batch, self.structure, self.model
        assert batch is not None and self._rotation is not None  # set with the state by reset()
        self._check_targets(targets, batch)
        sample = self._steps if sample is None else sample
        self._steps += 1
        if self._captured is not None and self._history.settled:
            replayed = self._captured(q, self._rotation, self._history, targets, dt)
            if replayed is not None:
                return self._commit(replayed, q, targets, start)
        dt = self._time_step(dt, batch.size)
        new_segment = self._no_restart
        if isinstance(dt, torch.Tensor):
            dt, new_segment = self._split_at_gaps(dt, targets)
            q = self._require_state()
        clean = clean_targets(targets, checked=checked)
        at = self._history.evaluate(q, self._rotation, clean, dt, positions=not structure.rotations_only)

        kinematics_start = time.perf_counter()
        kin = self._kinematics(q, at, batch)
        kinematics_time = time.perf_counter() - kinematics_start

        valid = None if clean.all_valid else (clean.position_valid, clean.orientation_valid)
        weights = (None, None) if valid is None else (valid[0].to(q.velocity.dtype), valid[1].to(q.velocity.dtype))
        context = StepContext(model, State(q.base_position, self._rotation, q.joint_positions, q.velocity), dt, sample) \
            if structure.tasks or structure.limits else None
        task = step_problem(model, structure, self.settings, batch, q.joint_positions, at, kin, dt, weights, context)
        problem = task.problem

        qp_start = time.perf_counter()
        solution = self.backend.solve(problem, warm_start=q.velocity)
        qp_time = time.perf_counter() - qp_start

        nu = solution.x
        failed = self._advance(q, nu, dt, targets)

        mnte, residual_norm = tracking_errors(at, kin, task, valid)
        diagnostics = StepDiagnostics(
            mnte=mnte,
            residual_norm=residual_norm,
            active_constraints=problem.active(nu),
            solved=solution.solved,
            dropped=clean.dropped,
            projected=clean.projected,
            failed=failed,
            new_segment=new_segment,
            step_time=time.perf_counter() - start,
            kinematics_time=kinematics_time,
            qp_time=qp_time,
        )
        return self.state, diagnostics

    def _advance(self, q: State, nu: torch.Tensor, dt: float | torch.Tensor, targets: Targets) -> torch.Tensor:
        """The state after dt at velocity nu, the history advanced, the invariant checked: the subjects
        that break it restart from `targets`. Returns the [B] bool of those (the shared all-False
        tensor when none does)."""
        p_next, R_next, s_next = integrate(q.base_position, q.base_rotation, q.joint_positions, nu, dt,
                                           self.settings.rotation_integrator, self.settings.baumgarte_gain)
        self._history.advance(nu, q.velocity, dt)
        self._state = State(p_next, R_next, s_next, nu)
        self._rotation = orthonormalize(R_next)
        failed = self._check_invariant(q)
        if failed is not self._no_restart:
            self._restart(failed, targets)
            self._history.forget(failed, previous=False)  # x_k, which it restarted from, stays
        return failed

    def _commit(self, replayed: Replayed, q: State, targets: Targets, start: float) -> tuple[State, StepDiagnostics]:
        """A captured step's results as the tracker's state, history and diagnostics (nothing dropped
        or projected). A usual step's are all there (its kinematics and QP not timed apart: NaN); a
        step with an active bound brings its QP, which the backend solves here, and the step ends as
        the eager one does (integration, invariant)."""
        self._history.push(replayed.targets)
        solved, none = self._usual
        failed, kinematics_time, qp_time = self._no_restart, math.nan, math.nan
        if replayed.problem is None:
            state, slope, active = replayed.state, replayed.slope, replayed.active_constraints
            assert state is not None and slope is not None and active is not None  # a usual step's
            self._state, self._rotation = state, replayed.rotation
            self._history.advance_to(slope, replayed.dt)
        else:
            qp_start = time.perf_counter()
            solution = self.backend.solve(replayed.problem, warm_start=q.velocity, start=replayed.start)
            qp_time = time.perf_counter() - qp_start
            failed, solved = self._advance(q, solution.x, replayed.dt, targets), solution.solved
            active = replayed.problem.active(solution.x)
        diagnostics = StepDiagnostics(replayed.mnte, replayed.residual_norm, active, solved, none, none, failed,
                                      self._no_restart, time.perf_counter() - start, kinematics_time, qp_time)
        return self.state, diagnostics

    def _check_invariant(self, before: State) -> torch.Tensor:
        """[B] bool: the subjects whose new state breaks the invariant (`invariant.py`); the shared
        all-False tensor when none does."""
        R = self._rotation
        assert R is not None  # set with the state
        broken = broken_subjects(self._require_state(), R, before.joint_positions, self.model.lower, self.model.upper)
        return self._no_restart if broken is None else broken

    def _split_at_gaps(self, dt: torch.Tensor, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        """dt [B,1] with the gaps longer than max_gap nominal steps replaced by the nominal step, the
        subjects they belong to restarted from `targets`; and the [B] bool of those subjects."""
        nominal = self._history.nominal_dt
        gap = dt[:, 0] > self.settings.max_gap * nominal  # [B]
        if not bool(gap.any()):
            return dt, self._no_restart
        self._restart(gap, targets)
        self._history.forget(gap, previous=True)  # the targets before the gap say nothing of those after
        return torch.where(gap[:, None], torch.full_like(dt, nominal), dt), gap

    def _restart(self, subjects: torch.Tensor, targets: Targets) -> None:
        """Subjects [B] bool start again from `initial_state(targets)`, at rest."""
        fresh, q = self.initial_state(targets), self._require_state()
        pick = lambda new, old: torch.where(subjects.view(-1, *(1,) * (old.dim() - 1)), new, old)  # noqa: E731
        self._state = State(*(pick(new, old) for new, old in zip(vars(fresh).values(), vars(q).values())))
        self._rotation = pick(fresh.base_rotation, self._rotation)

    def _kinematics(self, q: State, at: Evaluation, batch: BatchSetup) -> StepKinematics:
        R_B = self._rotation
        assert R_B is not None  # set with the state
        return step_kinematics(self.model, self.structure, batch, self.settings.scheme, q, R_B, at)

    def _check_targets(self, targets: Targets, batch: BatchSetup) -> None:
        """One comparison in the usual case; check_targets says what is wrong otherwise."""
        fields, model = vars(targets).values(), self.model
        if tuple(getattr(t, "shape", None) for t in fields) != batch.target_shapes or \
                any(t.dtype != model.dtype or t.device != model.device for t in fields):
            check_targets(targets, len(self.position_links), len(self.orientation_links), model.dtype, model.device,
                          batch.size)

    def _time_step(self, dt, B: int) -> torch.Tensor | float:
        """The step's dt: the nominal one (a float, the same object every step) or [B,1]."""
        if dt is None:
            return self._history.nominal_dt
        dt = torch.as_tensor(dt, dtype=self.model.dtype, device=self.model.device)
        if dt.dim() == 0:
            dt = dt.expand(B)
        if dt.shape != (B,) or not bool((dt > 0).all()) or not bool(torch.isfinite(dt).all()):
            raise InputError(f"dt: expected a positive scalar or [{B}] positive values, got {dt.tolist()}")
        return dt[:, None]

    def initial_state(self, targets: Targets) -> State:
        """The zero joint configuration at rest, with the base where the first targets put it: at the
        base link's position target and, when the base link has an orientation target, turned as it."""
        B = targets.batch
        p, R, s = self.model.zero_configuration(B)
        base = self.model.base_link
        if base in self.position_links:
            found = targets.position[:, self.position_links.index(base)]
            p = torch.where(torch.isfinite(found).all(-1, keepdim=True), found, p)
        if base in self.orientation_links:
            found = targets.rotation[:, self.orientation_links.index(base)]
            ok = torch.isfinite(found).flatten(-2).all(-1)[:, None, None]
            R = orthonormalize(torch.where(ok, found, R))
        return State(p.clone(), R.clone(), s, torch.zeros(B, 6 + self.model.n_dof, dtype=p.dtype, device=p.device))

    # ------------------------------------------------------------------ whole sequences
    def run(self, sequence: TargetSequence, initial: State | None = None, progress: bool | None = None,
            interruptible: bool = False, settle: float = 0.0) -> Trajectory:
        """Track a whole sequence from `initial` (default: `initial_state` of the first targets; with
        `settle` > 0 seconds, at rest in their posture: `sequence.settled_state`).

        Sample k of the result is the state after the step towards targets k. Steps at the nominal
        rate (to the rounding of the timestamps) take the nominal dt, others (jitter, gaps) their own.
        progress: a bar once the run has lasted a second (None: on runs of over 20 000
        subject-steps). interruptible: Ctrl-C stops the run between steps and the trajectory holds
        the steps done, with `interrupted` True (KeyboardInterrupt still rises before the first).
        """
        if len(sequence) == 0:
            raise InputError("the sequence is empty")
        return next(iter(run_parts(self, [sequence], sequence.time, initial, progress, interruptible, settle)))

    def run_parts(self, parts: Iterable[TargetSequence], time: torch.Tensor, initial: State | None = None,
                  progress: bool | None = None, interruptible: bool = False,
                  settle: float = 0.0) -> Generator[Trajectory, None, None]:
        """`run` over a sequence given a part at a time (time [T]: all its time stamps; parts: its
        targets, in order): yields each part's trajectory when done (`sequence.run_parts`)."""
        return run_parts(self, parts, time, initial, progress, interruptible, settle)


"""Dynamical inverse kinematics: one constrained velocity solve per time step.

Each step, for a batch of B subjects:

1. targets x_k (positions, rotations and their velocities) are cleaned: non-finite ones are
   dropped for the step, nearly orthonormal rotations projected;
2. kinematics at the evaluation configuration: link poses and the task Jacobian J;
3. residuals r (position p* - p, orientation R_hat sk(R_hat^T R*)^vee, world frame) and corrected
   velocities v* = v + K r;
4. the QP  min ||v* - J nu||^2 + lambda ||nu||^2  s.t. the velocity bounds of the joint limits
   (and A s_dot <= h for coupled limits);
5. integration of the configuration from nu over dt.

Two discretisations of the continuous law J nu = v + K r:

- 'midpoint' (default, second order): the residual compares the state q_{k-1} with the targets
  at the same instant t_{k-1}; the feed-forward velocity is the target's average velocity over
  the step (the integral of the quadratic through the last three samples, or the mean of two); the Jacobian is taken at the middle of the step,
  predicted from the previous velocities, which accounts for the curvature of the kinematics
  (with J(q_{k-1}) a chain of joints would leave an O(dt^2) error every step, a first-order
  scheme). Then q_k = q_{k-1} + dt nu_k. The error is O(dt^2 / K); stability: K dt < 2. It costs
  one kinematics call more than the paper's scheme, without Jacobians.
- 'paper' (the literal discrete law of the paper): J(q_{k-1}) nu_k = v(t_k) + K r(q_{k-1}, x(t_k)),
  q_k = q_{k-1} + dt nu_k. It lags by about dt v (first order). Stability: K dt < 2.

Diagnostics: mnte compares the state at the start of the step with the targets at that instant;
residual_norm is the residual the step used (against x(t_k) in the paper's scheme).
"""

from __future__ import annotations

import time
import warnings
from typing import Sequence

import torch

from . import so3
from ..errors import InputError
from .integrate import ROTATION_INTEGRATORS, integrate, orthonormalize
from .kinematics import KinematicModel, LinkKinematics
from .limits import LimitSettings, base_velocity_bounds, linear_limit_bounds, velocity_bounds
from .settings import SCHEMES
from .qp import BACKENDS, BatchedBackend, QPBackend, JointTree, QPProblem, TreeHessian, make_backend
from .residual import orientation_error, orientation_residual
from .state import State, StepDiagnostics, TargetSequence, Trajectory
from .targets import Targets, check_targets, clean_targets
from .task import TaskStructure, normal_equations



def _axpy(x: torch.Tensor, a: "float | torch.Tensor", y: torch.Tensor) -> torch.Tensor:
    """x + a y in one operation, a a float or a tensor that broadcasts ([B,1] for a jittered dt)."""
    return torch.addcmul(x, a, y) if isinstance(a, torch.Tensor) else torch.add(x, y, alpha=float(a))


class DynamicalIK:
    """The tracker. Build it once for a model and a set of targets, `reset`, then `step` or `run`.

    model: a KinematicModel (or a stack of subjects); orientation_links, position_links: the
    links the targets belong to (default: one position target on the base link).
    position_gain, orientation_gain: K per block, a scalar or one per target (1/s).
    dt: nominal time step (s); `step(..., dt=...)` may vary it (jittered timestamps).
    scheme: 'midpoint' (second order, default) or 'paper'; rotation_integrator: 'baumgarte' (rho:
    baumgarte_gain, 1/s) or 'exp'; damping: lambda; limits: LimitSettings; backend: 'piqp'
    (PIQP per subject), 'batched' (the whole batch in torch) or 'auto' (default: batched when
    B > 1 or on CUDA, else PIQP), or a configured QPBackend instance.
    """

    STACK_BELOW = 16  # batches up to this size evaluate both configurations of a step in one call
    TREE_FROM = 8  # from this batch size the batched backend solves with the tree structure, below densely

    def __init__(
        self,
        model: KinematicModel,
        orientation_links: Sequence[str],
        position_links: Sequence[str] | None = None,
        position_gain: float | torch.Tensor = 10.0,
        orientation_gain: float | torch.Tensor = 10.0,
        dt: float = 0.01,
        scheme: str = "midpoint",
        rotation_integrator: str = "baumgarte",
        baumgarte_gain: float = 100.0,
        damping: float = 1e-9,
        limits: LimitSettings = LimitSettings(),
        backend: "str | QPBackend" = "auto",
    ):
        if scheme not in SCHEMES:
            raise InputError(f"unknown scheme {scheme!r}; valid: {', '.join(SCHEMES)}")
        if rotation_integrator not in ROTATION_INTEGRATORS:
            raise InputError(f"unknown rotation integrator {rotation_integrator!r}; valid: {', '.join(ROTATION_INTEGRATORS)}")
        if dt <= 0:
            raise InputError(f"dt must be positive, got {dt}")
        self.model = model
        self.position_links = tuple(position_links if position_links is not None else (model.base_link,))
        self.orientation_links = tuple(orientation_links)
        links = tuple(dict.fromkeys(self.position_links + self.orientation_links))
        self._selection = model.select(links)  # raises UnknownLinkError for a bad name
        self._task = TaskStructure.build(model, self.orientation_links, self.position_links)
        # the paper's targets (orientations and the base's position) need only the links'
        # rotations and the joints' axes: no positions, no Jacobians
        self._rotations_only = self._task.position is None and len(self.orientation_links) > 0
        self._orientation_selection = model.select(self.orientation_links) if self.orientation_links else None
        index = {name: i for i, name in enumerate(links)}
        long = dict(dtype=torch.long, device=model.device)
        self._position_index = torch.tensor([index[n] for n in self.position_links], **long)
        self._orientation_index = torch.tensor([index[n] for n in self.orientation_links], **long)
        kw = dict(dtype=model.dtype, device=model.device)
        gains = []
        for name, gain, n in (("position_gain", position_gain, len(self.position_links)),
                              ("orientation_gain", orientation_gain, len(self.orientation_links))):
            gain = torch.as_tensor(gain, **kw)
            if gain.dim() > 1 or (gain.dim() == 1 and gain.shape[0] != n):
                raise InputError(f"{name}: give a scalar or one gain per target ({n}), got shape {list(gain.shape)}")
            gains.append(gain.expand(n).clone())
        self.position_gain, self.orientation_gain = gains
        self._position_gain, self._orientation_gain = (gain[:, None] for gain in gains)  # [n,1], against [B,n,3]
        self.dt, self.scheme, self.rotation_integrator = float(dt), scheme, rotation_integrator
        self.baumgarte_gain, self.damping, self.limits = float(baumgarte_gain), float(damping), limits
        if isinstance(backend, str) and backend != "auto" and backend not in BACKENDS:
            raise InputError(f"unknown QP backend {backend!r}; valid: auto, {', '.join(BACKENDS)}")
        self.backend_name, self._backends = backend, {}
        self.backend = self._backend_for(1)
        # The structured solve needs every position target on the base link (the base's linear
        # velocity is then its own block of H) and a joint to eliminate; otherwise the batched backend
        # works densely.
        self._tree = JointTree.build(model, self.orientation_links) \
            if set(self.position_links) <= {model.base_link} and model.n_dof > 0 else None
        bound = SCHEMES[scheme]
        largest = float(torch.cat((self.position_gain, self.orientation_gain)).max()) * self.dt
        if largest >= bound:
            warnings.warn(f"K dt = {largest:.3g} is beyond the {scheme} scheme's stability bound {bound}: "
                          f"the tracking error will grow; lower the gains or the time step", stacklevel=2)
        self._state: State | None = None

    def _backend_for(self, batch: int):
        name = self.backend_name
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
        if state is None:
            p, R, s = self.model.zero_configuration(batch)
            state = State(p, R, s, torch.zeros(batch, 6 + self.model.n_dof, dtype=p.dtype, device=p.device))
        B = state.base_position.shape[0]
        self.model.check_input("state.base_position", state.base_position, (B, 3))
        self.model.check_input("state.base_rotation", state.base_rotation, (B, 3, 3))
        self.model.check_input("state.joint_positions", state.joint_positions, (B, self.model.n_dof))
        self.model.check_input("state.velocity", state.velocity, (B, 6 + self.model.n_dof))
        self._state = state.clone()
        self._rotation = orthonormalize(self._state.base_rotation)
        self._previous = self._before = self._previous_valid = self._before_valid = None
        self._steps = 0
        kw = dict(dtype=state.velocity.dtype, device=state.velocity.device)
        self._nominal_dt = self.dt  # a float: arithmetic with it costs no tensor operation
        self._last_dt = self._nominal_dt
        self._velocity_slope = torch.zeros_like(state.velocity)
        self._base_bounds = base_velocity_bounds(B, self.limits, **kw)
        self.backend = self._backend_for(B)
        self._structured = self._tree is not None and isinstance(self.backend, BatchedBackend) and B >= self.TREE_FROM
        A = None if self.model.linear_limits is None else self.model.linear_limits.A
        # G [B,m,6+n] of the coupled limits A s_dot <= h: the base's columns are zero
        self._linear_rows = None if A is None else torch.cat((A.new_zeros(A.shape[0], 6), A), dim=1).expand(B, -1, -1)
        self._stacked = B <= self.STACK_BELOW and self.model.n_subjects == 1
        rows = 2 * B if self._stacked and self.scheme == "midpoint" else B
        self._target_shapes = ((B, len(self.position_links), 3), (B, len(self.position_links), 3),
                               (B, len(self.orientation_links), 3, 3), (B, len(self.orientation_links), 3))
        self._buffers = None if self._rotations_only else \
            self.model.empty_output(rows, self._selection, self._task.position is not None, self._task.position)
        return self.state

    @property
    def state(self) -> State:
        """The current state, its base rotation orthonormalised (what leaves the library). The
        tracker replaces its state every step and never writes into it: these tensors stay valid."""
        s = self._require_state()
        return State(s.base_position, self._rotation, s.joint_positions, s.velocity)

    def _require_state(self) -> State:
        if self._state is None:
            raise InputError("call reset() before step()")
        return self._state

    # ------------------------------------------------------------------ the step
    @torch.inference_mode()  # no autograd bookkeeping: at small batches it is a fifth of the step
    def step(self, targets: Targets, dt: float | torch.Tensor | None = None) -> tuple[State, StepDiagnostics]:
        """Advance by dt (default: the nominal dt; a scalar or [B]) towards `targets`.

        targets: Targets with n_p position and n_o orientation targets, batch B.
        Returns the new State and the step's StepDiagnostics. Their tensors are inference tensors
        (torch.inference_mode): use them freely, but clone one before using it in autograd.
        """
        start = time.perf_counter()
        q = self._require_state()
        B, model = q.base_position.shape[0], self.model
        fields = vars(targets).values()
        if tuple(getattr(t, "shape", None) for t in fields) != self._target_shapes or \
                any(t.dtype != model.dtype or t.device != model.device for t in fields):  # then says what is wrong
            check_targets(targets, len(self.position_links), len(self.orientation_links), model.dtype, model.device, B)
        dt = self._time_step(dt, B)
        clean = clean_targets(targets)
        x = clean.targets

        # The residual compares the state with the targets at the same instant: t_{k-1} (midpoint
        # scheme) or, literally as in the paper, q_{k-1} with x(t_k).
        previous, before = self._history(x, clean)
        R_B = self._rotation
        kinematics_start = time.perf_counter()
        if self.scheme == "midpoint":
            # the Jacobian at mid-step: q + dt/2 times the velocity at the step's first quarter,
            # extrapolated from the last two steps' velocities (each taken at its own midpoint)
            half = 0.5 * dt
            nu_ahead = _axpy(q.velocity, 0.5 * self._last_dt + 0.25 * dt, self._velocity_slope)
            R_mid = so3.exp(half * nu_ahead[:, 3:6]) @ R_B
            s_mid = _axpy(q.joint_positions, half, nu_ahead[:, 6:])
            p_mid = None if self._rotations_only else _axpy(q.base_position, half, nu_ahead[:, :3])
            x_r = previous
            v_p, v_o = self._mean_velocity(before, previous, x, dt)
        else:
            p_mid, R_mid, s_mid = q.base_position, R_B, q.joint_positions
            x_r, v_p, v_o = x, x.linear_velocity, x.angular_velocity
        R_hat, p_hat, joint_axes, J_p = self._kinematics(q, R_B, p_mid, R_mid, s_mid)
        kinematics_time = time.perf_counter() - kinematics_start
        r_p = x_r.position - p_hat
        r_o = orientation_residual(x_r.rotation, R_hat)
        weights = (None, None) if clean.all_valid else (clean.position_valid.to(q.velocity.dtype),
                                                        clean.orientation_valid.to(q.velocity.dtype))
        H, g = normal_equations(self._task, joint_axes, J_p,
                                torch.addcmul(v_p, self._position_gain, r_p), torch.addcmul(v_o, self._orientation_gain, r_o),
                                self.damping, *weights, hessian=not self._structured)
        tree = TreeHessian.from_targets(self._tree, joint_axes, self.damping, len(self.position_links),
                                        weights[1], weights[0]) if self._structured else None
        lb, ub = velocity_bounds(q.joint_positions, model.lower, model.upper, self.limits, dt, self._base_bounds)
        G, h = self._linear_rows, None
        if G is not None:
            h = linear_limit_bounds(q.joint_positions, model.linear_limits.A, model.linear_limits.b, self.limits, dt)
        problem = QPProblem(H, g, lb, ub, G, h, tree)
        qp_start = time.perf_counter()
        solution = self.backend.solve(problem, warm_start=q.velocity)
        qp_time = time.perf_counter() - qp_start
        nu = solution.x

        p_next, R_next, s_next = integrate(q.base_position, q.base_rotation, q.joint_positions, nu, dt,
                                           self.rotation_integrator, self.baumgarte_gain)
        # d(nu)/dt between this step's midpoint and the last one's, for the next prediction
        self._velocity_slope = (nu - q.velocity) / (0.5 * (dt + self._last_dt)) if self._steps else torch.zeros_like(nu)
        self._last_dt = dt
        self._steps += 1
        self._state = State(p_next, R_next, s_next, nu)
        self._rotation = orthonormalize(R_next)

        residual_norm = torch.linalg.vector_norm(torch.cat((r_p, r_o), dim=1), dim=-1)  # [B,n_p+n_o]
        diagnostics = StepDiagnostics(
            mnte=orientation_error(previous.rotation, R_hat).mean(-1) if clean.all_valid
            else self._mean_over_valid(orientation_error(previous.rotation, R_hat), clean.orientation_valid),
            residual_norm=residual_norm if clean.all_valid else
            residual_norm * torch.cat((clean.position_valid, clean.orientation_valid), dim=1),
            active_constraints=self._active(problem, nu),
            solved=solution.solved,
            dropped=clean.dropped,
            projected=clean.projected,
            step_time=time.perf_counter() - start,
            kinematics_time=kinematics_time,
            qp_time=qp_time,
        )
        return self.state, diagnostics

    def _kinematics(self, q: State, R_B: torch.Tensor, p_mid: torch.Tensor | None, R_mid: torch.Tensor,
                    s_mid: torch.Tensor):
        """What the step needs of the kinematics: the orientation targets' links' rotations R_hat
        [B,n_o,3,3] and the position targets' links' positions p_hat [B,n_p,3] (or [B,1,3]) at the
        state (q, R_B); the joints' world axes [B,n,3] and the Jacobians of the position links off
        the base (or None) at (p_mid, R_mid, s_mid), the same configuration in the paper's scheme.
        p_mid: None when every position target is on the base link; p_hat is then the base position
        [B,1,3], which broadcasts against every position target."""
        B, model = q.base_position.shape[0], self.model
        # small batches cost per operation, not per row: both configurations go in one call
        stacked = self.scheme == "midpoint" and self._stacked
        if self._rotations_only:  # orientation targets and the base's position: no positions, no Jacobians
            p_hat = q.base_position.unsqueeze(1)
            if self.scheme == "paper":
                now = model.rotations(R_B, q.joint_positions, self._orientation_selection, joint_axes=True)
                return now.rotation, p_hat, now.joint_axes, None
            if stacked:
                both = model.rotations(torch.cat((R_B, R_mid)), torch.cat((q.joint_positions, s_mid)),
                                       self._orientation_selection, joint_axes=True)
                return both.rotation[:B], p_hat, both.joint_axes[B:], None
            return (model.rotations(R_B, q.joint_positions, self._orientation_selection).rotation, p_hat,
                    model.rotations(R_mid, s_mid, self._orientation_selection, joint_axes=True).joint_axes, None)
        # position targets off the base need link positions and their Jacobians
        task = dict(jacobian=self._task.position is not None, jacobian_links=self._task.position, joint_axes=True)
        if self.scheme == "paper":
            now = mid = model(q.base_position, R_B, q.joint_positions, self._selection, out=self._buffers, **task)
        elif stacked:
            both = model(torch.cat((q.base_position, p_mid)), torch.cat((R_B, R_mid)),
                         torch.cat((q.joint_positions, s_mid)), self._selection, out=self._buffers, **task)
            now = LinkKinematics(both.rotation[:B], both.position[:B], None)
            mid = LinkKinematics(None, None, None if both.jacobian is None else both.jacobian[B:], both.joint_axes[B:])
        else:
            now = model(q.base_position, R_B, q.joint_positions, self._selection, jacobian=False)
            mid = model(p_mid, R_mid, s_mid, self._selection, out=self._buffers, **task)
        return (now.rotation.index_select(1, self._orientation_index), now.position.index_select(1, self._position_index),
                mid.joint_axes, mid.jacobian)

    def _history(self, x: Targets, clean) -> tuple[Targets, Targets | None]:
        """The targets one and two steps back, a dropped (non-finite) one replaced by the current;
        then remember the current ones."""
        valid = None if clean.all_valid else (clean.position_valid, clean.orientation_valid)
        if self._previous is None:
            previous, before = x, None
        else:
            previous = self._substitute(self._previous, self._previous_valid, x)
            before = None if self._before is None else self._substitute(self._before, self._before_valid, x)
        self._before, self._before_valid = self._previous, self._previous_valid
        # copies: a caller may refill the same target tensors in place every step
        self._previous, self._previous_valid = Targets(*(v.clone() for v in vars(x).values())), valid
        return previous, before

    @staticmethod
    def _substitute(old: Targets, old_valid, current: Targets) -> Targets:
        if old_valid is None:  # nothing was dropped
            return old
        p_ok, o_ok = old_valid
        pick_p = lambda a, b: torch.where(p_ok[..., None], a, b)  # noqa: E731
        pick_o = lambda a, b: torch.where(o_ok.view(o_ok.shape + (1,) * (a.dim() - 2)), a, b)  # noqa: E731
        return Targets(pick_p(old.position, current.position), pick_p(old.linear_velocity, current.linear_velocity),
                       pick_o(old.rotation, current.rotation), pick_o(old.angular_velocity, current.angular_velocity))

    def _mean_velocity(self, before: Targets | None, previous: Targets, current: Targets, dt: torch.Tensor):
        """The average target velocity over [t_{k-1}, t_k]: the integral of the quadratic through the
        last three samples (weights -1/12, 8/12, 5/12 for even steps), or the trapezoid rule while
        there are only two. Returns linear [B,n_p,3] and angular [B,n_o,3] velocities."""
        if before is None:
            w_before, w_now = 0.0, 0.5
        elif dt is self._nominal_dt and self._last_dt is self._nominal_dt:
            w_before, w_now = -1.0 / 12.0, 5.0 / 12.0
        else:
            h1, h = self._last_dt, dt
            w_before = (-h * h / (6.0 * h1 * (h1 + h)))[:, :, None]  # [B,1,1]
            w_now = ((h / 3.0 + h1 / 2.0) / (h + h1))[:, :, None]
        w_prev = 1.0 - w_now - w_before

        def mean(name: str) -> torch.Tensor:
            v = _axpy(w_prev * getattr(previous, name), w_now, getattr(current, name))
            return v if before is None else _axpy(v, w_before, getattr(before, name))

        return mean("linear_velocity"), mean("angular_velocity")

    def _time_step(self, dt, B: int) -> torch.Tensor | float:
        """The step's dt: the nominal one (a float) or [B,1]."""
        if dt is None:
            return self._nominal_dt
        kw = dict(dtype=self.model.dtype, device=self.model.device)
        dt = torch.as_tensor(dt, **kw)
        if dt.dim() == 0:
            dt = dt.expand(B)
        if dt.shape != (B,) or not bool((dt > 0).all()) or not bool(torch.isfinite(dt).all()):
            raise InputError(f"dt: expected a positive scalar or [{B}] positive values, got {dt.tolist()}")
        return dt[:, None]

    @staticmethod
    def _mean_over_valid(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        weight = valid.to(values.dtype)
        return (values * weight).sum(-1) / weight.sum(-1).clamp(min=1.0)

    @staticmethod
    def _active(problem: QPProblem, x: torch.Tensor, tolerance: float = 1e-9) -> torch.Tensor:
        """[B] bounds (lower or upper) and linear limits that the solution touches (infinite ones never)."""
        count = ((x <= problem.lb + tolerance) | (x >= problem.ub - tolerance)).sum(-1)
        if problem.G is not None:
            count = count + ((problem.G @ x.unsqueeze(-1)).squeeze(-1) >= problem.h - tolerance).sum(-1)
        return count

    def initial_state(self, targets: Targets) -> State:
        """The zero joint configuration at rest, with the base where the first targets put it: at the
        base link's position target and, when the base link has an orientation target, turned as it."""
        B = targets.rotation.shape[0] if targets.rotation.numel() else targets.position.shape[0]
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
    def run(self, sequence: TargetSequence, initial: State | None = None, progress: bool | None = None) -> Trajectory:
        """Track a whole sequence from `initial` (default: `initial_state` of the first targets). Sample k of the result
        is the state after the step towards targets k; the first step uses the nominal dt, later
        ones the timestamps' differences. A progress bar shows on runs longer than a few seconds."""
        T = len(sequence)
        if T == 0:
            raise InputError("the sequence is empty")
        time_ = sequence.time
        if T > 1 and not bool((time_[1:] > time_[:-1]).all()):
            raise InputError("sequence.time must be strictly increasing")
        B = sequence.rotation.shape[1] if sequence.rotation.numel() else sequence.position.shape[1]
        self.reset(initial if initial is not None else self.initial_state(sequence[0]), batch=B)
        steps = range(T)
        if progress is None:
            progress = T * B > 20000
        if progress:
            from tqdm import tqdm

            steps = tqdm(steps, desc="tracking", unit="step", leave=False)
        # Steps at the nominal rate (to the rounding of the timestamps) take the nominal dt, a float
        # the step uses without checks or tensor arithmetic; others (jitter, gaps) their own gap.
        gaps = (time_[1:] - time_[:-1]).to(self.model.dtype)
        rounding = 64 * torch.finfo(time_.dtype).eps * float(time_.abs().max()) if T > 1 else 0.0
        nominal = [True] + ((gaps - self.dt).abs() <= rounding).tolist()
        gaps = gaps.to(self.model.device)[:, None].expand(-1, B)
        states, diags = [], []
        for k in steps:
            dt = None if nominal[k] else gaps[k - 1]
            state, diag = self.step(sequence[k], dt)
            states.append(state)
            diags.append(diag)
        stack = lambda name: torch.stack([getattr(s, name) for s in states])  # noqa: E731
        diagnostics = {name: torch.stack([getattr(d, name) for d in diags])
                       for name in ("mnte", "residual_norm", "active_constraints", "solved", "dropped", "projected")}
        for name in ("step_time", "kinematics_time", "qp_time"):
            diagnostics[name] = torch.tensor([getattr(d, name) for d in diags], dtype=torch.float64)
        return Trajectory(time_, stack("base_position"), stack("base_rotation"), stack("joint_positions"),
                          stack("velocity"), diagnostics)

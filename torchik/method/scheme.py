"""The two discretisations of the continuous law J nu = v + K r, and the history the first needs.

- 'midpoint' (default, second order): the residual compares the state q_{k-1} with the targets
  at the same instant t_{k-1}; the feed-forward velocity is the targets' average velocity over
  the step (the integral of the quadratic through the last three samples, or the mean of two);
  the Jacobian is taken at the middle of the step, predicted from the previous velocities, which
  accounts for the curvature of the kinematics (with J(q_{k-1}) a chain of joints would leave an
  O(dt^2) error every step, a first-order scheme). Then q_k = q_{k-1} + dt nu_k. The error is
  O(dt^2 / K); stability: K dt < 2. It costs one kinematics call more than the paper's scheme,
  without Jacobians.
- 'paper' (the literal discrete law of the paper): J(q_{k-1}) nu_k = v(t_k) + K r(q_{k-1}, x(t_k)),
  q_k = q_{k-1} + dt nu_k. It lags by about dt v (first order). Stability: K dt < 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from . import so3
from .state import State
from .targets import CleanTargets, Targets


def axpy(x: torch.Tensor, a: "float | torch.Tensor", y: torch.Tensor) -> torch.Tensor:
    """x + a y in one operation, a a float or a tensor that broadcasts ([B,1] for a jittered dt)."""
    return torch.addcmul(x, a, y) if isinstance(a, torch.Tensor) else torch.add(x, y, alpha=float(a))


@dataclass(frozen=True)
class Evaluation:
    """What one step compares, and where it linearises.

    residual_targets: the targets the residual is taken against (x_{k-1} in the midpoint scheme,
    x_k in the paper's); start_targets: the targets at the step's start, x_{k-1} (what the step's
    MNTE compares the state with); linear_velocity [B,n_p,3], angular_velocity [B,n_o,3]: the
    feed-forward velocities; base_position [B,3] (None when the step needs no positions),
    base_rotation [B,3,3], joint_positions [B,n]: the configuration the Jacobian is taken at.
    """

    residual_targets: Targets
    start_targets: Targets
    linear_velocity: torch.Tensor
    angular_velocity: torch.Tensor
    base_position: torch.Tensor | None
    base_rotation: torch.Tensor
    joint_positions: torch.Tensor


class SchemeHistory:
    """A discretisation and what it remembers between steps: the targets one and two steps back
    (a dropped one replaced by the current), the last dt, and the slope of nu between the last two
    steps' midpoints, from which the midpoint scheme predicts its mid-step configuration."""

    def __init__(self, scheme: str, nominal_dt: float):
        self.scheme, self.nominal_dt = scheme, nominal_dt
        self.reset(None)

    def reset(self, velocity: torch.Tensor | None) -> None:
        """Forget every step; velocity [B,6+n]: the state's, for the slope's shape."""
        self._previous: Targets | None = None
        self._before: Targets | None = None
        self._previous_valid: tuple[torch.Tensor, torch.Tensor] | None = None
        self._before_valid: tuple[torch.Tensor, torch.Tensor] | None = None
        self.steps = 0
        self.last_dt: float | torch.Tensor = self.nominal_dt
        self.velocity_slope = torch.zeros(0) if velocity is None else torch.zeros_like(velocity)

    def forget(self, subjects: torch.Tensor, previous: bool) -> None:
        """Subjects [B] bool restarted: their velocity slope is zero and the targets two steps back
        (and one step back too, with `previous`) are replaced by the next ones, as dropped targets are."""
        self.velocity_slope = None if self.velocity_slope is None else \
            torch.where(subjects[:, None], 0.0, self.velocity_slope)
        if previous and self._previous is not None:
            self._previous_valid = _keep_valid(self._previous_valid, self._previous, subjects)
        if self._before is not None:
            self._before_valid = _keep_valid(self._before_valid, self._before, subjects)

    def evaluate(self, q: State, R_B: torch.Tensor, clean: CleanTargets, dt: "float | torch.Tensor",
                 positions: bool) -> Evaluation:
        """The step's Evaluation from the state q (base rotation R_B orthonormalised), the cleaned
        targets x_k and dt (a float, or [B,1]); positions: whether the kinematics needs the base
        position (targets off the base link). Remembers x_k for the next steps."""
        x = clean.targets
        previous, before = self._remember(x, clean)
        return evaluation(self.scheme, q, R_B, x, previous, before, dt, self.last_dt, self.velocity_slope, positions,
                          nominal=dt is self.nominal_dt and self.last_dt is self.nominal_dt)

    @property
    def settled(self) -> bool:
        """Two steps taken and no dropped target remembered: the next step's evaluation is the usual
        one (`evaluation` with every input a tensor), which a captured step replays."""
        return self.steps >= 2 and self._previous_valid is None and self._before_valid is None

    def remembered(self) -> tuple[Targets, Targets]:
        """The targets one and two steps back (`settled` histories hold both)."""
        assert self._previous is not None and self._before is not None, "a settled history"
        return self._previous, self._before

    def push(self, x: Targets) -> None:
        """Remember the targets of a step that skipped `evaluate` (a captured one, on a settled
        history): x all valid, a copy the caller will not write."""
        self._before, self._before_valid = self._previous, self._previous_valid
        self._previous, self._previous_valid = x, None

    def advance_to(self, slope: torch.Tensor, dt: "float | torch.Tensor") -> None:
        """`advance` with the next velocity slope computed elsewhere (by a captured step)."""
        self.velocity_slope, self.last_dt = slope, dt
        self.steps += 1

    def advance(self, nu: torch.Tensor, velocity_before: torch.Tensor, dt: "float | torch.Tensor") -> None:
        """After the step: nu [B,6+n] its solution, velocity_before [B,6+n] the previous one."""
        # d(nu)/dt between this step's midpoint and the last one's, for the next prediction
        self.velocity_slope = (nu - velocity_before) / (0.5 * (dt + self.last_dt)) if self.steps else torch.zeros_like(nu)
        self.last_dt = dt
        self.steps += 1

    def _remember(self, x: Targets, clean: CleanTargets) -> tuple[Targets, Targets | None]:
        """The targets one and two steps back, a dropped (non-finite) one replaced by the current;
        then remember the current ones."""
        valid = None if clean.all_valid else (clean.position_valid, clean.orientation_valid)
        if self._previous is None:
            previous, before = x, None
        else:
            previous = _substitute(self._previous, self._previous_valid, x)
            before = None if self._before is None else _substitute(self._before, self._before_valid, x)
        self._before, self._before_valid = self._previous, self._previous_valid
        # copies: a caller may refill the same target tensors in place every step
        self._previous, self._previous_valid = Targets(*(v.clone() for v in vars(x).values())), valid
        return previous, before


def evaluation(scheme: str, q: State, R_B: torch.Tensor, x: Targets, previous: Targets, before: Targets | None,
               dt: "float | torch.Tensor", last_dt: "float | torch.Tensor", velocity_slope: torch.Tensor,
               positions: bool, nominal: bool = False) -> Evaluation:
    """The step's Evaluation (see `SchemeHistory`): x the targets x_k, previous x_{k-1} and before
    x_{k-2} (None while there is none); dt, last_dt floats or [B,1]; velocity_slope [B,6+n];
    nominal: dt and last_dt are the nominal step (the mean velocity's weights are then constants)."""
    if scheme == "paper":
        return Evaluation(x, previous, x.linear_velocity, x.angular_velocity, q.base_position, R_B, q.joint_positions)
    # the Jacobian at mid-step: q + dt/2 times the velocity at the step's first quarter,
    # extrapolated from the last two steps' velocities (each taken at its own midpoint)
    half = 0.5 * dt
    nu_ahead = axpy(q.velocity, 0.5 * last_dt + 0.25 * dt, velocity_slope)
    R_mid = so3.exp(half * nu_ahead[:, 3:6]) @ R_B
    s_mid = axpy(q.joint_positions, half, nu_ahead[:, 6:])
    p_mid = axpy(q.base_position, half, nu_ahead[:, :3]) if positions else None
    v_p, v_o = mean_velocity(before, previous, x, dt, last_dt, nominal)
    return Evaluation(previous, previous, v_p, v_o, p_mid, R_mid, s_mid)


def mean_velocity(before: Targets | None, previous: Targets, current: Targets, dt, last_dt, nominal: bool):
    """The average target velocity over [t_{k-1}, t_k]: the integral of the quadratic through the
    last three samples (weights -1/12, 8/12, 5/12 for even steps), or the trapezoid rule while
    there are only two. Returns linear [B,n_p,3] and angular [B,n_o,3] velocities."""
    w_before: float | torch.Tensor
    w_now: float | torch.Tensor
    if before is None:
        w_before, w_now = 0.0, 0.5
    elif nominal:
        w_before, w_now = -1.0 / 12.0, 5.0 / 12.0
    else:
        h1, h = last_dt, dt
        w_before = -h * h / (6.0 * h1 * (h1 + h))
        w_now = (h / 3.0 + h1 / 2.0) / (h + h1)
        if isinstance(w_before, torch.Tensor) and isinstance(w_now, torch.Tensor):  # [B,1] -> [B,1,1], against [B,n,3]
            w_before, w_now = w_before[:, :, None], w_now[:, :, None]
    w_prev = 1.0 - w_now - w_before

    def mean(name: str) -> torch.Tensor:
        v = axpy(w_prev * getattr(previous, name), w_now, getattr(current, name))
        return v if before is None else axpy(v, w_before, getattr(before, name))

    return mean("linear_velocity"), mean("angular_velocity")


def _keep_valid(valid, targets: Targets, dropped: torch.Tensor):
    """The (position [B,n_p], orientation [B,n_o]) validity of remembered `targets` with every target
    of the dropped [B] subjects marked invalid."""
    if valid is None:
        valid = (torch.ones(targets.position.shape[:2], dtype=torch.bool, device=dropped.device),
                 torch.ones(targets.rotation.shape[:2], dtype=torch.bool, device=dropped.device))
    return tuple(v & ~dropped[:, None] for v in valid)


def _substitute(old: Targets, old_valid, current: Targets) -> Targets:
    """`old` with its dropped targets replaced by `current`'s."""
    if old_valid is None:  # nothing was dropped
        return old
    p_ok, o_ok = old_valid
    pick_p = lambda a, b: torch.where(p_ok[..., None], a, b)  # noqa: E731
    pick_o = lambda a, b: torch.where(o_ok.view(o_ok.shape + (1,) * (a.dim() - 2)), a, b)  # noqa: E731
    return Targets(pick_p(old.position, current.position), pick_p(old.linear_velocity, current.linear_velocity),
                   pick_o(old.rotation, current.rotation), pick_o(old.angular_velocity, current.angular_velocity))

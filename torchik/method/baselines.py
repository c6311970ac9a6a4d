"""Instantaneous inverse kinematics: the paper's comparison methods, batched like the tracker.

Both solve, at each time step and from the previous step's solution, for the configuration that
best matches the targets, iterating constrained Gauss-Newton steps to convergence; each step is a
QP with the tracker's backend (the same normal equations, the same limits).

`WholeBodyIK`: min ||K_r r(q)||^2 over the whole configuration subject to the joint limits
(K_r = I: with one gain for every target, as the experiments use, the weighting is a scale and
leaves the minimiser where it is). Each iteration linearises r(q + delta) ~ r - J delta and solves

    min ||r - J delta||^2 + lambda ||delta||^2   s.t.  s_min - s <= delta_s <= s_max - s,
                                                       A delta_s <= b - A s,

then q <- q (+) delta (the base rotation through the exponential map). The bounds are the
limits themselves: an iterate is always within them, and a start outside them is brought inside
by the first step. With r the paper's residual (sin(angle) u in the world frame), -J^T r is the
gradient of sum_i (1 - cos angle_i): the fixed points are the MNTE's own stationary points.
(The paper used IPOPT; Gauss-Newton with the same QP is the fair counterpart here.)

`PairwiseIK`: the model split into one subproblem per pair of adjacent targets (a target link and
its nearest target ancestor) over the joints between them: match the child's orientation relative
to its parent's, R_P^T R_C = R*_P^T R*_C. The pairs share no joint, and a pair's relative rotation
depends on its own joints only, so the subproblems are independent: all pairs of all subjects are
stacked as one batch of small QPs [B*P, k] (k: the most joints a pair has), and one kinematics
call per iteration evaluates every pair's chain at once. The base pose is the base target's;
assembling the pairs' joints gives the whole configuration.

Each subject (or pair) stops at a residual tolerance, when its increments fall below a step
tolerance (a least-squares optimum of unreachable targets, or a limit), or at an iteration cap.
Non-finite targets are dropped for the instant, as the tracker does: they weigh nothing in the
whole-body fit; a pair with a dropped end keeps its joints; a dropped base target keeps the base.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import torch

from ..errors import InputError
from . import so3
from .kinematics import KinematicModel
from .metrics import orientation_error
from .qp import QPProblem, make_backend
from .residual import orientation_residual
from .state import State, TargetSequence, Trajectory
from .target_equations import TargetStructure, normal_equations
from .targets import Targets, clean_targets


@dataclass(frozen=True)
class IKResult:
    """One instant's solve: state (its velocity zero: instantaneous IK gives configurations);
    iterations [B]; converged [B] (every residual below the tolerance); mnte [B] at the solution
    (mean over the targets used); solve_time (seconds, whole batch, iterations and all)."""

    state: State
    iterations: torch.Tensor
    converged: torch.Tensor
    mnte: torch.Tensor
    solve_time: float


def _mean_over(values: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
    """Mean of values [B,n] over the last axis, counting only `valid` [B,n] entries (None: all)."""
    if valid is None:
        return values.mean(-1)
    weight = valid.to(values.dtype)
    return (values * weight).sum(-1) / weight.sum(-1).clamp(min=1.0)


def central_velocity(time_: torch.Tensor, base_position: torch.Tensor, base_rotation: torch.Tensor,
                     joint_positions: torch.Tensor) -> torch.Tensor:
    """nu [T,B,6+n] of a sampled configuration trajectory by central differences (one-sided at the
    ends): base linear velocity, world angular velocity log(R_{k+1} R_{k-1}^T) / (t_{k+1} - t_{k-1}),
    joint rates. time_ [T]; base_position [T,B,3]; base_rotation [T,B,3,3]; joint_positions [T,B,n].
    What instantaneous IK offers as velocities: it solves for configurations only."""
    T = time_.shape[0]
    if T < 2:
        return torch.zeros(base_position.shape[:2] + (6 + joint_positions.shape[-1],), dtype=base_position.dtype,
                           device=base_position.device)
    ahead = torch.cat((torch.arange(1, T), torch.tensor([T - 1]))).to(time_.device)
    behind = torch.cat((torch.tensor([0]), torch.arange(0, T - 1))).to(time_.device)
    span = (time_[ahead] - time_[behind])[:, None, None]  # [T,1,1]
    linear = (base_position[ahead] - base_position[behind]) / span
    angular = so3.log(base_rotation[ahead] @ base_rotation[behind].transpose(-1, -2)) / span
    rates = (joint_positions[ahead] - joint_positions[behind]) / span
    return torch.cat((linear, angular, rates), -1)


class InstantaneousIK:
    """What both baselines share: `solve` one instant, `run` a sequence warm-started step to step."""

    model: KinematicModel
    orientation_links: tuple[str, ...]

    def solve(self, targets: Targets, start: State) -> IKResult:
        raise NotImplementedError

    def run(self, sequence: TargetSequence, initial: State, progress: bool = False) -> Trajectory:
        """Solve every instant of `sequence` [T,B,...], each from the previous solution (the first from
        `initial`). Returns a Trajectory whose velocity [T,B,6+n] is the central difference of the
        solutions (see `central_velocity`), with diagnostics mnte [T,B], iterations [T,B],
        converged [T,B], step_time [T] (s, whole batch: every iteration of the instant)."""
        steps = range(len(sequence))
        if progress:
            from tqdm import tqdm

            steps = tqdm(steps, desc=type(self).__name__, unit="step", leave=False)
        state, results = initial, []
        for k in steps:  # time steps (the method), not links or subjects
            result = self.solve(sequence[k], state)
            state = result.state
            results.append(result)
        stack = lambda name: torch.stack([getattr(r.state, name) for r in results])  # noqa: E731
        p, R, s = stack("base_position"), stack("base_rotation"), stack("joint_positions")
        diagnostics = {name: torch.stack([getattr(r, name) for r in results])
                       for name in ("mnte", "iterations", "converged")}
        diagnostics["step_time"] = torch.tensor([r.solve_time for r in results], dtype=torch.float64)
        return Trajectory(sequence.time, p, R, s, central_velocity(sequence.time, p, R, s), diagnostics)


def _increment_bounds(s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounds on an increment of s [...,n] that land it within [lower, upper] [...,n]."""
    return lower - s, upper - s


class WholeBodyIK(InstantaneousIK):
    """Iterate-to-convergence IK of all targets at once.

    tolerance: converged when the largest residual norm (m, or sin of the angle) is below it
    (default 1e-10); step_tolerance: stop when the largest increment (m, rad) is below it (default
    1e-6: a stationary point, the least-squares fit of unreachable targets; on large residuals
    Gauss-Newton converges linearly, and 1e-9 would cost half as many iterations again for an MNTE
    equal to 7 digits); max_iterations: the cap (default 50); damping: lambda of the step's QP;
    backend: the QP backend's name ('batched' or 'piqp').
    """

    def __init__(self, model: KinematicModel, orientation_links, position_links=None, tolerance: float = 1e-10,
                 max_iterations: int = 50, damping: float = 1e-9, backend: str = "batched", step_tolerance: float = 1e-6):
        self.model = model
        self.position_links = tuple(position_links if position_links is not None else (model.base_link,))
        self.orientation_links = tuple(orientation_links)
        links = tuple(dict.fromkeys(self.position_links + self.orientation_links))
        self._selection = model.select(links)
        index = {name: i for i, name in enumerate(links)}
        long: dict[str, Any] = dict(dtype=torch.long, device=model.device)
        self._p = torch.tensor([index[n] for n in self.position_links], **long)
        self._o = torch.tensor([index[n] for n in self.orientation_links], **long)
        self._task = TargetStructure.build(model, self.orientation_links, self.position_links)
        # as in the tracker: with every position target on the base, rotations and joint axes suffice
        self._rotations_only = self._task.position is None and len(self.orientation_links) > 0
        self._orientation_selection = model.select(self.orientation_links) if self.orientation_links else None
        self.tolerance, self.step_tolerance = tolerance, step_tolerance
        self.max_iterations, self.damping = max_iterations, damping
        self.backend = make_backend(backend)

    @torch.inference_mode()
    def solve(self, targets: Targets, start: State) -> IKResult:
        """Solve for one instant's targets [B,...] from `start` (the previous solution)."""
        began = time.perf_counter()
        model = self.model
        clean = clean_targets(targets)
        x = clean.targets
        valid = None if clean.all_valid else torch.cat((clean.position_valid, clean.orientation_valid), 1)
        weights = (None, None) if clean.all_valid else (clean.position_valid.to(x.position.dtype),
                                                        clean.orientation_valid.to(x.position.dtype))
        p, R, s = start.base_position.clone(), start.base_rotation.clone(), start.joint_positions.clone()
        B = p.shape[0]
        iterations = torch.zeros(B, dtype=torch.long, device=p.device)
        active = torch.ones(B, dtype=torch.bool, device=p.device)
        free = torch.full((B, 6), torch.inf, dtype=p.dtype, device=p.device)
        G = None
        if model.linear_limits is not None:
            A, b = model.linear_limits.A, model.linear_limits.b
            G = torch.cat((A.new_zeros(A.shape[0], 6), A), 1).expand(B, -1, -1)
        # Gauss-Newton iterations (the method, not links or subjects); the last pass only evaluates
        for iteration in range(self.max_iterations + 1):
            if self._rotations_only:
                assert self._orientation_selection is not None  # rotations only: there are orientation targets
                kin = model.rotations(R, s, self._orientation_selection, joint_axes=True)
                r_p, R_hat = x.position - p.unsqueeze(1), kin.rotation
            else:
                kin = model(p, R, s, self._selection, jacobian_links=self._task.position,
                            jacobian=self._task.position is not None, joint_axes=True)
                assert kin.position is not None
                r_p, R_hat = x.position - kin.position.index_select(1, self._p), kin.rotation.index_select(1, self._o)
            assert kin.joint_axes is not None  # asked for
            r_o = orientation_residual(x.rotation, R_hat)
            error = torch.cat((r_p, r_o), 1).norm(dim=-1)
            converged = (error if valid is None else error * valid).amax(-1) <= self.tolerance
            active = active & ~converged
            if iteration == self.max_iterations or not bool(active.any()):
                break
            H, g = normal_equations(self._task, kin.joint_axes, kin.jacobian, r_p, r_o, self.damping,
                                    w_position=weights[0], w_orientation=weights[1])
            lb_s, ub_s = _increment_bounds(s, model.lower, model.upper)
            h = None if G is None else b - s @ A.T
            delta = self.backend.solve(QPProblem(H, g, torch.cat((-free, lb_s), 1), torch.cat((free, ub_s), 1), G, h)).x
            delta = delta * active[:, None]
            p = p + delta[:, :3]
            R = so3.exp(delta[:, 3:6]) @ R
            s = s + delta[:, 6:]
            iterations += active
            active = active & (delta.abs().amax(-1) > self.step_tolerance)
        errors = orientation_error(x.rotation, R_hat)
        mnte = _mean_over(errors, None if clean.all_valid else clean.orientation_valid)
        zero = torch.zeros(B, 6 + model.n_dof, dtype=p.dtype, device=p.device)
        return IKResult(State(p, R, s, zero), iterations, converged, mnte, time.perf_counter() - began)


@dataclass(frozen=True)
class Pairs:
    """The pair split of a model's targets, compiled once.

    parent, child: [P] indices into the orientation links; joints: [P,k] each pair's joints (padded
    with 0), valid: [P,k] which are real; rows: [P,m,k] each pair's coupled-limit coefficients,
    row_index [P,m] their rows in A, row_valid [P,m] which are real (padding: zero coefficients).
    """

    parent: torch.Tensor
    child: torch.Tensor
    joints: torch.Tensor
    valid: torch.Tensor
    rows: torch.Tensor
    row_index: torch.Tensor
    row_valid: torch.Tensor

    @classmethod
    def build(cls, model: KinematicModel, links: tuple[str, ...], base: int) -> "Pairs":
        """Pair each target but the base (`links[base]`) with its nearest target ancestor (build time:
        Python over the links is fine). InputError where the targets do not split into independent
        pairs (a joint or a coupled limit shared by two pairs, a target with no target above it)."""
        M = model.select(links).ancestor_mask.bool().cpu()  # [L,n]
        parents, children, joint_lists = [], [], []
        for c in range(len(links)):
            if c == base:
                continue
            above = [a for a in range(len(links)) if a != c and bool((M[a] <= M[c]).all()) and M[a].sum() < M[c].sum()]
            if not above:
                raise InputError(f"target {links[c]!r} has no target above it; pair-wise IK needs each target's "
                                 f"parent link among the targets (the base {links[base]!r} is above all)")
            parent = max(above, key=lambda a: int(M[a].sum()))  # the nearest: the most joints above it
            parents.append(parent)
            children.append(c)
            joint_lists.append((M[c] & ~M[parent]).nonzero().flatten().tolist())
        owner: dict[int, int] = {}
        for pair, js in enumerate(joint_lists):
            for j in js:
                if j in owner:
                    raise InputError(f"joint {model.joint_names[j]!r} lies between two pairs of targets "
                                     f"({links[children[owner[j]]]!r}, {links[children[pair]]!r}): not separable")
                owner[j] = pair
        P = len(joint_lists)
        k = max([1] + [len(js) for js in joint_lists])
        joints = torch.zeros(P, k, dtype=torch.long)
        valid = torch.zeros(P, k, dtype=torch.bool)
        for pair, js in enumerate(joint_lists):
            joints[pair, :len(js)] = torch.tensor(js, dtype=torch.long)
            valid[pair, :len(js)] = True
        row_lists: list[list[int]] = [[] for _ in joint_lists]
        limits = model.linear_limits
        if limits is not None:
            A = limits.A.cpu()
            for r in range(A.shape[0]):
                pairs = {owner.get(j) for j in A[r].nonzero().flatten().tolist()}
                owning = pairs.pop() if len(pairs) == 1 else None
                if owning is None:
                    raise InputError(f"coupled limit {limits.names[r]!r} spans several pairs of targets")
                row_lists[owning].append(r)
        m = max([1] + [len(rs) for rs in row_lists])
        rows = torch.zeros(P, m, k, dtype=model.dtype)
        row_index = torch.zeros(P, m, dtype=torch.long)
        row_valid = torch.zeros(P, m, dtype=torch.bool)
        for pair, rs in enumerate(row_lists):
            for i, r in enumerate(rs):
                rows[pair, i] = A[r, joints[pair]] * valid[pair]
                row_index[pair, i], row_valid[pair, i] = r, True
        to = lambda t: t.to(model.device)  # noqa: E731
        return cls(to(torch.tensor(parents)), to(torch.tensor(children)), to(joints), to(valid), to(rows),
                   to(row_index), to(row_valid))


class PairwiseIK(InstantaneousIK):
    """Iterate-to-convergence IK of each pair of adjacent targets, all pairs in one batch.

    orientation_links: the targets, the base link among them; position_links: the base link only
    (its position target places the base). tolerance: a pair has converged when its relative
    orientation residual (sin of the angle) is below it (default 1e-10); step_tolerance: a pair
    stops when its largest increment (rad) is below it (default 1e-6); max_iterations: the cap
    (default 50); damping: lambda; backend: the QP backend's name ('batched' solves all pairs in
    one call; 'piqp' calls PIQP once per pair that a limit constrains). Raises InputError for
    targets that do not split into pairs (a joint between two pairs, a coupled limit across pairs).
    """

    def __init__(self, model: KinematicModel, orientation_links, position_links=None, tolerance: float = 1e-10,
                 max_iterations: int = 50, damping: float = 1e-9, backend: str = "batched", step_tolerance: float = 1e-6):
        position_links = tuple(position_links if position_links is not None else (model.base_link,))
        if position_links != (model.base_link,):
            raise InputError(f"pair-wise IK takes one position target, the base link {model.base_link!r}; "
                             f"got {list(position_links)}")
        self.model = model
        self.orientation_links = tuple(orientation_links)
        if model.base_link not in self.orientation_links:
            raise InputError(f"pair-wise IK takes the base's rotation from its target: the orientation links must "
                             f"include the base link {model.base_link!r}")
        self._base = self.orientation_links.index(model.base_link)
        self._selection = model.select(self.orientation_links)
        self.pairs = Pairs.build(model, self.orientation_links, self._base)
        self.tolerance, self.step_tolerance = tolerance, step_tolerance
        self.max_iterations, self.damping = max_iterations, damping
        self.backend = make_backend(backend)
        pairs = self.pairs
        self._lower, self._upper = model.lower[pairs.joints], model.upper[pairs.joints]  # [P,k]
        # padding entries of a pair's QP are pinned at zero: H = I there, g = 0, 0 <= x <= 0
        k = pairs.joints.shape[1]
        self._regulariser = torch.diag_embed((~pairs.valid).to(model.dtype)) + \
            damping * torch.eye(k, dtype=model.dtype, device=model.device)  # [P,k,k]
        self._b = None
        if model.linear_limits is not None:
            self._b = torch.where(pairs.row_valid, model.linear_limits.b[pairs.row_index], 1.0)  # [P,m]

    @torch.inference_mode()
    def solve(self, targets: Targets, start: State) -> IKResult:
        """Solve for one instant's targets from `start` (the previous solution). Targets [B,...]:
        position [B,1,3] of the base, rotation [B,n_o,3,3]."""
        began = time.perf_counter()
        model, pairs = self.model, self.pairs
        clean = clean_targets(targets)
        x = clean.targets
        B, (P, k), m = x.rotation.shape[0], pairs.joints.shape, pairs.rows.shape[1]
        base_ok = clean.position_valid[:, 0] & clean.orientation_valid[:, self._base]  # [B]
        p = torch.where(base_ok[:, None], x.position[:, 0], start.base_position)
        R = torch.where(base_ok[:, None, None], x.rotation[:, self._base], start.base_rotation)
        s = start.joint_positions.clone()
        R_target = x.rotation
        relative_target = R_target[:, pairs.parent].transpose(-1, -2) @ R_target[:, pairs.child]  # [B,P,3,3]
        pair_ok = clean.orientation_valid[:, pairs.parent] & clean.orientation_valid[:, pairs.child]  # [B,P]
        flat_joints = pairs.joints.flatten()
        valid = pairs.valid.to(p.dtype)  # [P,k]
        iterations = torch.zeros(B, dtype=torch.long, device=p.device)
        active = pair_ok.clone()
        G = None if self._b is None else pairs.rows.expand(B, P, m, k)
        # Gauss-Newton iterations (the method, not pairs or subjects); the last pass only evaluates
        for iteration in range(self.max_iterations + 1):
            kin = model.rotations(R, s, self._selection, joint_axes=True)  # pairs need no positions
            R_parent = kin.rotation[:, pairs.parent]  # [B,P,3,3]
            relative = R_parent.transpose(-1, -2) @ kin.rotation[:, pairs.child]
            residual = orientation_residual(relative_target, relative)  # [B,P,3] in the parent's frame
            converged = residual.norm(dim=-1) <= self.tolerance
            active = active & ~converged
            if iteration == self.max_iterations or not bool(active.any()):
                break
            # a pair's Jacobian: its joints' axes in the parent's frame, rows [B,P,k,3]
            assert kin.joint_axes is not None  # asked for
            axes = (kin.joint_axes[:, flat_joints].view(B, P, k, 3) @ R_parent) * valid[..., None]
            H = axes @ axes.transpose(-1, -2) + self._regulariser
            g = -(axes @ residual[..., None]).squeeze(-1)
            s_pair = s[:, flat_joints].view(B, P, k)
            lb, ub = _increment_bounds(s_pair, self._lower, self._upper)
            lb, ub = lb * valid, ub * valid
            h = None
            if G is not None and self._b is not None:
                h = (self._b - (G @ s_pair[..., None]).squeeze(-1)).reshape(B * P, m)
            delta = self.backend.solve(QPProblem(H.reshape(B * P, k, k), g.reshape(B * P, k), lb.reshape(B * P, k),
                                                 ub.reshape(B * P, k), None if G is None else G.reshape(B * P, m, k),
                                                 h)).x.view(B, P, k)
            delta = delta * (active[..., None] * valid)
            s = s.index_add(1, flat_joints, delta.reshape(B, P * k))  # padding adds zero to joint 0
            iterations += active.any(-1)
            active = active & (delta.abs().amax(-1) > self.step_tolerance)
        errors = orientation_error(R_target, kin.rotation)
        mnte = _mean_over(errors, None if clean.all_valid else clean.orientation_valid)
        zero = torch.zeros(B, 6 + model.n_dof, dtype=p.dtype, device=p.device)
        done = (converged | ~pair_ok).all(-1)
        return IKResult(State(p, R, s, zero), iterations, done, mnte, time.perf_counter() - began)

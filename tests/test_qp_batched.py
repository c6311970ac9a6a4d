"""qp.batched: exact KKT points on 1000 tracker-like step problems, the same optimum and active set
as PIQP, the same tracked trajectories, and faults confined to the subject that has them."""

import numpy as np
import pytest
import qpsolvers
import torch
from step_problems import step_problems

from torchik import KinematicModel
from torchik.method.limits import LimitSettings
from torchik.method.models import TRACKED_LINKS, HumanSubject, load_model
from torchik.method.qp import BatchedBackend, DenseHessian, PiqpBackend, QPProblem
from torchik.method.state import TargetSequence
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.motion import periodic_motion, targets_from_motion

# 1000 problems in all
SIZES = {"human66": 400, "human48": 300, "icub": 300}
PIQP_TIGHT = dict(eps_abs=1e-10, eps_rel=1e-11, eps_duality_gap_abs=1e-10, eps_duality_gap_rel=1e-11, max_iter=1000)


def objective(problem: QPProblem, x: torch.Tensor) -> torch.Tensor:
    H = problem.dense_hessian.to(x.dtype)
    return 0.5 * (x[:, None, :] @ H @ x[:, :, None]).flatten() + (problem.g.to(x.dtype) * x).sum(-1)


def piqp_reference(problem: QPProblem, tolerances: dict = PIQP_TIGHT):
    """PIQP at tight tolerances, one problem at a time: x [B,N], bound multipliers [B,N], status."""
    numpy = lambda t: None if t is None else t.double().numpy()  # noqa: E731
    H, g, lb, ub, G, h = (numpy(t) for t in (problem.dense_hessian, problem.g, problem.lb, problem.ub, problem.G, problem.h))
    xs, zs, ys, status = [], [], [], []
    for b in range(g.shape[0]):
        qp = qpsolvers.Problem(H[b], g[b], None if G is None else G[b], None if h is None else h[b], lb=lb[b], ub=ub[b])
        solution = qpsolvers.solve_problem(qp, solver="piqp", **tolerances)
        status.append(str(solution.extras["info"].status).rsplit("PIQP_", 1)[-1])
        ok = status[-1] == "SOLVED"
        xs.append(solution.x if ok else np.full(g.shape[1], np.nan))
        zs.append(solution.z_box if ok else np.full(g.shape[1], np.nan))
        ys.append((solution.z if ok else np.full(h.shape[1], np.nan)) if h is not None else np.zeros(0))
    return torch.tensor(np.array(xs)), torch.tensor(np.array(zs)), torch.tensor(np.array(ys)), status


def kkt_error(problem: QPProblem, x, bound, row) -> torch.Tensor:
    """The largest violation of the KKT conditions, each relative to its scale. -> [B]"""
    g, lb, ub, G, h = problem.g, problem.lb, problem.ub, problem.G, problem.h
    scale = 1 + g.abs().amax(-1)
    largest = lambda bound: torch.where(torch.isfinite(bound), bound.abs(), 0).amax(-1)  # noqa: E731
    bound_scale = 1 + largest(lb) + largest(ub)
    gradient = (problem.dense_hessian @ x[..., None]).squeeze(-1) + g + bound
    upper, lower = bound.clamp(min=0), (-bound).clamp(min=0)
    errors = [
        gradient.abs().amax(-1) / scale if G is None else
        (gradient + (G.transpose(1, 2) @ row[..., None]).squeeze(-1)).abs().amax(-1) / scale,  # stationarity
        ((x - ub).clamp(min=0).amax(-1) + (lb - x).clamp(min=0).amax(-1)) / bound_scale,  # primal feasibility
        torch.where(torch.isfinite(ub), upper * (ub - x),
                    upper * torch.inf).nan_to_num(0.0).amax(-1) / (scale * bound_scale),
        torch.where(torch.isfinite(lb), lower * (x - lb),
                    lower * torch.inf).nan_to_num(0.0).amax(-1) / (scale * bound_scale),
    ]
    # complementarity with multipliers on a missing bound: inf * 0 is nan, so such a multiplier must be 0
    on_missing = lambda multiplier, bound: torch.where((multiplier > 0) & ~torch.isfinite(bound), 1.0, 0.0).amax(-1)
    errors.append(on_missing(upper, ub) + on_missing(lower, lb))
    if G is not None:
        Gx = (G @ x[..., None]).squeeze(-1)
        row_scale = 1 + h.abs().amax(-1) + G.abs().sum(-1).amax(-1) * x.abs().amax(-1)
        errors += [(Gx - h).clamp(min=0).amax(-1) / row_scale, (-row).clamp(min=0).amax(-1) / scale,
                   (row * (h - Gx)).abs().amax(-1) / (scale * row_scale)]
    return torch.stack(errors).amax(0)


@pytest.fixture(scope="module", params=list(SIZES))
def solved(request):
    name = request.param
    model = load_model(name)
    problem = step_problems(model, TRACKED_LINKS[name], SIZES[name], seed=7)
    solution = BatchedBackend().solve(problem)
    return name, problem, solution, piqp_reference(problem)


def test_every_solution_is_a_kkt_point_or_reported_infeasible(solved):
    name, problem, solution, (x_ref, z_ref, y_ref, status) = solved
    ok = solution.solved
    assert float(kkt_error(problem, solution.x, solution.bound_multipliers, solution.row_multipliers)[ok].max()) < 1e-8
    # a subject left unsolved is one PIQP finds infeasible too (iCub states outside the coupled limits)
    unsolved = (~ok).nonzero().flatten().tolist()
    assert all(status[b] == "PRIMAL_INFEASIBLE" for b in unsolved), [status[b] for b in unsolved]
    assert len(unsolved) <= 0.1 * len(status) and (name == "icub" or not unsolved)


@pytest.mark.parametrize("subjects", [slice(None), slice(0, 20)])
def test_continued_from_the_unconstrained_start_the_solve_reaches_the_same_kkt_points(solved, subjects):
    """`start` (the captured step's unconstrained minimiser and factorisation): its feasible
    subjects are kept as they are, the others solved from it, on the tree's factorisation (the
    whole batch) or densely (20 subjects)."""
    from torchik.method.qp import unconstrained

    name, problem, solution, _ = solved
    if subjects != slice(None):
        rows = torch.arange(problem.g.shape[0])[subjects]
        pick = lambda t: None if t is None else t[rows]  # noqa: E731
        problem = QPProblem(None, *(pick(t) for t in (problem.g, problem.lb, problem.ub, problem.G, problem.h)),
                            problem.tree.select(rows))
        solution = BatchedBackend().solve(problem)
    assert problem.tree is not None  # the tree's factorisation starts, the gathered subjects go on densely or not
    start = unconstrained(problem)
    continued = BatchedBackend().solve(problem, start=start)
    ok = continued.solved
    assert torch.equal(ok, solution.solved)
    assert torch.equal(continued.x[start.feasible], start.x[start.feasible])
    assert float(kkt_error(problem, continued.x, continued.bound_multipliers, continued.row_multipliers)[ok].max()) < 1e-8
    f, f_ref = objective(problem, continued.x)[ok], objective(problem, solution.x)[ok]
    assert float(((f - f_ref).abs() / (1 + f_ref.abs())).max()) < 1e-10


def test_a_continued_solve_leaves_nothing_active_where_its_start_solved_for_the_next_warm_start():
    """The subjects `start` solves hold no bound and no row in the active set the backend keeps for
    its next solve, whether some subjects are left to solve or none."""
    from torchik.method.qp import unconstrained

    name = "icub"
    problem = step_problems(load_model(name), TRACKED_LINKS[name], 64, seed=7)
    assert problem.G is not None and problem.h is not None
    backend = BatchedBackend()
    backend.solve(problem)
    assert backend._last is not None and bool(backend._last[2].any())  # rows active to be forgotten
    unbounded = torch.full_like(problem.lb, torch.inf)
    for rows_kept in (8, 0):  # the first subjects keep their rows (still violated), the others none
        h = torch.where(torch.arange(64)[:, None] < rows_kept, problem.h, torch.inf)
        loose = QPProblem(problem.H, problem.g, -unbounded, unbounded, problem.G, h, problem.tree)
        start = unconstrained(loose)
        backend.solve(loose, start=start)
        upper, lower, rows = backend._last
        assert not bool((upper | lower)[start.feasible].any() or rows[start.feasible].any())
        assert bool(start.feasible.all()) == (rows_kept == 0)


def strictly_active(problem: QPProblem, bound: torch.Tensor, threshold: float) -> torch.Tensor:
    """Bounds whose multiplier exceeds `threshold`, relative to the gradient's scale: +1 upper, -1
    lower, 0 not. -> [B,N]. By multipliers, not positions: on these nearly singular problems
    PIQP's point can sit 1e-5 off a bound it holds while its multipliers agree to 1e-6."""
    scale = 1 + problem.g.abs().amax(-1, keepdim=True)
    return (bound > threshold * scale).long() - (bound < -threshold * scale).long()


def piqp_trustworthy(problem: QPProblem, solution, x_ref, status) -> torch.Tensor:
    """Subjects both solved, where PIQP's point is feasible to 1e-10 (at its tolerances PIQP leaves
    some slightly outside their bounds, and a point outside can have a lower objective). -> [B]"""
    bound_scale = 1 + problem.lb.abs().nan_to_num(0, 0, 0).amax(-1) + problem.ub.abs().nan_to_num(0, 0, 0).amax(-1)
    violation = torch.maximum((x_ref - problem.ub).clamp(min=0), (problem.lb - x_ref).clamp(min=0)).amax(-1)
    return solution.solved & torch.tensor([s == "SOLVED" for s in status]) & (violation <= 1e-10 * bound_scale)


def multipliers_unique(problem: QPProblem, x: torch.Tensor, tolerance: float = 1e-6) -> torch.Tensor:
    """Whether the bounds and rows that x [B,N] touches (to `tolerance`) have linearly independent
    normals (LICQ): only then are the KKT multipliers, and with them the strictly active set,
    unique. A state past a coupled limit can pinch a joint between a row and its own bound (row
    r_shoulder_roll <= h and the rate bound r_shoulder_roll >= lb meeting at one value, or 1e-9
    apart): any split of the force between the two is optimal, or within the solvers' tolerances,
    and each solver picks its own. -> [B]"""
    touched = (x <= problem.lb + tolerance) | (x >= problem.ub - tolerance)
    normals = torch.diag_embed(touched.to(x.dtype))
    count = touched.sum(-1)
    if problem.G is not None:
        rows = (problem.G @ x[..., None]).squeeze(-1) >= problem.h - tolerance
        normals = torch.cat((normals, problem.G * rows[..., None]), dim=1)
        count = count + rows.sum(-1)
    return torch.linalg.matrix_rank(normals) == count


def test_objective_and_strictly_active_set_match_piqp(solved):
    name, problem, solution, (x_ref, z_ref, y_ref, status) = solved
    both = piqp_trustworthy(problem, solution, x_ref, status)
    assert int(both.sum()) >= 0.8 * len(status)
    f, f_ref = objective(problem, solution.x)[both], objective(problem, x_ref)[both]
    assert float(((f - f_ref).abs() / (1 + f_ref.abs())).max()) < 1e-8
    # the multipliers below only where they are unique (all of the human models' problems)
    unique = multipliers_unique(problem, solution.x)
    assert name == "icub" or bool(unique.all())
    both &= unique
    # a bound clearly active for one solver is active, on the same side, for the other; bounds with
    # multipliers near rounding (weakly active) may go either way
    ours_strong = strictly_active(problem, solution.bound_multipliers, 1e-4)[both]
    ours_weak = strictly_active(problem, solution.bound_multipliers, 1e-8)[both]
    piqp_strong = strictly_active(problem, z_ref, 1e-4)[both]
    piqp_weak = strictly_active(problem, z_ref, 1e-8)[both]
    assert bool((ours_weak[ours_strong != 0] == ours_strong[ours_strong != 0]).all())
    assert bool((piqp_weak[ours_strong != 0] == ours_strong[ours_strong != 0]).all())
    assert bool((ours_weak[piqp_strong != 0] == piqp_strong[piqp_strong != 0]).all())
    assert int((ours_strong != 0).sum()) > 0
    if problem.G is not None:
        # rows where the two points coincide: dependent rows (a shoulder at a vertex of its coupled
        # limits) on a nearly singular Hessian leave optimal points 0.1 apart with the same objective
        # and different active rows, both exact KKT points
        same = both & ((solution.x - x_ref).abs().amax(-1) < 1e-6 * (1 + x_ref.abs().amax(-1)))
        assert int(same.sum()) >= 50
        scale = (1 + problem.g.abs().amax(-1, keepdim=True))[same]
        rows, rows_ref = solution.row_multipliers[same] / scale, y_ref[same] / scale
        assert int((rows > 1e-4).sum()) >= 20
        assert bool(((rows > 1e-8)[rows_ref > 1e-4]).all() and ((rows_ref > 1e-8)[rows > 1e-4]).all())


def test_the_step_matches_piqp_where_the_reduced_hessian_is_well_conditioned(solved):
    """nu against PIQP at its tightest tolerances (1e-12: it then stops at its iteration cap on some
    problems, which are left out), where the Hessian on the free variables is well conditioned: an
    error in the KKT residual moves nu by at most the residual over the smallest eigenvalue."""
    name, problem, solution, (x_ref, z_ref, y_ref, status) = solved
    both = piqp_trustworthy(problem, solution, x_ref, status)
    free = strictly_active(problem, z_ref, 1e-8) == 0
    H = problem.dense_hessian
    reduced = H * (free[:, :, None] & free[:, None, :]) + torch.diag_embed((~free).double())
    well = (both & (torch.linalg.cond(reduced) < 1e4)).nonzero().flatten()
    pick = lambda t: None if t is None else t[well]  # noqa: E731
    subset = QPProblem(pick(problem.dense_hessian),
                       *(pick(t) for t in (problem.g, problem.lb, problem.ub, problem.G, problem.h)))
    x_tight, _, _, tight_status = piqp_reference(subset, dict(eps_abs=1e-12, eps_rel=1e-13, eps_duality_gap_abs=1e-12,
                                                                eps_duality_gap_rel=1e-13, max_iter=1000))
    solved_tight = torch.tensor([s == "SOLVED" for s in tight_status])
    assert int(solved_tight.sum()) >= 10
    x, reference = solution.x[well][solved_tight], x_tight[solved_tight]
    difference = (x - reference).abs().amax(-1) / (1 + reference.abs().amax(-1))
    assert float(difference.max()) < 1e-6


def test_float32_objective_within_1e_4_of_piqp():
    name = "human66"
    problem = step_problems(load_model(name), TRACKED_LINKS[name], 100, seed=11)
    single = step_problems(load_model(name), TRACKED_LINKS[name], 100, seed=11, dtype=torch.float32)
    solution = BatchedBackend().solve(single)
    x_ref, _, _, status = piqp_reference(problem)
    ok = piqp_trustworthy(problem, solution, x_ref, status)
    assert int(ok.sum()) >= 85
    f, f_ref = objective(problem, solution.x.double())[ok], objective(problem, x_ref)[ok]
    assert float(((f - f_ref).abs() / (1 + f_ref.abs())).max()) < 1e-4


def test_dense_and_tree_hessians_give_the_same_solutions():
    name = "human48"
    tree = step_problems(load_model(name), TRACKED_LINKS[name], 64, seed=3)
    dense = step_problems(load_model(name), TRACKED_LINKS[name], 64, seed=3, structured=False)
    a, b = BatchedBackend().solve(tree), BatchedBackend().solve(dense)
    assert bool(a.solved.all() and b.solved.all())
    fa, fb = objective(dense, a.x), objective(dense, b.x)
    assert float(((fa - fb).abs() / (1 + fb.abs())).max()) < 1e-10


def test_tracking_reuses_the_last_active_set_and_needs_about_one_iteration_a_step():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 0.5, 100, batch=16, frequency=2.0)
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, dt=0.01, backend="batched")
    tracker.reset(tracker.initial_state(sequence[0]), batch=16)
    iterations, rescued, active = [], 0, 0
    for k in range(len(sequence)):
        _, diagnostics = tracker.step(sequence[k])
        iterations.append(tracker.backend.iterations)
        rescued += tracker.backend.rescued
        active += int(diagnostics.active_constraints.sum())
    assert active > 0  # the rate bounds bind, so there is an active set to carry over
    # the batch's most: one iteration when no subject's active set changed, two when one did
    assert sum(iterations[10:]) / len(iterations[10:]) <= 2.2 and rescued <= 0.02 * 16 * len(sequence)


def test_nan_in_one_subject_touches_only_that_subject():
    name = "icub"
    problem = step_problems(load_model(name), TRACKED_LINKS[name], 32, seed=2)
    clean = BatchedBackend().solve(problem)
    g = problem.g.clone()
    g[5, 10] = float("nan")
    broken = BatchedBackend().solve(QPProblem(problem.H, g, problem.lb, problem.ub, problem.G, problem.h, problem.tree))
    assert not bool(broken.solved[5]) and bool(torch.isfinite(broken.x).all())
    rest = torch.arange(32) != 5
    assert torch.equal(broken.solved[rest], clean.solved[rest])
    # the same optima; x itself only to rounding amplified by the conditioning (the other subjects
    # are solved in a differently composed batch, so the sums round differently)
    f, f_clean = objective(problem, broken.x)[rest], objective(problem, clean.x)[rest]
    assert float(((f - f_clean).abs() / (1 + f_clean.abs())).max()) < 1e-13
    assert torch.allclose(broken.x[rest], clean.x[rest], atol=1e-6, rtol=0)


def test_a_subject_that_does_not_converge_in_the_budget_is_flagged_and_falls_back():
    name = "human66"
    problem = step_problems(load_model(name), TRACKED_LINKS[name], 64, seed=9)
    starved = BatchedBackend(active_set_iterations=2, interior_point_iterations=4, polish_iterations=1)
    solution = starved.solve(problem)
    full = BatchedBackend().solve(problem)
    assert 0 < int((~solution.solved).sum()) < 64
    failed = ~solution.solved
    assert bool((solution.x[failed] >= problem.lb[failed]).all() and (solution.x[failed] <= problem.ub[failed]).all())
    # the subjects it did solve are exact: the same optimum as with the full budget
    f, f_full = objective(problem, solution.x)[~failed], objective(problem, full.x)[~failed]
    assert float(((f - f_full).abs() / (1 + f_full.abs())).max()) < 1e-9


def test_16_tracked_subjects_batched_follow_the_piqp_trajectories_within_1e_6_rad():
    subjects = [HumanSubject(height=1.5 + 0.03 * i, mass=55 + 2 * i) for i in range(16)]
    models = [load_model("human66", s) for s in subjects]
    stacked = KinematicModel.stack(models)
    links = TRACKED_LINKS["human66"]
    # fast motion (3 Hz) so that joint-rate bounds bind during the run
    sequences = [targets_from_motion(m, periodic_motion(m, 0.6, 100, seed=i, frequency=3.0), links)
                 for i, m in enumerate(models)]
    cat = lambda name: torch.cat([getattr(s, name) for s in sequences], dim=1)  # noqa: E731
    batch = TargetSequence(sequences[0].time, cat("position"), cat("linear_velocity"), cat("rotation"),
                           cat("angular_velocity"))
    slow = LimitSettings(max_rate=8.0)  # joint-rate bounds that the motion's rates reach
    batched = DynamicalIK(stacked, links, dt=0.01, backend="batched", limits=slow).run(batch)
    tight = PiqpBackend(eps_abs=1e-11, eps_rel=1e-12)  # at its 1e-9 default PIQP alone moves nu by 1e-4 here
    piqp = DynamicalIK(stacked, links, dt=0.01, backend=tight, limits=slow).run(batch)
    assert int(batched.diagnostics["active_constraints"].sum()) > 0  # the limits took part
    assert bool(batched.diagnostics["solved"].all())
    assert float((batched.joint_positions - piqp.joint_positions).abs().max()) < 1e-6
    relative = batched.base_rotation.transpose(-1, -2) @ piqp.base_rotation
    assert float((relative - torch.eye(3, dtype=torch.float64)).abs().max()) < 1e-6


def test_auto_backend_is_batched_for_batches_and_piqp_for_one_subject():
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    tracker = DynamicalIK(model, links, dt=0.01)
    tracker.reset(batch=4)
    assert tracker.backend.name == "batched"
    tracker.reset(batch=1)
    assert tracker.backend.name == "piqp"


def test_dense_hessian_operator_agrees_with_the_matrix():
    g = torch.Generator().manual_seed(0)
    A = torch.randn(3, 5, 5, generator=g, dtype=torch.float64)
    H = A @ A.transpose(1, 2) + torch.eye(5, dtype=torch.float64)
    x = torch.randn(3, 5, 2, generator=g, dtype=torch.float64)
    dense = DenseHessian(H)
    assert torch.allclose(dense.matvec(x), H @ x)
    free = torch.tensor([[True, False, True, True, True]] * 3)
    held = torch.randn(3, 5, 2, generator=g, dtype=torch.float64)
    y = dense.factor(free).solve(x, held)
    assert torch.allclose(y[:, 1], held[:, 1])
    assert torch.allclose((H @ y)[free], x[free])

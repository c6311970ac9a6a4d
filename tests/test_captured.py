"""captured step (TrackerSettings(compile=True)): it gives the eager step's states and diagnostics, to
rounding, on a walking run and through every unusual step (a dropped target and a gap, which run
eagerly; a jittered dt; an active bound, whose QP the backend solves); compiled by TorchInductor it
agrees to 1e-12 too."""

import dataclasses
import math
import warnings

import pytest
import torch
from compilers import missing_compiler

import torchik.method.capture as capture_module
import torchik.method.captured as captured_module
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import TargetSequence
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.motion import periodic_motion, targets_from_motion

LINKS = TRACKED_LINKS["human66"]
STATES = ("base_position", "base_rotation", "joint_positions", "velocity")
EXACT = ("active_constraints", "solved", "dropped", "projected", "failed", "new_segment")


@pytest.fixture(scope="module")
def walking():
    model = load_model("human66")
    motion = periodic_motion(model, 2.0, 100, seed=0)
    return model, motion, targets_from_motion(model, motion, LINKS)


@pytest.fixture
def uncompiled(monkeypatch):
    """The captured step's function run as it is, uncompiled, in the form it takes when traced
    (`capture.tracing`): its logic, without TorchInductor's cost."""

    def as_traced(fn, inputs):
        def call(*args):
            monkeypatch.setattr(capture_module, "_tracing", True)
            try:
                return fn(*args)
            finally:
                monkeypatch.setattr(capture_module, "_tracing", False)
        return call

    monkeypatch.setattr(captured_module, "capture", as_traced)


def batch_of(sequence: TargetSequence, B: int) -> TargetSequence:
    grow = lambda t: t.expand(t.shape[0], B, *t.shape[2:]).clone() if t.dim() > 1 else t.clone()  # noqa: E731
    return TargetSequence(*(grow(t) for t in vars(sequence).values()))


def assert_same_run(model, sequence, atol=1e-12, tracker=None, links=LINKS, velocity_atol=None, **settings):
    """Eager and captured runs of `sequence` give the same states and diagnostics (the velocity to
    `velocity_atol`, by default `atol`); returns the steps the captured one ran eagerly (a list of
    indices) and its trajectory."""
    eager = DynamicalIK(model, links, dt=0.01, **settings).run(sequence)
    tracker = tracker or DynamicalIK(model, links, dt=0.01, compile=True, **settings)
    replay = tracker.run(sequence)
    for name in STATES:
        tolerance = velocity_atol if name == "velocity" and velocity_atol is not None else atol
        torch.testing.assert_close(getattr(replay, name), getattr(eager, name), rtol=0, atol=tolerance)
    for name in ("mnte", "residual_norm"):
        torch.testing.assert_close(replay.diagnostics[name], eager.diagnostics[name], rtol=0, atol=atol)
    for name in EXACT:
        assert torch.equal(replay.diagnostics[name], eager.diagnostics[name]), name
    assert tracker.captured is not None and not tracker.captured.unavailable
    return (~torch.isnan(replay.diagnostics["kinematics_time"])).nonzero().flatten().tolist(), replay


@pytest.mark.parametrize("B", [1, 2])
def test_every_settled_step_of_a_walking_run_is_replayed_and_gives_the_eager_states(walking, uncompiled, B):
    model, _, sequence = walking
    assert assert_same_run(model, batch_of(sequence, B))[0] == [0, 1]  # the steps that settle the history


@pytest.mark.parametrize("case", ["paper scheme", "position targets off the base", "icub"])
def test_other_steps_replayed_give_the_eager_states_too(uncompiled, case):
    """The paper's scheme, positions and Jacobians off the base (the full kinematics), coupled limits."""
    name = "icub" if case == "icub" else "human66"
    model, links = load_model(name), TRACKED_LINKS[name]
    position_links = (model.base_link, "RightHand", "LeftFoot") if case == "position targets off the base" else None
    motion = periodic_motion(model, 1.0, 100, seed=1)
    sequence = targets_from_motion(model, motion, links, position_links)
    # iCub's walk passes near singular configurations, where H's conditioning turns the rounding of
    # sums taken in another order into differences of the velocity for a few steps (measured 1e-9 on
    # one machine, 1.07e-8 on another, an AVX-512 CPU): rounding that the conditioning amplifies,
    # not another solution; the joints then differ by 6e-11.
    icub = case == "icub"
    eager_steps, _ = assert_same_run(model, sequence, links=links, position_links=position_links,
                                     scheme="paper" if case == "paper scheme" else "midpoint",
                                     atol=1e-9 if icub else 1e-12, velocity_atol=1e-7 if icub else None)
    assert eager_steps[:2] == [0, 1] and len(eager_steps) < len(sequence) // 2


def test_unusual_steps_run_eagerly_and_the_run_stays_the_eager_one(walking, uncompiled):
    model, _, sequence = walking
    rotation = sequence.rotation.clone()
    rotation[50:53, 0, LINKS.index("LeftToe")] = math.nan  # a dropped target (a leaf: its joints rest), remembered two steps
    time = sequence.time.clone()
    time[100:] += 0.5  # a gap: a new segment
    time[150:] += 0.003 * torch.arange(len(time) - 150, dtype=time.dtype)  # jitter from there on
    faulty = dataclasses.replace(sequence, rotation=rotation, time=time)
    # eager: the steps that settle the history, the dropped target's and the two after that remember
    # it, the gap's and the one after (its history restarts); the jittered steps are replayed
    assert assert_same_run(model, faulty)[0] == [0, 1, 50, 51, 52, 53, 54, 100, 101]


def test_a_step_with_an_active_bound_has_its_qp_solved_by_the_backend(walking, uncompiled):
    model, _, sequence = walking
    narrow = load_model("human66")
    narrow.upper = narrow.upper.clone()
    narrow.upper[:] = 0.05  # joints that walk reach their upper limits: the QP's bounds become active
    tracker = DynamicalIK(narrow, LINKS, dt=0.01, compile=True)
    eager_steps, replay = assert_same_run(narrow, sequence, tracker=tracker)
    assert eager_steps == [0, 1]  # every settled step captured
    solved = torch.isfinite(replay.diagnostics["qp_time"]).nonzero().flatten().tolist()
    active = replay.diagnostics["active_constraints"][:, 0]
    assert solved == [0, 1] + [k for k in range(2, len(sequence)) if active[k] > 0] and len(solved) > 10


CUDA = pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device"))


@pytest.mark.parametrize("device", ["cpu", CUDA])
@pytest.mark.parametrize("narrow", [False, True])
def test_a_batch_solved_on_the_tree_is_replayed_with_the_tree_and_gives_the_eager_states(walking, uncompiled,
                                                                                        monkeypatch, narrow, device):
    """The tree's elimination, level by level in fresh tensors, and its QP handed to the backend
    where a bound is active (narrow limits)."""
    from torchik.method.structure import BatchSetup

    _, _, sequence = walking
    model = load_model("human66", device=device)
    if narrow:
        model.upper = model.upper.clone()
        model.upper[:] = 0.05
    monkeypatch.setattr(BatchSetup, "TREE_FROM", 4)
    # more subjects than the kinematics composes by pointer jumping (compose.SMALL_BATCH): level by level
    phases = batch_of(TargetSequence(*(t[:60].to(device) for t in vars(sequence).values())), 40)
    tracker = DynamicalIK(model, LINKS, dt=0.01, compile=True, backend="batched")
    eager_steps, replay = assert_same_run(model, phases, tracker=tracker, backend="batched")
    assert tracker._batch.structured and eager_steps == [0, 1]
    assert (replay.diagnostics["active_constraints"][2:] > 0).any() == narrow


@pytest.mark.parametrize("gathered", ["densely", "on the tree"])
def test_icub_on_the_tree_hands_its_active_coupled_rows_to_the_backend_from_the_captured_solve(
        uncompiled, monkeypatch, gathered):
    """Where a coupled row is active the backend goes on from the captured step's unconstrained
    solve (`BatchedBackend.solve(start=...)`): the eager states; the captured factorisation reused
    where the few subjects gathered stay on the tree (`DENSE_BELOW` lowered to 1), not where they
    are solved densely; and at most one active-set iteration a step more than the eager step's
    (start's guess, where a subject held a bound in the last solve's set)."""
    import torchik.method.qp.active_set as active_set_module
    import torchik.method.qp.batched as batched_module
    from torchik.method.structure import BatchSetup

    model, links = load_model("icub"), TRACKED_LINKS["icub"]
    monkeypatch.setattr(BatchSetup, "TREE_FROM", 4)
    if gathered == "on the tree":
        monkeypatch.setattr(active_set_module, "DENSE_BELOW", 1)
    reused: list[bool] = []

    def spied(H, problem, sets, budget, tolerance, factor=None, **rest):
        reused.append(factor is not None)
        return active_set_module.active_set(H, problem, sets, budget, tolerance, factor, **rest)

    monkeypatch.setattr(batched_module, "active_set", spied)
    sequence = targets_from_motion(model, periodic_motion(model, 0.8, 100, batch=40, seed=1), links)
    iterations = {}
    for compiled in (False, True):
        tracker = DynamicalIK(model, links, dt=0.01, compile=compiled, backend="batched")
        tracker.reset(tracker.initial_state(sequence[0]), batch=40)
        iterations[compiled], reused[:] = [], []
        for k in range(len(sequence)):
            _, diagnostics = tracker.step(sequence[k])
            solved = not math.isnan(diagnostics.qp_time)
            iterations[compiled].append(tracker.backend.iterations if solved else 1)
    assert tracker._batch.structured
    assert any(reused) == (gathered == "on the tree")
    # start's guess (no bound held) is one iteration more than the eager step's warm start where a
    # subject held a bound (measured: 112 against 99 over 79 steps); never more, and two at most
    captured, eager = iterations[True][2:], iterations[False][2:]
    assert all(c <= e + 1 for c, e in zip(captured, eager)) and sum(captured) / len(captured) <= 2
    tracker = DynamicalIK(model, links, dt=0.01, compile=True, backend="batched")
    eager_steps, replay = assert_same_run(model, sequence, tracker=tracker, links=links, backend="batched",
                                          atol=1e-8, velocity_atol=1e-6)
    assert eager_steps == [0, 1]
    qp_steps = torch.isfinite(replay.diagnostics["qp_time"]).nonzero().flatten().tolist()
    assert len(qp_steps) > 2 + 5, "coupled rows active in a few steps"


def test_a_dt_of_the_wrong_shape_is_refused_as_the_eager_step_refuses_it(walking, uncompiled):
    from torchik import InputError

    model, motion, sequence = walking
    tracker = DynamicalIK(model, LINKS, dt=0.01, compile=True)
    tracker.reset(motion.state(0))
    for k in range(3):
        tracker.step(sequence[k])
    with pytest.raises(InputError, match="dt"):
        tracker.step(sequence[3], dt=torch.full((2,), 0.01, dtype=torch.float64))


def captured_by(tracker: DynamicalIK, first_steps: TargetSequence, device: str) -> None:
    """Runs the steps that capture the tracker's step. Skips where this machine has no compiler for
    `device`; where it has one, a failed capture fails the test with the capture's message (the code
    or the set-up, headers or OpenMP say, is then to mend: the tracker alone would only warn and run
    eagerly)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tracker.run(first_steps)
    assert tracker.captured is not None
    if tracker.captured.unavailable:
        why = missing_compiler(device)
        if why is not None:
            pytest.skip(f"TorchInductor cannot compile for {device} here: {why}")
        pytest.fail("the capture failed with a compiler present: "
                    + "; ".join(str(w.message) for w in caught if "eagerly" in str(w.message)))


def test_compiled_by_torchinductor_the_step_gives_the_eager_states_to_1e_12(walking):
    """The one test that compiles (seconds with TorchInductor's cache, tens the first time on a machine)."""
    model, _, sequence = walking
    tracker = DynamicalIK(model, LINKS, dt=0.01, compile=True)
    captured_by(tracker, TargetSequence(*(t[:3] for t in vars(sequence).values())), "cpu")
    assert assert_same_run(model, sequence, tracker=tracker)[0] == [0, 1]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_cuda_the_compiled_step_gives_the_eager_states(walking):
    _, _, sequence = walking
    model = load_model("human66", device="cuda")
    on_cuda = TargetSequence(*(t.to("cuda") for t in vars(sequence).values()))
    tracker = DynamicalIK(model, LINKS, dt=0.01, compile=True)
    captured_by(tracker, TargetSequence(*(t[:3] for t in vars(on_cuda).values())), "cuda")
    assert assert_same_run(model, on_cuda, tracker=tracker)[0] == [0, 1]

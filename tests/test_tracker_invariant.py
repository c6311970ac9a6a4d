"""tracker's invariant: every state a step returns is finite, its base rotation orthonormal to 1e-12 and
its joints within their limits; a subject that would break it restarts from its targets (the others
untouched), and a gap in time restarts the subjects after it instead of one huge step."""

import dataclasses

import torch

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import TargetSequence, Trajectory
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.motion import periodic_motion, targets_from_motion

LINKS = TRACKED_LINKS["human66"]


def walking(batch: int, seconds: float = 2.0) -> tuple:
    model = load_model("human66")
    motion = periodic_motion(model, seconds, 100, seed=0)
    sequence = targets_from_motion(model, motion, LINKS)
    grow = lambda t: t.expand(t.shape[0], batch, *t.shape[2:]).clone() if t.dim() > 1 else t.clone()  # noqa: E731
    return model, motion, TargetSequence(*(grow(t) for t in vars(sequence).values()))


def assert_invariant(model, trajectory: Trajectory) -> None:
    for name in ("base_position", "base_rotation", "joint_positions", "velocity"):
        assert bool(torch.isfinite(getattr(trajectory, name)).all()), name
    R = trajectory.base_rotation
    assert float((R.transpose(-1, -2) @ R - torch.eye(3, dtype=R.dtype)).abs().max()) <= 1e-12
    s = trajectory.joint_positions
    assert float((s - model.upper).max()) <= 1e-6 and float((model.lower - s).max()) <= 1e-6


def test_a_subject_fed_huge_velocities_restarts_while_the_others_are_untouched():
    model, motion, clean = walking(batch=3)
    faulty = clean.angular_velocity.clone()
    faulty[80:90, 1, 3] = 1e300  # subject 1, one link, 10 frames: finite, so nothing drops it
    sequence = dataclasses.replace(clean, angular_velocity=faulty)
    tracker = DynamicalIK(model, LINKS, dt=0.01)
    expected = tracker.run(clean, initial=tracker.initial_state(clean[0]))
    got = tracker.run(sequence, initial=tracker.initial_state(sequence[0]))
    assert_invariant(model, got)
    failed = got.diagnostics["failed"]
    assert bool(failed[:, 1].any()) and not bool(failed[:, [0, 2]].any())
    assert int(failed.sum()) <= 12  # the faulty frames and the two after, which the midpoint scheme averages them into
    for name in ("base_position", "base_rotation", "joint_positions", "velocity"):
        # to rounding: the batch's rotations are orthonormalised with as many iterations as its worst needs
        torch.testing.assert_close(getattr(got, name)[:, [0, 2]], getattr(expected, name)[:, [0, 2]], rtol=0, atol=1e-12)
    # subject 1 recovers: a second after the fault it tracks like the others
    late = motion.time >= 1.9
    assert float((got.joint_positions[late, 1] - expected.joint_positions[late, 1]).abs().max()) < 1e-2


def test_on_clean_targets_no_step_fails_and_no_segment_starts():
    model, _, sequence = walking(batch=1, seconds=1.0)
    tracker = DynamicalIK(model, LINKS, dt=0.01)
    trajectory = tracker.run(sequence)
    assert not bool(trajectory.diagnostics["failed"].any()) and not bool(trajectory.diagnostics["new_segment"].any())


def test_a_gap_in_time_starts_a_new_segment_from_the_targets_after_it():
    model, motion, sequence = walking(batch=1, seconds=3.0)
    after = sequence.time > 1.0
    gapped = dataclasses.replace(sequence, time=torch.where(after, sequence.time + 10.0, sequence.time))
    trajectory = DynamicalIK(model, LINKS, dt=0.01).run(gapped)
    assert_invariant(model, trajectory)
    new_segment = trajectory.diagnostics["new_segment"][:, 0]
    first_after = int(after.nonzero()[0])
    assert new_segment.nonzero()[:, 0].tolist() == [first_after]
    assert bool(trajectory.diagnostics["solved"].all())  # no QP fell back
    # from the restart the tracker converges on the targets as it does at the start of a run
    truth = motion.joint_positions[:, 0] if motion.joint_positions.dim() == 3 else motion.joint_positions
    assert float((trajectory.joint_positions[-1, 0] - truth[-1]).abs().max()) < 1e-2


def test_a_gap_no_longer_than_max_gap_steps_is_integrated():
    model, _, sequence = walking(batch=1, seconds=1.0)
    stretched = dataclasses.replace(sequence, time=torch.where(sequence.time > 0.5, sequence.time + 0.03, sequence.time))
    trajectory = DynamicalIK(model, LINKS, dt=0.01, max_gap=5.0).run(stretched)  # a 4-step gap
    assert not bool(trajectory.diagnostics["new_segment"].any())


def test_float32_tracking_keeps_the_invariant_at_float32_rounding_and_tracks_below_1e_6():
    """In float32 an orthonormalised rotation is off by a few 1e-7: the invariant's rotation
    tolerance follows the dtype, or every step of every subject would fail and restart."""
    model = load_model("human48", dtype=torch.float32)
    links = TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 0.5, 100, batch=8, seed=1, dtype=torch.float32)
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, dt=0.01, backend="batched")
    result = tracker.run(sequence, initial=motion.state(0))  # from the motion's own first state
    assert not bool(result.diagnostics["failed"].any())
    # after the start's transient (float64 takes the same 0.3 s to settle below 1e-6)
    assert float(result.diagnostics["mnte"][30:].max()) < 1e-6

"""Tracking a sequence of targets, given whole or a part at a time: what `DynamicalIK.run` and
`DynamicalIK.run_parts` do. A long recording's targets need not be held at once: the tracker's
state carries over from one part to the next, and each part's trajectory is returned as it is
done, the same samples as a run over the whole sequence."""

from __future__ import annotations

from typing import Generator, Iterable, Protocol

import torch

from ..errors import InputError
from .kinematics import KinematicModel
from .state import State, StepDiagnostics, TargetSequence, Trajectory, TrajectoryBuffer
from .targets import Targets, clean_steps


class Tracker(Protocol):
    """What a run needs of the tracker (`DynamicalIK`)."""

    model: KinematicModel

    @property
    def dt(self) -> float: ...

    def reset(self, state: State | None = None, batch: int = 1) -> State: ...

    def initial_state(self, targets: Targets) -> State: ...

    def step(self, targets: Targets, dt: float | torch.Tensor | None = None,
             checked: bool = False, sample: int | None = None) -> tuple[State, StepDiagnostics]: ...


def run_parts(tracker: Tracker, parts: Iterable[TargetSequence], time: torch.Tensor, initial: State | None = None,
              progress: bool | None = None, interruptible: bool = False,
              settle: float = 0.0, held: bool = False) -> Generator[Trajectory, None, None]:
    """Track the sequence whose time stamps are `time` [T], its targets given in consecutive `parts`
    (their lengths adding up to T), from `initial` (default: `initial_state` of the first targets,
    or with `settle` > 0 seconds, `settled_state` on them: at rest in their posture, without the
    transient from the zero posture). Yields each part's trajectory once its steps are done.

    Steps at the nominal rate (to the rounding of the time stamps) take the nominal dt, others
    (jitter, gaps) their own. progress: a bar once the run has lasted a second (None: on runs of
    over 20 000 subject-steps). interruptible: Ctrl-C (KeyboardInterrupt, while stepping or while
    `parts` makes the next part) stops the run; the last part yielded then holds the steps done of
    its part, perhaps none, with `interrupted` True. Before the first step, KeyboardInterrupt still rises.
    held: every step tracks the first sample held still (`settled_state`): the tasks with inputs per
    sample read that sample's."""
    T = len(time)
    if T == 0:
        raise InputError("the sequence is empty")
    if initial is not None and settle > 0:
        raise InputError("a run starts from `initial` or settles on its first targets, not both")
    if T > 1 and not bool((time[1:] > time[:-1]).all()):
        raise InputError("sequence.time must be strictly increasing")
    bar = None
    done, steps, buffer, last = 0, None, None, None  # last: the latest step's (state, diagnostics)
    sample = (lambda k: 0) if held else (lambda k: k)  # noqa: E731
    try:
        for part in parts:
            if not 0 < len(part) <= T - done:
                raise InputError(f"a part of {len(part)} samples after {done} of the {T} samples of `time`")
            if steps is None:  # the first part: where the run starts, and how many subjects
                first = part[0]
                if initial is None:
                    initial = settled_state(tracker, first, settle) if settle > 0 else tracker.initial_state(first)
                tracker.reset(initial, batch=first.batch)
                steps = time_steps(tracker, time, first.batch)
                if progress or (progress is None and T * first.batch > 20000):
                    from tqdm import tqdm

                    bar = tqdm(total=T, desc="tracking", unit="step", leave=False, delay=1.0)
            buffer = TrajectoryBuffer(part.time, *last) if last is not None else None
            checked = clean_steps(part.position, part.linear_velocity, part.rotation, part.angular_velocity).tolist()
            for k in range(len(part)):
                last = tracker.step(part[k], steps(done + k), checked[k], sample=sample(done + k))
                if buffer is None:
                    buffer = Trajectory.preallocated(part.time, *last)
                buffer.put(*last)
                if bar is not None:
                    bar.update()
            done += len(part)
            assert buffer is not None  # the part had samples
            finished, buffer = buffer, None
            yield finished.trajectory()
        if done != T:
            raise InputError(f"the parts hold {done} of the {T} samples of `time`")
    except KeyboardInterrupt:
        if not interruptible or last is None:
            raise
        if buffer is None:  # stopped between parts: an empty one says so
            buffer = TrajectoryBuffer(time[done:done], *last)
        yield buffer.trajectory(interrupted=True)
    finally:
        if bar is not None:
            bar.close()


def settled_state(tracker: Tracker, targets: Targets, seconds: float) -> State:
    """The state [B] at rest in the posture of `targets` [B,...]: the tracker run from
    `initial_state(targets)` for `seconds` (two steps at least, at its nominal dt) on these targets
    held still (their velocities zero; missing ones stay missing), then its velocity zeroed. A run
    started from it follows its first targets from its first step, where one started from the zero
    posture spends its first tenths of a second converging: most of a trial of one or two seconds."""
    n = max(2, round(seconds / tracker.dt))
    held = lambda x: x[None].expand(n, *x.shape)  # noqa: E731
    still = TargetSequence(tracker.dt * torch.arange(n, dtype=targets.position.dtype, device=targets.position.device),
                           held(targets.position), torch.zeros_like(held(targets.linear_velocity)),
                           held(targets.rotation), torch.zeros_like(held(targets.angular_velocity)))
    run = next(iter(run_parts(tracker, [still], still.time, held=True)))
    return State(run.base_position[-1], run.base_rotation[-1], run.joint_positions[-1],
                 torch.zeros_like(run.velocity[-1]))


def nominal_steps(time: torch.Tensor, dt: float, dtype: torch.dtype | None = None) -> torch.Tensor:
    """[T] bool: step k's gap time[k] - time[k-1] (in `dtype`, default time's) is dt to the time
    stamps' rounding (the first step, which has none, is)."""
    gaps = (time[1:] - time[:-1]).to(dtype or time.dtype)
    rounding = 64 * torch.finfo(time.dtype).eps * float(time.abs().max()) if len(time) > 1 else 0.0
    return torch.cat((torch.ones(1, dtype=torch.bool, device=time.device), (gaps - dt).abs() <= rounding))


def time_steps(tracker: Tracker, time: torch.Tensor, B: int):
    """Step k's dt, a function of k: None (the nominal dt, which the step uses without checks or
    tensor arithmetic) where the time stamps' gap is the nominal one to their rounding, else the
    gap [B] (made when asked: a tensor per step held for the whole run would weigh more than the
    trajectory)."""
    nominal = nominal_steps(time, tracker.dt, tracker.model.dtype).tolist()
    gaps = (time[1:] - time[:-1]).to(tracker.model.dtype).to(tracker.model.device)
    return lambda k: None if nominal[k] else gaps[k - 1].expand(B)

"""What the tracker consumes and returns: the state, the targets over time, a step's diagnostics,
a tracked trajectory."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .targets import Targets


@dataclass
class State:
    """The configuration and its velocity. base_position [B,3]; base_rotation [B,3,3];
    joint_positions [B,n]; velocity [B,6+n] = (p_dot_B, omega_B world, s_dot)."""

    base_position: torch.Tensor
    base_rotation: torch.Tensor
    joint_positions: torch.Tensor
    velocity: torch.Tensor

    def clone(self) -> "State":
        return State(*(t.clone() for t in vars(self).values()))


@dataclass(frozen=True)
class StepDiagnostics:
    """What a step did, per subject.

    mnte: [B] mean of 1 - cos(angle) over the orientation targets used, state and targets at the
    start of the step;
    residual_norm: [B,n_p+n_o] |r| per target (m for positions, sin(angle) for orientations);
    active_constraints: [B] bounds and linear limits active in the QP's solution;
    solved: [B] False where the QP failed and the clipped fallback was used;
    dropped: [B] non-finite targets dropped; projected: [B] target rotations projected onto SO(3);
    failed: [B] True where the step's state broke the invariant (not finite, rotation not orthonormal,
    joints beyond their limits) and the subject restarted from the step's targets;
    new_segment: [B] True where a gap in time longer than max_gap steps restarted the subject;
    step_time: seconds for the whole batch, of which kinematics_time (the kinematics calls) and
    qp_time (the QP backend's solve); for a step replayed compiled (TrackerSettings.compile), whose
    parts are one computation, both NaN, or only kinematics_time where a bound was active and the
    backend solved the step's QP.
    """

    mnte: torch.Tensor
    residual_norm: torch.Tensor
    active_constraints: torch.Tensor
    solved: torch.Tensor
    dropped: torch.Tensor
    projected: torch.Tensor
    failed: torch.Tensor
    new_segment: torch.Tensor
    step_time: float
    kinematics_time: float = 0.0
    qp_time: float = 0.0


PER_SUBJECT = ("mnte", "residual_norm", "active_constraints", "solved", "dropped", "projected", "failed",
               "new_segment")  # [B] each step
PER_BATCH = ("step_time", "kinematics_time", "qp_time")  # seconds, one per step


@dataclass(frozen=True)
class TargetSequence:
    """Targets over time: time [T] s (strictly increasing); fields as Targets with a leading T."""

    time: torch.Tensor
    position: torch.Tensor
    linear_velocity: torch.Tensor
    rotation: torch.Tensor
    angular_velocity: torch.Tensor

    def __len__(self) -> int:
        return self.time.shape[0]

    def __getitem__(self, k: int) -> Targets:
        return Targets(self.position[k], self.linear_velocity[k], self.rotation[k], self.angular_velocity[k])

    def part(self, start: int, stop: int) -> "TargetSequence":
        """Samples [start, stop) (views)."""
        return TargetSequence(*(x[start:stop] for x in vars(self).values()))


@dataclass
class Trajectory:
    """A tracked sequence: time [T]; base_position [T,B,3]; base_rotation [T,B,3,3];
    joint_positions [T,B,n]; velocity [T,B,6+n]; the step diagnostics stacked over time
    (mnte [T,B], residual_norm [T,B,n_t], active_constraints [T,B], solved [T,B], dropped [T,B],
    projected [T,B], failed [T,B], new_segment [T,B], step_time [T], kinematics_time [T], qp_time [T]); interrupted: the run
    was stopped (Ctrl-C) before the end of its targets."""

    time: torch.Tensor
    base_position: torch.Tensor
    base_rotation: torch.Tensor
    joint_positions: torch.Tensor
    velocity: torch.Tensor
    diagnostics: dict[str, torch.Tensor] = field(default_factory=dict)
    interrupted: bool = False

    def part(self, start: int, stop: int) -> "Trajectory":
        """Samples [start, stop) (views), the diagnostics with them."""
        cut = slice(start, stop)
        return Trajectory(self.time[cut], self.base_position[cut], self.base_rotation[cut], self.joint_positions[cut],
                          self.velocity[cut], {name: x[cut] for name, x in self.diagnostics.items()}, self.interrupted)

    @classmethod
    def concatenate(cls, parts: list["Trajectory"]) -> "Trajectory":
        """Consecutive parts of a run as one trajectory (interrupted when the last part is)."""
        if len(parts) == 1:
            return parts[0]
        cat = lambda name: torch.cat([getattr(p, name) for p in parts])  # noqa: E731
        diagnostics = {name: torch.cat([p.diagnostics[name] for p in parts]) for name in parts[0].diagnostics}
        return cls(cat("time"), cat("base_position"), cat("base_rotation"), cat("joint_positions"), cat("velocity"),
                   diagnostics, parts[-1].interrupted)

    @classmethod
    def preallocated(cls, time: torch.Tensor, state: State, diagnostics: StepDiagnostics) -> "TrajectoryBuffer":
        """A buffer for a run of len(time) steps shaped as this first step's state and diagnostics."""
        return TrajectoryBuffer(time, state, diagnostics)

    @classmethod
    def from_steps(cls, time: torch.Tensor, states: list[State], diagnostics: list[StepDiagnostics],
                   interrupted: bool = False) -> "Trajectory":
        """The trajectory of a run's steps: time [T], one State and StepDiagnostics per step."""
        stack = lambda items, name: torch.stack([getattr(x, name) for x in items])  # noqa: E731
        stacked = {name: stack(diagnostics, name) for name in PER_SUBJECT}
        for name in PER_BATCH:
            stacked[name] = torch.tensor([getattr(d, name) for d in diagnostics], dtype=torch.float64)
        return cls(time, stack(states, "base_position"), stack(states, "base_rotation"),
                   stack(states, "joint_positions"), stack(states, "velocity"), stacked, interrupted)


class TrajectoryBuffer:
    """A run's trajectory filled step by step into tensors allocated once ([T,...] per field): memory
    is the trajectory's size, not a few tensor objects per step (which, for an hour at 100 Hz, weigh
    several times the numbers they hold). Steps are written CHUNK at a time, one stacked copy per
    field: fifteen indexed writes a step cost more than a small batch's whole integration."""

    CHUNK = 64

    def __init__(self, time: torch.Tensor, state: State, diagnostics: StepDiagnostics):
        T = time.shape[0]
        empty = lambda x: x.new_empty((T, *x.shape))  # noqa: E731
        self.time = time
        self.states = {name: empty(x) for name, x in vars(state).items()}
        self.per_subject = {name: empty(getattr(diagnostics, name)) for name in PER_SUBJECT}
        self.per_batch = {name: torch.empty(T, dtype=torch.float64) for name in PER_BATCH}
        self.done = 0
        self._pending: list[tuple] = []  # the steps put and not written yet: each step's own tensors
        self._written = 0

    def put(self, state: State, diagnostics: StepDiagnostics) -> None:
        """Append a step. Its tensors are held until written: the tracker never writes into them."""
        self._pending.append((*vars(state).values(), *(getattr(diagnostics, name) for name in PER_SUBJECT),
                              *(getattr(diagnostics, name) for name in PER_BATCH)))
        self.done += 1
        if len(self._pending) == self.CHUNK:
            self._write()

    def _write(self) -> None:
        if not self._pending:
            return
        rows, fields = slice(self._written, self.done), list(zip(*self._pending))
        buffers = [*self.states.values(), *self.per_subject.values()]
        for buffer, values in zip(buffers, fields):
            torch.stack(values, out=buffer[rows])
        for buffer, values in zip(self.per_batch.values(), fields[len(buffers):]):
            buffer[rows] = torch.tensor(values, dtype=torch.float64)
        self._pending, self._written = [], self.done

    def trajectory(self, interrupted: bool = False) -> Trajectory:
        """The steps put so far as a Trajectory (views of the buffers)."""
        self._write()
        done = slice(0, self.done)
        diagnostics = {name: x[done] for name, x in {**self.per_subject, **self.per_batch}.items()}
        s = {name: x[done] for name, x in self.states.items()}
        return Trajectory(self.time[done], s["base_position"], s["base_rotation"], s["joint_positions"], s["velocity"],
                          diagnostics, interrupted)

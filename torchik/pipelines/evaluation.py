"""How well a trajectory tracks its targets: the estimated link motion, the paper's metrics at
every sample (`method.metrics` has their formulas), and their statistics after the transient.
`torchik track`, `torchik retarget`, the cohort, the diagnosis and the paper's experiment all
measure with these."""

from __future__ import annotations

import math
from typing import Iterator

import torch

from ..io.recording import Recording
from ..method.kinematics import KinematicModel
from ..method.metrics import angular_velocity_rmse, mnte
from ..method.state import TargetSequence, Trajectory


def time_chunks(model: KinematicModel, trajectory: Trajectory, chunk: int = 4096) -> Iterator[tuple]:
    """The trajectory's configurations a few whole time steps at a time, for batched kinematics.

    Yields (steps, m, p [t*B,3], R [t*B,3,3], s [t*B,n]): `steps` a slice of the time axis, row
    t*B + b subject b at step t, and `m` the model to call on those rows (a stack of subjects
    repeated once per step when `model` holds several). About `chunk` rows per call."""
    T, B = trajectory.joint_positions.shape[:2]
    per_call = max(chunk // B, 1)
    stacked: dict[int, KinematicModel] = {}
    for start in range(0, T, per_call):
        steps = slice(start, min(start + per_call, T))
        t = steps.stop - steps.start
        m = model if model.n_subjects == 1 else stacked.setdefault(t, KinematicModel.stack([model] * t))
        p, R, s = (x[steps].reshape(t * B, *x.shape[2:])
                   for x in (trajectory.base_position, trajectory.base_rotation, trajectory.joint_positions))
        yield steps, m, p, R, s


def link_motion(model: KinematicModel, trajectory: Trajectory, links, scheme: str | None = "midpoint",
                chunk: int = 4096) -> tuple[torch.Tensor, torch.Tensor]:
    """Estimated link rotations [T,B,L,3,3] and world angular velocities [T,B,L,3], computed a few
    time steps at a time from the joint axes (omega_L = omega_B + sum_j M_Lj s_dot_j a_j).

    scheme: what the trajectory's velocities mean. The midpoint scheme's nu_k is the mean velocity
    over [t_{k-1}, t_k]; its estimate at t_k is the mean of the two steps around it. The paper's
    nu_k is meant at t_k and is taken as it is, as are velocities of any other source (None: the
    instantaneous methods' central differences)."""
    parts = list(link_motion_chunks(model, trajectory, links, scheme, chunk))
    return torch.cat([R for _, R, _ in parts]), torch.cat([w for _, _, w in parts])


def link_motion_chunks(model: KinematicModel, trajectory: Trajectory, links, scheme: str | None = "midpoint",
                       chunk: int = 4096, next_velocity: torch.Tensor | None = None
                       ) -> Iterator[tuple[slice, torch.Tensor, torch.Tensor]]:
    """`link_motion` a few time steps at a time: (steps, rotations [t,B,L,3,3], angular velocities
    [t,B,L,3]), so that a long trajectory's metrics need memory for one chunk of link motion only.
    next_velocity [B,6+n]: the velocity of the step after the trajectory's last, when it is a part of
    a longer run (the midpoint scheme's estimate at t_k averages the steps around it)."""
    links = tuple(links)
    mask = model.select(links).ancestor_mask  # [L,n]
    velocity = trajectory.velocity  # [T,B,6+n]
    if scheme == "midpoint":
        following = velocity[1:] if next_velocity is None else torch.cat((velocity[1:], next_velocity[None]))
        velocity = torch.cat((0.5 * (velocity[:len(following)] + following), velocity[len(following):]))
    B, L = velocity.shape[1], len(links)
    with torch.inference_mode():
        for steps, m, p, R, s in time_chunks(model, trajectory, chunk):
            kin = m(p, R, s, links, jacobian=False, joint_axes=True)
            nu = velocity[steps].reshape(-1, velocity.shape[-1])
            omega = nu[:, None, 3:6] + mask @ (nu[:, 6:, None] * kin.joint_axes)
            yield steps, kin.rotation.view(-1, B, L, 3, 3), omega.view(-1, B, L, 3)


def known_targets(sequence: TargetSequence, frames: int | None = None) -> torch.Tensor:
    """[T,B] bool: every orientation and angular-velocity target of the sample is given (a missing
    one is NaN), over the first `frames` samples (default all)."""
    return present_targets(sequence, frames).all(-1)


def present_targets(sequence: TargetSequence, frames: int | None = None) -> torch.Tensor:
    """[T,B,L] bool: link l's orientation target is there at the sample, its rotation and angular
    velocity both finite (what the tracker keeps, `clean_targets`), over the first `frames` samples."""
    R, w = sequence.rotation[:frames], sequence.angular_velocity[:frames]
    return torch.isfinite(R).flatten(-2).all(-1) & torch.isfinite(w).all(-1)


def tracking_errors(model: KinematicModel, trajectory: Trajectory, sequence: TargetSequence, links,
                    scheme: str | None = "midpoint", next_velocity: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """The paper's metrics of every subject at every sample: mnte [T,B] and rmse [T,B] (rad/s),
    estimate at t_k against the targets at t_k (`sequence` cut to the trajectory's length; scheme
    and next_velocity as `link_motion_chunks`'), each a mean over the targets present at the sample
    (`present_targets`, as the tracker's step has them); NaN only where none is."""
    T, B = trajectory.velocity.shape[:2]
    present = present_targets(sequence, T)  # [T,B,L]
    out = {name: trajectory.velocity.new_empty((T, B)) for name in ("mnte", "rmse")}
    chunks = link_motion_chunks(model, trajectory, links, scheme, next_velocity=next_velocity)
    for steps, R_hat, w_hat in chunks:  # a chunk at a time: bounded memory
        ok = present[steps]
        out["mnte"][steps] = mnte(sequence.rotation[steps], R_hat, ok)
        out["rmse"][steps] = angular_velocity_rmse(sequence.angular_velocity[steps], w_hat, ok)
    return out


def position_errors(model: KinematicModel, trajectory: Trajectory, sequence: TargetSequence, links,
                    chunk: int = 4096) -> torch.Tensor:
    """[T,B,P] distance (m) from each position target of `links` (the sequence's position links, in its
    order) to the estimated link origin at the same sample; NaN where the target is missing."""
    T = len(trajectory.time)
    chunks = []
    for start in range(0, T, chunk):  # a few thousand samples at a time: the memory of the batch
        p, R, s = (x[start:start + chunk] for x in (trajectory.base_position, trajectory.base_rotation,
                                                    trajectory.joint_positions))
        n, B = p.shape[:2]
        kin = model(p.flatten(0, 1), R.flatten(0, 1), s.flatten(0, 1), tuple(links), jacobian=False)
        chunks.append(kin.position.unflatten(0, (n, B)))  # type: ignore[union-attr]  # positions asked for
    estimate = torch.cat(chunks)
    return (sequence.position[:T] - estimate).norm(dim=-1)


def after_transient(values: torch.Tensor, time: torch.Tensor, transient: float = 2.0) -> torch.Tensor:
    """values [T,...] at t >= time[0] + transient (all of them when the sequence is shorter)."""
    keep = (time >= time[0] + transient).to(values.device)  # times stay on the CPU, values may not
    return values[keep] if bool(keep.any()) else values


def summary(values: torch.Tensor, time: torch.Tensor, transient: float = 2.0) -> dict[str, float]:
    """Median, 99th percentile, mean and max of values [T,...] over t >= time[0] + transient
    (all samples when the sequence is shorter than that)."""
    v = after_transient(values, time, transient).flatten().double()
    return dict(median=float(v.median()), p99=float(v.quantile(0.99)), mean=float(v.mean()), max=float(v.max()))


def tracking_statistics(trajectory: Trajectory, sequence: TargetSequence, recording: Recording,
                        model: KinematicModel, transient: float) -> dict:
    """What `torchik track` reports of subject 0's accuracy: mnte and angular_velocity_rmse
    (`summary` dicts over the steps with a target, None when no step has one) from
    statistics_from_s seconds after the first sample (`transient`, or 0 when the run has no
    measured step that late: its statistics are then the whole run's), steps_without_targets (the
    steps whose metrics are NaN) and, when the recording carries the model's joint angles,
    joint_error_rad (max, rms). trajectory: [T,1,...] with the mnte and rmse diagnostics
    (`tracking_errors`); sequence: its targets (at least T frames)."""
    statistics = TrackingStatistics(model, transient, len(trajectory.time))
    statistics.add(trajectory, sequence, recording)
    return statistics.result()


def statistics_start(time: torch.Tensor, measured: torch.Tensor, transient: float) -> float:
    """Seconds after time[0] from which a run's statistics are taken: `transient` when a measured
    step (measured [T] bool) comes that late, else 0 (the whole run, shorter than the transient)."""
    late = time >= time[0] + transient
    return float(transient) if bool((late & measured).any()) else 0.0


class Series:
    """Per-sample values of a run of at most `frames` samples, given a part at a time (`append`) into
    one tensor allocated with the first: a long run keeps no small blocks between its parts' large
    temporaries, which would keep the heap from shrinking."""

    def __init__(self, frames: int):
        self.frames, self.done = frames, 0
        self.buffer: torch.Tensor | None = None

    def append(self, values: torch.Tensor) -> None:
        """values [t,...] for the next t samples."""
        if self.buffer is None:
            self.buffer = values.new_empty((self.frames, *values.shape[1:]))
        self.buffer[self.done:self.done + len(values)] = values
        self.done += len(values)

    def values(self) -> torch.Tensor:
        """[T,...]: the samples given."""
        assert self.buffer is not None  # a part was given
        return self.buffer[:self.done]


class TrackingStatistics:
    """`tracking_statistics` of a run of at most `frames` samples given a part at a time (`add` each,
    in order): the per-sample metrics its summaries are taken of (two numbers a step), sums for the
    joint error."""

    def __init__(self, model: KinematicModel, transient: float, frames: int):
        self.model, self.transient = model, transient
        self.time = Series(frames)
        self.metrics = dict(mnte=Series(frames), rmse=Series(frames))
        # joint error: max and sum of squares (and their count) after the transient, and over all samples
        # (what is reported when the run is shorter than the transient)
        self.joints: dict[str, list[float]] | None = None

    def add(self, trajectory: Trajectory, sequence: TargetSequence, recording: Recording) -> None:
        """A part: trajectory [t,1,...] with mnte and rmse, its targets and recording from its first sample."""
        done, time, d = len(trajectory.time), trajectory.time, trajectory.diagnostics
        start = float((self.time.values() if self.time.done else time)[0])
        self.time.append(time)
        for name, series in self.metrics.items():
            series.append(d[name][:, 0])
        if recording.joint_positions is not None and recording.joint_names == self.model.joint_names:
            truth = torch.from_numpy(recording.joint_positions[:done]).to(trajectory.joint_positions)
            error = (trajectory.joint_positions[:, 0] - truth).abs()
            self.joints = self.joints or dict(after=[0.0, 0.0, 0], all=[0.0, 0.0, 0])
            for which, e in (("after", error[time >= start + self.transient]), ("all", error)):
                if e.numel():
                    total = self.joints[which]
                    total[:] = [max(total[0], float(e.max())), total[1] + float(e.square().sum()), total[2] + e.numel()]

    def result(self) -> dict:
        """mnte, angular_velocity_rmse, statistics_from_s, steps_without_targets and (with ground
        truth) joint_error_rad, as `tracking_statistics`."""
        time = self.time.values().cpu()  # the run's device may be a GPU
        values = {name: series.values().cpu() for name, series in self.metrics.items()}
        measured = torch.isfinite(values["mnte"])  # NaN only where no target is (`tracking_errors`)
        start = statistics_start(time, measured, self.transient)
        window = time >= time[0] + start
        out: dict = {}
        for key, v in zip(("mnte", "angular_velocity_rmse"), values.values()):
            keep = window & torch.isfinite(v)
            out[key] = summary(v[keep], time[keep], 0.0) if bool(keep.any()) else None
        out.update(statistics_from_s=start, steps_without_targets=int((~measured).sum()))
        if self.joints is not None:
            peak, squares, count = self.joints["after" if self.joints["after"][2] else "all"]
            out["joint_error_rad"] = dict(max=peak, rms=math.sqrt(squares / count))
        return out

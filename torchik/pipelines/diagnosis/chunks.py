"""Time-parallel tracking: a recording's run split into overlapping chunks tracked as one batch.

The tracker forgets where it started. An error in the directions its targets pull decays by
|1 - K dt| a step (K the gain, dt the step): 0.6 at the study's 50 Hz and K = 20/s. So a chunk
started `warm_up` steps before the samples it keeps, at rest in that frame's posture (settled as the
whole run is), is at the run's state to FORGET of its start by the time it reaches them. A run of T
steps on B subjects becomes one of about T / C + warm_up steps on C B subjects, and on a CPU a
step's cost grows slowly with a small batch: one Human48 subject's 12 s at 50 Hz tracks in half the
time in nine chunks (`experiments/chunked_tracking.py`, figures in experiments/diagnosis/README.md).

Each hand-over is checked: chunk k and chunk k - 1 tracked the same warm-up steps, and where they
differ by more than HANDOVER at the last of them, the run is tracked in one piece instead
(`analysis.track`). The decay holds where every direction of the joints is pulled by a target and
the least squares have one minimum: of the study's 90 recordings, 89 hand over within HANDOVER
(median 1e-13); on the measured ones (links without a marker cluster, arms 20-40 deg off what the
model can reach) none does, and a subject's Chunking stops the tries after the first. Only
uniformly sampled recordings are split: the batch's subjects share each step's dt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ...method.state import TargetSequence, Trajectory

FORGET = 1e-12  # what a chunk keeps of its start's error once its own samples begin
HANDOVER = 1e-9  # the most two chunks' configurations may differ where one takes over (m, rad)
ROUNDINGS = 64  # ... or this many times the dtype's rounding, where that is more (float32)
BATCH = 16  # chunks times subjects aimed at: on this project's 2-core CPU a step of 16 costs about twice one's
SLOWEST = 0.99  # a decay slower than this per step would need warm-ups of thousands of steps
FEWEST = 10  # warm-up steps at least: near K dt = 1 the linear decay says one, the tracker's large errors need more


@dataclass
class Chunking:
    """Whether a subject's runs are tracked in chunks: on until one's chunks disagree, off from then
    on for it and the variants made from it (which share this object). Where the tracker does not
    forget its start (a joint no target pulls, a residual so large that the least squares have more
    than one minimum: the measured recordings' arms), every try would cost half a run for nothing."""

    on: bool = True


@dataclass(frozen=True)
class Chunks:
    """C chunks of `length` samples each, chunk c tracked from sample starts[c] and keeping samples
    [owned[c], owned[c + 1]) of the T; warm_up: the samples each chunk but the first tracks before
    its own."""

    starts: tuple[int, ...]
    owned: tuple[int, ...]
    length: int
    warm_up: int

    @property
    def count(self) -> int:
        return len(self.starts)

    def batch(self, sequence: TargetSequence) -> TargetSequence:
        """The chunks of `sequence` [T,B,...] as one sequence [length, C B, ...] (chunk-major: subject
        b of chunk c at c B + b), timed as the first chunk (every step is nominal)."""
        fields = {name: x for name, x in vars(sequence).items() if name != "time"}
        cut = {name: torch.cat([x[s:s + self.length] for s in self.starts], dim=1) for name, x in fields.items()}
        return TargetSequence(sequence.time[:self.length], **cut)

    def stitch(self, run: Trajectory, time: torch.Tensor, gain: float) -> Trajectory | None:
        """The chunks' trajectory [length, C B, ...] as the recording's [T, B, ...] at `time` [T], each
        sample from the chunk that owns it; None where two chunks' configurations differ by more than
        HANDOVER (or ROUNDINGS roundings) at a hand-over, or their velocities by more than gain (1/s)
        times that (the velocity corrects the configuration's error at that rate), or either is not
        finite there. The per-batch diagnostics (step_time, kinematics_time, qp_time) are the chunked
        run's steps, each for all the chunks."""
        C = self.count
        B = run.joint_positions.shape[1] // C
        assert not run.interrupted and len(run.time) == self.length and B * C == run.joint_positions.shape[1] \
            and len(time) == self.owned[-1], "the chunks' run, whole, of the recording they were cut from"
        # in float32 the two runs' roundings differ by a few units of the last place, not less
        tolerance = max(HANDOVER, ROUNDINGS * torch.finfo(run.joint_positions.dtype).eps)
        states = dict(base_position=run.base_position, base_rotation=run.base_rotation,
                      joint_positions=run.joint_positions, velocity=run.velocity)
        for c in range(1, C):
            frame = self.owned[c] - 1  # the last warm-up sample of chunk c, which chunk c - 1 owns
            for name, x in states.items():
                this = x[frame - self.starts[c], c * B:(c + 1) * B]
                before = x[frame - self.starts[c - 1], (c - 1) * B:c * B]
                gap = (this - before).abs().max()
                if not bool(torch.isfinite(gap)) or float(gap) > tolerance * (gain if name == "velocity" else 1.0):
                    return None

        def own(x: torch.Tensor, per_subject: bool = True) -> torch.Tensor:
            parts = [x[self.owned[c] - s:self.owned[c + 1] - s] for c, s in enumerate(self.starts)]
            if per_subject:
                parts = [part[:, c * B:(c + 1) * B] for c, part in enumerate(parts)]
            return torch.cat(parts)

        diagnostics = {name: own(x, x.dim() > 1) for name, x in run.diagnostics.items()}
        return Trajectory(time, own(run.base_position), own(run.base_rotation), own(run.joint_positions),
                          own(run.velocity), diagnostics, run.interrupted)


def plan(steps: int, subjects: int, dt: float, gain: float, nominal: bool) -> Chunks | None:
    """How to split a run of `steps` samples of `subjects` subjects at the step dt with gain K (1/s)
    into chunks (None: in one piece). nominal: every step of the recording is dt (to rounding).
    Chunks enough to bring the batch near BATCH (fewer where the last would keep too little), each
    keeping at least as many samples as it warms up on."""
    decay = abs(1.0 - gain * dt)
    if not nominal or decay >= SLOWEST or subjects >= BATCH:
        return None
    warm_up = max(FEWEST, math.ceil(math.log(FORGET) / math.log(decay)) if decay > 0 else 1)
    for count in range(min(math.ceil(BATCH / subjects), steps // warm_up - 1), 1, -1):
        length = -(-(steps + (count - 1) * warm_up) // count)
        # each chunk starts where the one before it has `warm_up` samples left; the last ends at T
        starts = (*(c * (length - warm_up) for c in range(count - 1)), steps - length)
        owned = (0, *(s + warm_up for s in starts[1:]), steps)
        if all(b - a >= warm_up for a, b in zip(owned, owned[1:])):  # rounding can leave the last too little
            return Chunks(starts, owned, length, warm_up)
    return None

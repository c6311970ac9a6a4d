"""Batches of a cohort: trials that one batched tracker can run together, of similar length.

Trials share a batch when they share a topology, a link map and the tracker's options
(`TrialSpec.batch_key`); subjects' dimensions may differ (`KinematicModel.stack`). Within a
group, trials are sorted by length and cut into batches of near-equal size, so a batch pads
little: the shorter trials of a batch are padded to the longest with their last frame held
(see `trial.pad`), which leaves their result unchanged, the tracker being causal.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .manifest import TrialSpec

MAX_BATCH = 64  # subjects: a lost (or failed, then redone trial by trial) batch costs no more than this
# A step's time grows slowly with the batch (the timings: experiments/speed_history.md), so a
# worker does most with one large batch; more, smaller batches
# would only trade that for finer resuming, which MAX_BATCH already bounds.
BATCHES_PER_WORKER = 1


@dataclass(frozen=True)
class Batch:
    """Trials to track together (`trials`), each with the fingerprint of its spec (`fingerprints`),
    and the frames each was probed to have (None: unknown until it is read)."""

    index: int
    trials: tuple[TrialSpec, ...]
    fingerprints: tuple[str, ...]
    frames: tuple[int | None, ...]

    def __len__(self) -> int:
        return len(self.trials)


def probe_frames(path: str | Path) -> int | None:
    """The frame count of a .npz recording, reading its time array only; None for other formats
    or a file that does not read (its trial then fails when it is tracked, not here)."""
    if Path(path).suffix.lower() != ".npz":
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return int(data["time"].shape[0])
    except Exception:  # a corrupt file is the trial's failure, recorded when it runs
        return None


def batch_size_for(trials: int, workers: int) -> int:
    """The default batch size: the trials spread over BATCHES_PER_WORKER batches per worker, at
    most MAX_BATCH a batch."""
    return max(1, min(MAX_BATCH, math.ceil(trials / (BATCHES_PER_WORKER * max(workers, 1)))))


def plan_batches(specs: list[TrialSpec], fingerprints: list[str], batch_size: int) -> list[Batch]:
    """Group `specs` by batch key, sort each group by length (longest first) and cut it into
    batches of at most `batch_size`, sizes differing by one at most. The batches come longest
    work first, so the last to finish are short."""
    groups: dict[tuple, list] = defaultdict(list)
    for spec, fingerprint in zip(specs, fingerprints):
        groups[spec.batch_key].append((spec, fingerprint, probe_frames(spec.recording)))
    chunks = []
    for members in groups.values():
        members.sort(key=lambda m: -(m[2] or 0))
        count = math.ceil(len(members) / batch_size)
        bounds = np.linspace(0, len(members), count + 1).round().astype(int)
        chunks += [members[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    chunks.sort(key=lambda c: -len(c) * max((m[2] or 0) for m in c))
    return [Batch(i, *(tuple(x) for x in zip(*chunk))) for i, chunk in enumerate(chunks)]

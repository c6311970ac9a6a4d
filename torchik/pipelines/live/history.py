"""What a live session keeps of its steps (`History`), and what it gives back at the end
(`LiveResult`: per-character trajectories, the counters and the report)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...method.state import PER_SUBJECT, State, StepDiagnostics, Trajectory
from ..evaluation import summary

REPORTED = ("mnte", "dropped")  # the per-subject diagnostics the report needs, kept always


class History:
    """Per step, the batch rows that had a sample: their characters [m] and frames [m], and the
    step's per-subject diagnostics (`REPORTED`; with keep_states all of them and the states) as the
    step's own tensors, rows picked only when a character had no sample. Per-character
    trajectories are cut from them once, at the end: a step costs a few list appends, whatever the
    number of characters."""

    def __init__(self, keep_states: bool = True):
        self.keep_states = keep_states
        self.characters: list[np.ndarray] = []
        self.frames: list[np.ndarray] = []
        self.columns: dict[str, list[torch.Tensor]] = {}

    def add(self, characters: np.ndarray, frames: np.ndarray, rows: torch.Tensor | None, state: State,
            diagnostics: StepDiagnostics) -> None:
        """A step: characters [m] and frames [m] of the batch rows `rows` [m] (None: every row)."""
        kept = {name: getattr(diagnostics, name) for name in (PER_SUBJECT if self.keep_states else REPORTED)}
        if self.keep_states:
            kept.update(vars(state))
        for name, values in kept.items():
            self.columns.setdefault(name, []).append(values if rows is None else
                                                     values.index_select(0, rows.to(values.device)))
        self.characters.append(characters)
        self.frames.append(frames)

    def per_character(self, rate: float) -> dict[int, tuple[torch.Tensor, dict[str, torch.Tensor]]]:
        """Each character's time [T] (its frames over the rate) and kept columns [T,...]."""
        if not self.characters:
            return {}
        characters, frames = np.concatenate(self.characters), np.concatenate(self.frames)
        columns = {name: torch.cat(values) for name, values in self.columns.items()}
        out = {}
        for c in np.unique(characters).tolist():  # once per character, at the end
            index = np.flatnonzero(characters == c)
            rows = torch.from_numpy(index)
            out[c] = (torch.from_numpy(frames[index] / rate),
                      {name: values.index_select(0, rows.to(values.device)).cpu() for name, values in columns.items()})
        return out

    def trajectories(self, rate: float, interrupted: bool) -> dict[int, Trajectory]:
        """Each character's Trajectory (B = 1); empty unless the states were kept."""
        if not self.keep_states:
            return {}
        out = {}
        for c, (time, columns) in self.per_character(rate).items():
            one = {name: values[:, None] for name, values in columns.items()}
            out[c] = Trajectory(time, one["base_position"], one["base_rotation"], one["joint_positions"],
                                one["velocity"], {name: one[name] for name in PER_SUBJECT}, interrupted)
        return out


@dataclass
class LiveResult:
    """What a session did: per character its time and diagnostics (`characters`: time [T], mnte
    [T], dropped [T]) and, when the states were kept, its trajectory (B = 1); with retargeting the
    robot's trajectories; the source's counters, samples skipped per character, events (joins,
    stalls), latency (s, datagram arrival to published estimate, per published sample) and the
    step times (s) of every step, and the report (`report()`)."""

    characters: dict[int, tuple[torch.Tensor, dict[str, torch.Tensor]]]
    trajectories: dict[int, Trajectory]
    retargeted: dict[int, Trajectory]
    source_stats: dict[str, int]
    skipped: dict[int, int]
    events: list[str]
    latency: np.ndarray
    step_time: np.ndarray
    rate: float
    interrupted: bool
    retarget: dict | None = None  # the robot's limit checks (`LiveRetarget.report`)

    def report(self, transient: float = 2.0) -> dict:
        characters = {}
        for c, (time, columns) in self.characters.items():
            characters[str(c)] = dict(
                frames=len(time), duration_s=float(time[-1] - time[0]) if len(time) else 0.0,
                skipped=self.skipped.get(c, 0), dropped_targets=int(columns["dropped"].sum()),
                mnte=summary(columns["mnte"], time, transient) if len(time) else None)
        return dict(rate_hz=self.rate, characters=characters, source=self.source_stats,
                    skipped=sum(self.skipped.values()), events=self.events, latency_ms=milliseconds(self.latency),
                    step_time_ms=milliseconds(self.step_time), transient_s=transient, interrupted=self.interrupted,
                    **({"retarget": self.retarget} if self.retarget is not None else {}))


def milliseconds(values: np.ndarray) -> dict[str, float] | None:
    """Median, 99th percentile and max of durations (s) in ms; None for none."""
    if not len(values):
        return None
    return dict(median=float(np.median(values)) * 1e3, p99=float(np.quantile(values, 0.99)) * 1e3,
                max=float(values.max()) * 1e3)

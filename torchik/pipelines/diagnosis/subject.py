"""A recording in the diagnosis loop, and the tracking and analysis of several as batches."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from ...method.state import Trajectory
from .analysis import Analysis, analyse
from .candidates import candidates
from .chunks import Chunking
from .effect import Effect, halves
from .joints import joint_groups
from .posture import held_by_reference


@dataclass
class Subject:
    """One recording in the loop: its current (corrected) recording, URDF and model, the effects kept
    (steps) and rejected, its latest and first analyses (subject `b` of a batch), and the recording
    and URDF it started from (source)."""

    recording: Recording
    urdf: str
    model: KinematicModel
    steps: list = field(default_factory=list)
    done: bool = False
    best_rejected: Effect | None = None
    analysis: tuple[Analysis, int] | None = None  # set by the first round's analysis
    first: tuple[Analysis, int] | None = None
    derived: torch.Tensor | None = None
    unobservable: list = field(default_factory=list)
    rejected: list = field(default_factory=list)
    stop: str = "cap"
    source: tuple[Recording, str] | None = None  # the recording and URDF the loop started from
    rounds: int = 0  # the loop's rounds that added effects to it
    deferred: set = field(default_factory=set)  # (kind, target) taken back from a round with others: tried alone
    tried: set = field(default_factory=set)  # (kind, candidate, flips and swaps kept then) re-tracked (frames.py)
    chunking: Chunking = field(default_factory=Chunking)  # shared with the variants made from it
    negligible: dict = field(default_factory=dict)  # (kind, target): significant candidates below their floor
    shrunk: set = field(default_factory=set)  # (kind, target) added, then refined below its floor: not tried again
    unseen: dict = field(default_factory=dict)  # link: directions of a sensor turn the joints follow (first round)
    confounded: dict = field(default_factory=dict)  # link: its turns told from a neighbour's only poorly (first round)

    @property
    def effects(self) -> list[Effect]:
        return [st.effect for st in self.steps]

    @property
    def current(self) -> tuple[Analysis, int]:
        """The latest analysis and the subject's index in its batch."""
        assert self.analysis is not None, "analysed in the loop's first round"
        return self.analysis

    @property
    def initial(self) -> tuple[Analysis, int]:
        """The first round's analysis and the subject's index in its batch."""
        assert self.first is not None, "analysed in the loop's first round"
        return self.first

    def candidates(self, kinds, train=None, test=None, target=None, like=None) -> list[Effect]:
        """Candidates on the current analysis (train and test: halves() unless given; target: only
        those on that link or joint)."""
        analysis, b = self.current
        if train is None:
            train, test = halves(analysis.time)
        return candidates(analysis, b, train, test, self.urdf, kinds, self.derived, target, like)

    def refit(self, effect: Effect) -> Effect | None:
        """The effect's kind and target fitted again on all the current data (after the transient)."""
        train, test = halves(self.current[0].time, guard=0.0)
        found = [c for c in self.candidates((effect.kind,), train | test, train | test, effect.target, effect)
                 if c.fit is not None]
        return found[0] if found else None

    def adopted(self, c: Effect) -> tuple[Effect, str]:
        """Candidate c as the loop adds it: refitted on all the current data, keeping c's held-out score,
        the judgements made beside it and why a preference put it first; and why it is implausible
        ("" when it is not: its values, or a limit the reference pose holds it at)."""
        final = self.refit(c) or c
        final.fit = c.fit
        if final is not c and c.notes:
            final.notes = "; ".join(filter(None, [c.notes, final.notes]))
        final.params.update({name: c.params[name] for name in c.judged if name in c.params})
        why = final.implausible() or held_by_reference(final, self.model, self.current[0].poses[self.current[1]])
        return final, why

    def neighbours(self, link: str) -> list[str]:
        """The tracked links one joint from `link` (its nearest tracked ancestor and the links whose it is)."""
        groups = joint_groups(self.urdf, self.current[0].links)
        return sorted({g.parent for g in groups if g.child == link} | {g.child for g in groups if g.parent == link})

    def add(self, effect: Effect) -> None:
        if effect.model_effect:
            self.urdf = effect.augment(self.urdf)
            self.model = KinematicModel.from_urdf(self.urdf, name=f"{self.model.name}+", dtype=self.model.dtype)
        else:
            self.recording = effect.correct(self.recording)

    def saved(self) -> tuple:
        return self.recording, self.urdf, self.model, self.analysis


def analyse_subjects(subjects: list[Subject], links, gain: float, progress: bool, max_samples: int = 300) -> None:
    """Track and analyse the subjects, one batch per model."""
    groups: dict[int, list[Subject]] = {}
    for s in subjects:
        groups.setdefault(id(s.model), []).append(s)
    for group in groups.values():
        tried = all(s.chunking.on for s in group)  # one subject's chunks refused keep its group whole
        chunking = Chunking(tried)
        analysis = analyse(group[0].model, [s.recording for s in group], links, gain=gain, progress=progress,
                           max_samples=max_samples, chunking=chunking)
        for b, s in enumerate(group):
            s.analysis = (analysis, b)
            if tried and not chunking.on:  # which subject's chunks disagreed the batch does not say
                s.chunking.on = False


def trajectory_of(analysis: Analysis, b: int) -> Trajectory:
    """Subject b's trajectory of a batch's analysis, as a batch of one."""
    return one_of(analysis.trajectory, b)


def one_of(t: Trajectory, b: int) -> Trajectory:
    """Subject b of a batch's trajectory [T,B,...], as a batch of one [T,1,...]."""
    return Trajectory(t.time, t.base_position[:, b:b + 1], t.base_rotation[:, b:b + 1], t.joint_positions[:, b:b + 1],
                      t.velocity[:, b:b + 1])

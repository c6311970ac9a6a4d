"""A drift its gyro was unaware of, beside a bias of that gyro about the vertical: one shared drift.

A filter without a heading reference integrates its gyro's bias about the vertical into the heading,
and its rate stream carries that bias too (drift.HeadingDrift, gyro_shares): the orientations drift
and the gyro agrees with them. The loop may name it as two effects instead: the heading drifting
under a gyro unaware of it (which disagrees with its orientations by -rate z) and a bias of +rate z
in that gyro's stream, which cancels the disagreement: four parameters for the one the shared drift
has. Where a kept drift of the unaware kind and a kept gyro bias share a sensor, the pair is tried,
where the bias' part about the vertical is the drift's rate in size, as one shared drift, fitted on
the recording without either, and kept in their place where the tracking errors it acts on
(orientations and angular velocities) are not worse (result.WORSE).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from ...method.kinematics import KinematicModel
from . import elimination
from .drift import HeadingDrift
from .effect import Effect
from .result import Step, errors
from .subject import Subject, analyse_subjects

AGREE = 0.3  # the bias' vertical part within this share of the drift's rate: the pair is one drift


def _of_its_rate(s: Subject, drift: Effect, bias: Effect) -> bool:
    """Whether the bias' part about the world vertical (its sensor's orientations, averaged over the
    recording) is the drift's rate in size, within AGREE: only then are the two one drift its gyro
    shares (a magnetic drift beside a small bias of its gyro is two effects)."""
    assert s.source is not None, "set by the loop"
    recording = s.source[0]
    R = recording.orientation[:, recording.links.index(drift.target)]  # [T,3,3] sensor to world
    vertical = float(np.nanmean((R @ np.asarray(bias.params["bias"]))[:, 2]))
    rate = abs(float(drift.params["rate"]))
    return abs(abs(vertical) - rate) <= AGREE * rate


def merge(subjects: Sequence[Subject], links, gain: float, progress: bool, max_samples: int, worse: float,
          say: Callable[[str], None]) -> None:
    """Each subject's pairs (an unaware drift, a gyro bias on its sensor) replaced by a shared drift
    where that tracks as well (`worse`: the share by which neither error may rise)."""
    for s in subjects:
        for drift in [e for e in s.effects if e.kind == "heading_drift" and not e.params.get("gyro_shares")]:
            bias = next((e for e in s.effects if e.kind == "gyro_bias" and e.target == drift.target), None)
            if bias is None or drift not in s.effects or not _of_its_rate(s, drift, bias):
                continue
            others = [e for e in s.effects if e is not drift and e is not bias]
            assert s.source is not None, "set by the loop"
            recording, urdf = elimination.without(*s.source, others, None)
            model = s.model if urdf == s.urdf else KinematicModel.from_urdf(urdf, name=s.model.name, dtype=s.model.dtype)
            trial = Subject(recording, urdf, model, source=s.source, chunking=s.chunking)
            analyse_subjects([trial], links, gain, progress, max_samples)
            trial.derived = s.derived
            shared = trial.refit(HeadingDrift("heading_drift", drift.target, dict(gyro_shares=True)))
            if shared is None or not shared.params.get("gyro_shares") or shared.implausible():
                continue
            before = errors(*s.current).overall
            trial.add(shared)
            analyse_subjects([trial], links, gain, progress, max_samples)
            after = errors(*trial.current).overall
            if any(after[key] > before[key] * (1 + worse) for key in ("mnte", "rmse")):
                continue
            shared.notes = "; ".join(filter(None, [shared.notes, (
                f"in place of {drift.summary()} and {bias.summary()}: the two together are this drift, its gyro "
                f"sharing it, with one parameter for four")]))
            steps = [st for st in s.steps if st.effect is not drift and st.effect is not bias]
            s.steps = steps + [Step(shared, errors(*s.current), errors(*trial.current))]
            s.recording, s.urdf, s.model, s.analysis = trial.recording, trial.urdf, trial.model, trial.analysis
            for e in (drift, bias):
                e.notes = "; ".join(filter(None, [e.notes, f"replaced, with its pair, by {shared.summary()}"]))
            s.rejected += [drift, bias]
            say(f"{drift.kind} at {drift.target} and its gyro's bias: one drift its gyro shares instead")

"""What each kept effect changes in what a report shows, and the effects that change nothing of it.

Significance says the data show an effect; its family's floor (Effect.below_floor) says its size
matters. An effect seen only in the orientations (a sensor's turned frame, a heading drift, a moved
limit, a late sensor) can pass both and still change nothing anyone reports: the joints follow it,
or it acts on a few samples, or its size is spread over a chain of small joints.
Its contribution is measured as what it changes once tracked: the subject with every kept effect
against the subject without that one (elimination.variants), compared on

- the estimated joint angles and the base's orientation (what a gait report shows), and
- the orientation residual each tracked link is left with (what the tracker could not follow),

each as an rms over the time after TRANSIENT, the largest over joints and links. Under VISIBLE
(1 deg, the misalignment's floor: joint angles are reported to about a degree) the effect is listed
as significant but negligible and taken out. The gyro's families (a bias, a scale error, a stream's
delay) are judged on the gyro's own stream, which the tracker uses only through its gain, and keep
their floors in rate units.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import torch

from ...method.kinematics import KinematicModel
from ...method.state import Trajectory
from ..evaluation import link_motion
from . import elimination
from .analysis import Analysis, analyse, orientation_residual, sequence_of, track
from .chunks import Chunking
from .subject import Subject, analyse_subjects, one_of

VISIBLE = 1.0  # deg
TRANSIENT = 2.0  # s, the tracker's start left out
# a missing axis is not among them: the joint angle it adds is itself what a report shows, and its
# floor (joints.AXIS_FLOOR) already asks that angle to move by a degree
SEEN_IN_ORIENTATIONS = ("misalignment", "heading_drift", "joint_limit", "sensor_delay")


def _rms(x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """[...] the rms over the kept rows of x [T,...] (NaN rows left out)."""
    x = torch.where(keep.reshape(-1, *([1] * (x.dim() - 1))) & x.isfinite(), x, torch.nan)
    return x.square().nanmean(0).sqrt()


class Tracked(NamedTuple):
    """What `change` compares of a tracked recording: time [T], the model's joint names, joint angles
    s [T,n], base rotation [T,3,3], tracked links and each one's residual angle [T,L] (rad, NaN where
    its streams are not valid)."""

    time: torch.Tensor
    joint_names: tuple[str, ...]
    s: torch.Tensor
    base_rotation: torch.Tensor
    links: tuple[str, ...]
    angle: torch.Tensor
    trajectory: Trajectory | None = None  # the run itself, a batch of one (`tracked`'s)


def of_analysis(analysis: Analysis, b: int) -> Tracked:
    """Subject b of an analysis as `change` compares it (the angle of its residual r, whose norm is
    the angle's sine)."""
    angle = torch.where(analysis.valid[:, b], torch.asin(analysis.r[:, b].norm(dim=-1).clamp(max=1.0)), torch.nan)
    return Tracked(analysis.time, analysis.model.joint_names, analysis.s[:, b], analysis.trajectory.base_rotation[:, b],
                   analysis.links, angle)


def change(with_: Tracked, without: Tracked, transient: float = TRANSIENT) -> tuple[float, str]:
    """deg, and where: the largest rms change, after `transient` seconds, of a joint angle (the joints
    both models have), of the base's orientation, or of a link's residual angle, between two tracked
    runs of the same recording (one with an effect, one without)."""
    a, b = with_, without
    keep = a.time >= a.time[0] + (transient if float(a.time[-1] - a.time[0]) > 2 * transient else 0.0)
    shared = [n for n in a.joint_names if n in b.joint_names]
    sa = a.s[:, [a.joint_names.index(n) for n in shared]]
    sb = b.s[:, [b.joint_names.index(n) for n in shared]]
    joints = torch.rad2deg(_rms(sa - sb, keep))  # [n]
    cos = ((a.base_rotation.transpose(-1, -2) @ b.base_rotation).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    base = torch.rad2deg(_rms(torch.acos(cos.clamp(-1.0, 1.0)), keep))
    links = torch.rad2deg(_rms(a.angle - b.angle, keep))  # [L]
    found = [(float(v), f"the {name} angle") for name, v in zip(shared, joints.tolist())]
    found += [(float(base), "the base's orientation")]
    found += [(float(v), f"the {name} residual") for name, v in zip(a.links, links.tolist())]
    found = [f for f in found if math.isfinite(f[0])]
    return max(found) if found else (0.0, "nothing")


def tracked(variants: Sequence[Subject], links, gain: float, progress: bool) -> list[Tracked]:
    """Each of `variants` tracked (as the loop's analyses track: one batch per model, the chunking
    its subject's), without the rest of an analysis: what `change` compares."""
    links = tuple(links)
    groups: dict[int, list[int]] = {}
    for k, v in enumerate(variants):
        groups.setdefault(id(v.model), []).append(k)
    out: list[Tracked | None] = [None] * len(variants)
    for members in groups.values():
        model, recordings = variants[members[0]].model, [variants[k].recording for k in members]
        chunking = Chunking(all(variants[k].chunking.on for k in members))
        trajectory = track(model, recordings, links, gain, progress, chunking=chunking)
        if not chunking.on:  # as analyse_subjects: the chunks disagreed, their subject tracks in one piece
            for k in members:
                variants[k].chunking.on = False
        sequence = sequence_of(recordings, links, model.dtype)
        R_hat = link_motion(model, trajectory, links)[0]
        valid, r = orientation_residual(sequence.rotation, sequence.angular_velocity, R_hat)
        valid = valid & torch.cat((valid[:1], valid[:-1])) & torch.cat((valid[1:], valid[-1:]))  # as analyse's
        angle = torch.where(valid, torch.asin(r.norm(dim=-1).clamp(max=1.0)), torch.nan)
        for b, k in enumerate(members):
            out[k] = Tracked(sequence.time, model.joint_names, trajectory.joint_positions[:, b],
                             trajectory.base_rotation[:, b], links, angle[:, b], one_of(trajectory, b))
    return [t for t in out if t is not None]


def drop_invisible(subjects: Sequence[Subject], links, gain: float, progress: bool, max_samples: int,
                   say: Callable[[str], None]) -> None:
    """Move the kept effects seen only in the orientations (SEEN_IN_ORIENTATIONS) whose contribution
    (`change`) is under VISIBLE to the subject's negligible ones; the subjects that lose one are
    rebuilt from their source without them and tracked again."""
    found = [v for s in subjects if s.effects for v in elimination.variants(s, s.effects, every=True)
             if v[1].kind in SEEN_IN_ORIENTATIONS]
    if not found:
        return
    runs = tracked([v for _, _, v in found], links, gain, progress)
    moved: dict[int, Subject] = {}
    dropped: dict[int, list[Tracked]] = {}  # per subject, the runs without each effect it loses
    for (s, effect, _), run in zip(found, runs):
        size, where = change(of_analysis(*s.current), run)
        effect.params["contribution_deg"] = size
        if size >= VISIBLE:
            continue
        why = (f"significant but negligible: tracked with and without it, nothing a report shows changes by "
               f"{VISIBLE:g} deg (at most {size:.2f} deg rms, {where})")
        effect.notes = "; ".join(filter(None, [effect.notes, why]))
        s.negligible[(effect.kind, effect.target)] = effect
        s.steps = [st for st in s.steps if st.effect is not effect]
        moved[id(s)] = s
        dropped.setdefault(id(s), []).append(run)
        say(f"{effect.kind} at {effect.target} taken out as negligible ({why})")
    again = []
    for s in moved.values():
        assert s.source is not None, "set by the loop"
        s.recording, s.urdf = elimination.without(*s.source, s.effects, None)
        s.model = KinematicModel.from_urdf(s.urdf, name=s.model.name, dtype=s.model.dtype)
        run = dropped[id(s)][0]
        if len(dropped[id(s)]) == 1 and run.trajectory is not None:
            # without its one negligible effect the subject is that variant, tracked already
            s.analysis = (analyse(s.model, [s.recording], links, run.trajectory, gain, max_samples), 0)
        else:
            again.append(s)
    analyse_subjects(again, links, gain, progress, max_samples)

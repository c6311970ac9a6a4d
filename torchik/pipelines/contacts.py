"""Contacts from the motion: when a foot is on the ground, how far it slides while it is, and the
tasks `torchik track --contacts`, `--com` and `--posture` add to the step.

A link is on the ground where its origin is within HEIGHT of the lowest it goes over the run and
moves horizontally slower than SPEED (a foot in stance rolls over its heel and toes, its origin
moves by centimetres per second; in swing by metres per second). Its slide in a contact phase is
the largest horizontal distance its origin travels from where the phase began.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ..errors import InputError
from ..method.constraints import ContactLimit, Limit
from ..method.kinematics import KinematicModel
from ..method.kinematics.mass import centre_of_mass
from ..method.state import TargetSequence, Trajectory
from ..method.tasks import ContactTask, PostureTask, StepContext, Task, TaskTerms

FEET = {"human66": ("RightFoot", "LeftFoot"), "human48": ("RightFoot", "LeftFoot"), "icub": ("r_foot", "l_foot")}
HEIGHT = 0.03  # m above the lowest the link goes
SPEED = 0.3  # m/s, horizontal
CONTACT_WEIGHT = 100.0  # a contact against each target's 1: stiff, yet a wrong switch costs a little, not a jump
GROUND_PERCENTILE = 2.0  # the lowest the link goes: a low percentile, not the minimum (one bad frame)


def contact_mask(position: np.ndarray, time: np.ndarray, height: float = HEIGHT, speed: float = SPEED) -> np.ndarray:
    """[T] bool: on the ground, from the link's origin [T,3] (world, z up) at `time` [T] (s). NaN
    positions are not in contact."""
    if len(time) < 3:
        return np.zeros(len(time), dtype=bool)
    z = position[:, 2]
    ground = np.nanpercentile(z, GROUND_PERCENTILE) if np.isfinite(z).any() else np.nan
    velocity = np.gradient(position[:, :2], time, axis=0)
    return (z - ground < height) & (np.linalg.norm(velocity, axis=-1) < speed)


def slide_series(position: np.ndarray, on: np.ndarray) -> np.ndarray:
    """[T] mm: while `on`, the horizontal distance of the link's origin [T,3] from where the contact
    phase began; NaN while off (what the rerun recording draws)."""
    out = np.full(len(on), np.nan)
    start = None
    for k in range(len(on)):
        start = (k if start is None else start) if on[k] else None
        if start is not None:
            out[k] = 1e3 * np.linalg.norm(position[k, :2] - position[start, :2])
    return out


def foot_slide(position: np.ndarray, on: np.ndarray) -> dict:
    """The link's slide over its contact phases (`on` [T] runs of 2 samples or more), from its origin
    [T,3]: per phase the largest horizontal distance from where it began (mm, `slide_series`); their
    mean and largest, and how many."""
    series = slide_series(position, on)
    starts = np.flatnonzero(on & ~np.concatenate(([False], on[:-1])))
    ends = np.append(starts[1:], len(on))
    slides = [float(np.nanmax(series[a:b])) for a, b in zip(starts, ends) if on[a:b].sum() >= 2]
    return dict(phases=len(slides), mean_mm=float(np.mean(slides)) if slides else None,
                max_mm=float(np.max(slides)) if slides else None)


class LinkPositions:
    """An output (pipelines.track) that keeps subject 0's positions of `links` [T,L,3] over the run."""

    def __init__(self, model: KinematicModel, links: Sequence[str]):
        self.model, self.links = model, tuple(links)
        self.parts: list[np.ndarray] = []
        self.times: list[np.ndarray] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None:
        out = self.model(trajectory.base_position[:, 0], trajectory.base_rotation[:, 0],
                         trajectory.joint_positions[:, 0], self.links, jacobian=False)
        assert out.position is not None  # a forward call gives positions
        self.parts.append(out.position.cpu().numpy())
        self.times.append(trajectory.time.cpu().numpy())

    @property
    def position(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros((0, len(self.links), 3))

    @property
    def time(self) -> np.ndarray:
        return np.concatenate(self.times) if self.times else np.zeros(0)


class PostureDistance:
    """An output (pipelines.track) that keeps the rms [T] (rad) over the joints of subject 0's angles
    from the zero posture (what --posture pulls towards)."""

    def __init__(self) -> None:
        self.parts: list[np.ndarray] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None:
        self.parts.append(trajectory.joint_positions[:, 0].square().mean(-1).sqrt().cpu().numpy())

    @property
    def distance(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros(0)


@dataclass
class CentreOfMassOverFeet(Task):
    """The centre of mass held, horizontally, over the middle of the `feet` (a static balance prior,
    weak by default: walking carries it between them)."""

    feet: tuple[str, ...] = ()
    weight: float = 0.1
    name: str = field(default="centre of mass over the feet", kw_only=True)

    def terms(self, context: StepContext) -> TaskTerms:
        q, model = context.state, context.model
        com = centre_of_mass(model, q.base_position, q.base_rotation, q.joint_positions)
        feet = model(q.base_position, q.base_rotation, q.joint_positions, self.feet)
        assert com.jacobian is not None and feet.position is not None and feet.jacobian is not None
        middle, J_middle = feet.position.mean(1), feet.jacobian[:, :, :3].mean(1)
        return TaskTerms((middle - com.position)[:, :2], (com.jacobian - J_middle)[:, :2])


def tracking_tasks(model: KinematicModel, model_name: str, contacts: Sequence[str] | None, masks: dict[str, np.ndarray],
               com: float | None, posture: float | None,
               contact_weight: float = CONTACT_WEIGHT) -> tuple[list[Task], list[Limit]]:
    """The tasks and limits of `torchik track`'s --contacts (links, each with its [T] mask; weight
    contact_weight, inf: equality rows), --com (weight) and --posture (weight)."""
    tasks: list[Task] = []
    limits: list[Limit] = []
    for link in contacts or ():
        if link not in model.link_names:
            raise InputError(f"--contacts: model {model.name!r} has no link {link!r}")
        on = torch.as_tensor(masks[link], device=model.device)[:, None]
        if math.isinf(contact_weight):
            limits.append(ContactLimit(contact=ContactTask(link=link, on=on), name=f"contact {link}"))
        else:
            tasks.append(ContactTask(link=link, on=on, weight=contact_weight, name=f"contact {link}"))
    if com:
        tasks.append(CentreOfMassOverFeet(weight=com, feet=FEET[model_name]))
    if posture:
        tasks.append(PostureTask(weight=posture))
    return tasks, limits


class CentreOfMassOffsets:
    """An output (pipelines.track) that keeps the horizontal distance [T] (m) of subject 0's centre of
    mass from the middle of its `feet` over the run."""

    def __init__(self, model: KinematicModel, feet: Sequence[str]):
        self.model, self.feet = model, tuple(feet)
        self.parts: list[np.ndarray] = []
        self.times: list[np.ndarray] = []

    def write(self, trajectory: Trajectory, targets: TargetSequence) -> None:
        args = (trajectory.base_position[:, 0], trajectory.base_rotation[:, 0], trajectory.joint_positions[:, 0])
        com = centre_of_mass(self.model, *args, jacobian=False).position
        out = self.model(*args, self.feet, jacobian=False)
        assert out.position is not None  # a forward call gives positions
        self.parts.append((out.position.mean(1) - com)[:, :2].norm(dim=-1).cpu().numpy())
        self.times.append(trajectory.time.cpu().numpy())

    @property
    def offset(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros(0)

    @property
    def time(self) -> np.ndarray:
        return np.concatenate(self.times) if self.times else np.zeros(0)


def task_report(contacts, masks, before, after, com, posture, com_weight, posture_weight) -> dict:
    """Each added task's error: a contact's slide per phase before (the run without) and after (mm),
    the centre of mass' horizontal distance from the middle of the feet (m), the joints' rms distance
    from the posture (rad), medians over the run (`torchik track`'s report["tasks"]). before, after:
    LinkPositions of the contacts' links without and with them; com, posture: CentreOfMassOffsets and
    PostureDistance (None where the task is not added)."""
    out: dict = {}
    for k, link in enumerate(contacts):
        on = masks[link][:len(after.time)]
        out[f"contact {link}"] = dict(contact_share=float(on.mean()) if len(on) else None,
                                      slide_before=foot_slide(before.position[:len(on), k], on),
                                      slide_after=foot_slide(after.position[:, k], on))
    if com is not None:
        offset = com.offset
        out["centre of mass over the feet"] = dict(weight=com_weight, median_offset_m=float(np.nanmedian(offset))
                                                   if len(offset) else None)
    if posture is not None:
        distance = posture.distance
        out["posture"] = dict(weight=posture_weight, median_rms_rad=float(np.median(distance)) if len(distance) else None)
    return out


def log_tasks(rrd, contacts, masks, after, com) -> None:
    """The added tasks over time in the rerun recording, under tasks/: each contact's switch and
    slide (mm, from where its phase began), the centre of mass' offset from the feet (m); rrd: an
    RrdWriter before its commit."""
    from rerun import escape_entity_path_part as escape

    time = after.time
    for k, link in enumerate(contacts):
        on = masks[link][:len(time)]
        series = np.stack((on.astype(float), slide_series(after.position[:, k], on)), axis=1)
        rrd.log_series(f"tasks/{escape(f'contact {link}')}", time, series, ["on", "slide (mm)"])
    if com is not None and com.parts:
        rrd.log_series(f"tasks/{escape('centre of mass over the feet')}", com.time, com.offset, ["offset (m)"])

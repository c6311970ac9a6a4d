"""The forces of a measured motion: a recording tracked, its force plates' ground reactions put on
the model's feet, and the inverse dynamics along the trajectory (the pipeline behind `torchik
dynamics`; the conventions are docs/dynamics.md's).

- **Tracking**: as `torchik track` does (`track_recording`, from rest in the first frame's posture).
- **Ground reactions**: the recording's `external_wrench` [T,n,6] (force N, moment N m about the
  world origin, world frame), which `read_c3d` gives each foot standing on a plate and a link map
  carries to the model's foot link, on the links that ever carry one. `inverse_dynamics` takes the
  moment about each link's origin. By default (`wrench_at="segment"`) it is taken about the
  recording's own origin of the link's segment (`position`; Plug-in Gait's foot: the ankle joint
  centre), the point the markers measured the centre of pressure from, and put on the model's link:
  the model's foot may sit a few millimetres off the markers' (its segment lengths, joint limits
  the motion goes beyond), and the lever arm about the ankle stays the measured one. With
  `wrench_at="model"` (or where the segment's origin is not measured) it is taken about the model's
  link origin: the force acts where the plate measured it in the world, as the base's residual
  moment assumes. The wrenches are used as the reader gives them (the plates' channels low-passed at
  0.3 of the frame rate, analog.py), as Plug-in Gait does; `wrench_cutoff` low-passes them too.
- **Dynamics**: `trajectory_dynamics` at `cutoff` (6 Hz): torques and powers of every joint, and the
  base's residual wrench, what no plate explains.
- **Where the plates see every foot**: a foot on the floor off the plates has a ground reaction no
  plate measures; the residual carries it. `covered` marks the frames where every foot on the ground
  stands on a plate: the ground is told from the file's gait events where it has them (Vicon's "Foot
  Strike" and "Foot Off"), else from the model's feet (within 3 cm of the lowest they go and slower
  than 0.3 m/s). A foot whose heel or toe overhangs its plate's edge (`io/foot_contacts.py`) may rest
  partly on the floor beside it: it does not count as on a plate there. Over those frames the residual
  measures how far the model's masses and the tracked motion agree with the plates.
- **The residual's frames** (`residual_frames`): the covered ones with a plate loaded, less those
  within the motion's low-pass' `reach` (6 frames at 6 Hz and 100 Hz) of one the plates do not
  cover: the residual compares the motion and the plates through the same filter (the loop on
  forces', `dynamics_loop.py`), and a filtered plate sample there mixes in frames where a foot's
  reaction is missing.

The sagittal plane of the human models: each leg joint's y degree of freedom is its flexion axis
(x forward, y left, z up in the zero posture); a positive turn about y is hip extension, knee
flexion and ankle plantarflexion. `EXTENSOR` signs a torque about it into the gait convention's
moment, extensor (plantarflexor) positive, which Plug-in Gait uses.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording
from ..method.dynamics import CUTOFF, low_pass, reach, trajectory_dynamics
from ..method.dynamics.inverse import GRAVITY
from ..method.kinematics import KinematicModel
from ..method.kinematics.mass import total_mass
from ..method.settings import TrackerSettings
from ..method.state import Trajectory
from .contacts import contact_mask
from .dynamics_effects import shift
from .track import SETTLE, track_recording

SIDES = ("Right", "Left")
JOINTS = ("Hip", "Knee", "Ankle")
EXTENSOR = {"Hip": 1.0, "Knee": -1.0, "Ankle": 1.0}  # the y torque's sign of an extensor (plantarflexor) moment
AT_LIMIT = 1e-3  # rad from a limit: a joint held there
NO_LIMIT = 19.9  # rad: a range this wide is no limit (URDFs write +-10 rad for none)
WrenchAt = Literal["segment", "model"]
WRENCH_AT = ("segment", "model")


@dataclass
class MotionDynamics:
    """A tracked motion's forces, subject 0, over time [T] (s).

    joint_positions [T,n] (rad), joint_velocities [T,n] (rad/s, low-passed as the dynamics used them),
    joint_torques [T,n] (N m), joint_powers [T,n] (W), in `joint_names`' order; base_wrench [T,6] the
    residual (force N; moment N m about the base's origin, world axes); wrench_links [L] the links with
    ground reactions, wrenches [T,L,6] theirs as measured (force N; moment N m about the world origin,
    world frame; NaN where one plate carried two feet), stance [T,L] where a plate's contact is on the
    link; covered [T] where every foot on the ground stands on a plate (module docstring); mass (kg,
    the model's); trajectory the tracked one, its velocity on the frames (`centred`); tracking its
    report; notes: how it was computed."""

    time: np.ndarray
    joint_names: tuple[str, ...]
    joint_positions: np.ndarray
    joint_velocities: np.ndarray
    joint_torques: np.ndarray
    joint_powers: np.ndarray
    base_wrench: np.ndarray
    wrench_links: tuple[str, ...]
    wrenches: np.ndarray
    stance: np.ndarray
    covered: np.ndarray
    mass: float
    trajectory: Trajectory
    tracking: dict
    notes: dict = field(default_factory=dict)

    @property
    def weight(self) -> float:
        """The body's weight (N)."""
        return self.mass * float(np.linalg.norm(GRAVITY))

    def residual_force(self) -> np.ndarray:
        """[T,3] the base's residual force as a fraction of body weight."""
        return self.base_wrench[:, :3] / self.weight

    def residual_moment(self) -> np.ndarray:
        """[T,3] the base's residual moment (about its origin) per kg of body mass, N m/kg."""
        return self.base_wrench[:, 3:] / self.mass

    def joint(self, side: str, joint: str, axis: str = "y") -> int:
        """The column of a leg joint's degree of freedom (side "Right"/"Left", joint "Hip"/"Knee"/"Ankle")."""
        name = f"j{side}{joint}_rot{axis}"
        if name not in self.joint_names:
            raise InputError(f"the model has no joint {name}: the sagittal plane is the human models' (Human66, Human48)")
        return self.joint_names.index(name)

    def sagittal(self, side: str, joint: str) -> tuple[np.ndarray, np.ndarray]:
        """[T] the joint's sagittal moment per kg (N m/kg, extensor or plantarflexor positive) and its
        power per kg (W/kg, positive when it generates)."""
        k = self.joint(side, joint)
        return EXTENSOR[joint] * self.joint_torques[:, k] / self.mass, self.joint_powers[:, k] / self.mass

    def total_power(self, side: str, joint: str) -> np.ndarray:
        """[T] the joint's power over all its degrees of freedom per kg (W/kg)."""
        columns = [k for k, name in enumerate(self.joint_names) if name.startswith(f"j{side}{joint}_rot")]
        return self.joint_powers[:, columns].sum(-1) / self.mass

    def foot(self, side: str) -> str | None:
        """The link of `side`'s foot among the links with ground reactions (None if it has none)."""
        return next((link for link in self.wrench_links if link.startswith(side) and "Foot" in link), None)

    def cop(self) -> np.ndarray:
        """[T,L,3] each link's centre of pressure on the floor z = 0 (m, world; NaN where unloaded):
        the point about which its moment has no horizontal part."""
        f, m = self.wrenches[..., :3], self.wrenches[..., 3:]
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.stack((-m[..., 1], m[..., 0], np.zeros_like(f[..., 2])), -1) / f[..., 2:3]
        return np.where(self.stance[..., None] & (f[..., 2:3] > 0), p, np.nan)


def motion_dynamics(model: KinematicModel, recording: Recording, links: Sequence[str] | None = None, *,
                    settings: TrackerSettings | None = None, cutoff: float = CUTOFF, wrench_cutoff: float | None = None,
                    wrench_at: WrenchAt = "segment", plates: bool = True, progress: bool = False,
                    settle: float = SETTLE) -> MotionDynamics:
    """Track `recording` (in the model's links: mapped already) on `links` (default its links that are
    the model's) and compute its forces with the ground reactions it carries (module docstring).
    plates=False computes without any (the base's residual is then the whole ground reaction).
    InputError when the recording has no ground reactions and plates is True, or none on the model's links."""
    links = tuple(link for link in (links or recording.links) if link in model.link_names)
    if wrench_at not in WRENCH_AT:
        raise InputError(f"wrench_at {wrench_at!r}: expected one of {', '.join(WRENCH_AT)}")
    source = recording.meta.get("source", "the recording")
    wrench_links: tuple[str, ...] = ()
    measured = None
    if plates:
        if recording.external_wrench is None:
            raise InputError(f"{source} has no ground reactions (no force plates, or none read): give a file with "
                             f"plates, or compute without them (plates=False, --no-plates), the base's residual then "
                             f"carrying the whole ground reaction")
        carried = ~np.all(recording.external_wrench == 0.0, axis=(0, 2))  # NaN counts as carried
        wrench_links = tuple(link for link, on in zip(recording.links, carried) if on)
        outside = [link for link in wrench_links if link not in model.link_names]
        if outside:
            raise InputError(f"{source}: ground reactions on {outside}, which are not links of {model.name}: map the "
                             f"recording onto the model's links first")
        measured = recording.external_wrench[:, [recording.links.index(link) for link in wrench_links]]
    if recording.position is None:
        wrench_at = "model"  # no segment origin measured: the model's is the only one
    trajectory, report = track_recording(model, recording, links, settings, progress=progress, settle=settle)
    trajectory = centred(trajectory)
    T = len(trajectory.time)
    wrenches = np.zeros((T, 0, 6)) if measured is None else measured[:T]
    stance = np.abs(np.nan_to_num(wrenches, nan=1.0)).sum(-1) > 0
    notes = dict(cutoff_hz=cutoff, wrench_cutoff_hz=wrench_cutoff, wrench_at=wrench_at if wrench_links else None,
                 at_limits=at_limits(model, trajectory),
                 plates=recording.meta.get("force_plates"), events=recording.meta.get("events", []), source=source,
                 link_map=(recording.meta.get("link_map") or {}).get("name"))
    empty = np.zeros((T, 0))
    result = MotionDynamics(time=trajectory.time.detach().cpu().double().numpy(), joint_names=tuple(model.joint_names),
                            joint_positions=empty, joint_velocities=empty, joint_torques=empty, joint_powers=empty,
                            base_wrench=empty, wrench_links=wrench_links, wrenches=wrenches, stance=stance,
                            covered=np.zeros(T, dtype=bool), mass=0.0, trajectory=trajectory, tracking=report,
                            notes=notes)
    result = with_forces(result, model, recording, wrenches)
    overhang = overhanging(recording, wrench_links, T)
    result.notes["overhang_frames"] = {link: int(n) for link, n in zip(wrench_links, overhang.sum(0)) if n}
    result.covered = covered_frames(result, model, overhang)
    return result


def centred(trajectory: Trajectory) -> Trajectory:
    """The trajectory with its velocity [T,1,6+n] read half a step later: the tracker's velocity at a
    frame is its step's, the mean over the step that ends there (scheme.py), the velocity half a step
    before the frame; its derivative, the acceleration, would be half a step late on the positions
    and on the plates (5 ms at 100 Hz, which the loop on forces then finds as the plates' lag)."""
    T = len(trajectory.time)
    if T < 3:
        return trajectory
    rate = 1.0 / float(trajectory.time.diff().double().mean())
    return replace(trajectory, velocity=shift(trajectory.velocity, rate, 0.5 / rate))


def with_forces(dynamics: MotionDynamics, model: KinematicModel, recording: Recording,
                wrenches: np.ndarray) -> MotionDynamics:
    """The forces of `dynamics`' tracked motion with `model`'s masses and the ground reactions
    `wrenches` [T,L,6] on its `wrench_links` (force N, moment N m about the world origin), computed as
    its notes say (cutoffs, the point the moments are taken about); its stance and covered frames kept.
    What `motion_dynamics` computes once tracked, and the loop on forces again with the masses and the
    plates corrected (`dynamics_loop.py`)."""
    trajectory, notes = dynamics.trajectory, dynamics.notes
    T = len(trajectory.time)
    about = None
    if dynamics.wrench_links:
        about = _wrench_origins(model, recording, trajectory, dynamics.wrench_links, notes["wrench_at"])
    rate = 1.0 / float(np.median(np.diff(recording.time))) if T > 1 else 1.0
    forces = trajectory_dynamics(model, trajectory, _about(wrenches, about, model, rate, notes["wrench_cutoff_hz"]),
                                 dynamics.wrench_links or None, cutoff=notes["cutoff_hz"])
    velocity = low_pass(trajectory.velocity, rate, notes["cutoff_hz"]) if T > 2 else trajectory.velocity
    host = lambda x: x[:, 0].detach().cpu().double().numpy()  # noqa: E731
    return replace(dynamics, joint_positions=host(trajectory.joint_positions), joint_velocities=host(velocity[..., 6:]),
                   joint_torques=host(forces.joint_torques), joint_powers=host(forces.joint_powers),
                   base_wrench=host(forces.base_wrench), wrenches=wrenches, mass=float(total_mass(model)[0]))


def at_limits(model: KinematicModel, trajectory: Trajectory, within: float = AT_LIMIT) -> dict[str, int]:
    """The joints that sat on a limit (within `within` rad of an effective one), and for how many frames:
    where the motion went beyond the model's range, which the tracker then bent the neighbours to follow."""
    lower, upper = (x.detach().cpu().double().numpy() for x in (model.lower, model.upper))
    s = trajectory.joint_positions[:, 0].detach().cpu().double().numpy()
    effective = np.isfinite(lower) & np.isfinite(upper) & (upper - lower < NO_LIMIT)
    held = ((s <= lower + within) | (s >= upper - within)) & effective
    return {name: int(n) for name, n in zip(model.joint_names, held.sum(0)) if n}


def link_origins(model: KinematicModel, trajectory: Trajectory, links: Sequence[str]) -> np.ndarray:
    """[T,L,3] the links' origins (m, world) along the trajectory (subject 0)."""
    with torch.no_grad():
        kin = model(trajectory.base_position[:, 0], trajectory.base_rotation[:, 0], trajectory.joint_positions[:, 0],
                    tuple(links), jacobian=False)
    assert kin.position is not None  # positions are computed unless asked not to be
    return kin.position.detach().cpu().double().numpy()


def _wrench_origins(model: KinematicModel, recording: Recording, trajectory: Trajectory, links: tuple[str, ...],
                    wrench_at: WrenchAt) -> np.ndarray:
    """[T,L,3] the point (m, world) each link's moment is taken about: the model's link origin, or the
    recording's origin of its segment where measured (wrench_at "segment")."""
    origin = link_origins(model, trajectory, links)
    if wrench_at == "model" or recording.position is None:
        return origin
    segment = recording.position[:len(origin), [recording.links.index(link) for link in links]]
    return np.where(np.isfinite(segment).all(-1, keepdims=True), segment, origin)


def _about(wrenches: np.ndarray, origins: np.ndarray | None, model: KinematicModel, rate: float,
           cutoff: float | None) -> torch.Tensor | None:
    """[T,1,L,6] the wrenches [T,L,6] (moment about the world origin) with their moments about
    `origins` [T,L,3], low-passed at `cutoff` Hz when given, as trajectory_dynamics takes them."""
    if origins is None:
        return None
    force = wrenches[..., :3]
    moved = np.concatenate((force, wrenches[..., 3:] - np.cross(origins, force)), -1)
    out = torch.as_tensor(moved, dtype=model.dtype, device=model.device)
    if cutoff is not None:
        if not 0.0 < cutoff < rate / 2:
            raise InputError(f"wrench cutoff {cutoff} Hz: expected above 0 and below half the rate ({rate / 2:g} Hz)")
        unknown = out.isnan()  # a plate two feet shared: filtered as zero, unknown again after
        out = low_pass(out.nan_to_num(0.0), rate, cutoff).masked_fill(unknown, torch.nan)
    return out[:, None]


def overhanging(recording: Recording, links: Sequence[str], frames: int) -> np.ndarray:
    """[T,L] where each of `links` overhangs the plate whose contact it has (the reader's contacts'
    overhang_frames, through the link map's segments; none where the recording kept no contacts)."""
    out = np.zeros((frames, len(links)), dtype=bool)
    contacts = ((recording.meta.get("force_plates") or {}).get("contacts")) or []
    to_link = {segment: link for link, segment in ((recording.meta.get("link_map") or {}).get("segments") or {}).items()}
    for contact in contacts:
        link = to_link.get(contact.get("link"), contact.get("link"))
        if link in links:
            for start, stop in contact.get("overhang_frames") or []:
                out[start:min(stop, frames), list(links).index(link)] = True
    return out


def residual_frames(dynamics: MotionDynamics) -> np.ndarray:
    """[T] the frames the residual is measured on (module docstring): covered, a plate loaded, the
    plates known, and no frame within the motion's low-pass' reach that is not."""
    T = len(dynamics.time)
    if not dynamics.wrench_links or T < 2:
        return np.zeros(T, dtype=bool)
    seen = dynamics.covered & np.isfinite(dynamics.wrenches).all((1, 2))
    k = reach(1.0 / float(np.median(np.diff(dynamics.time))), dynamics.notes["cutoff_hz"])
    near = np.convolve((~seen).astype(float), np.ones(2 * k + 1), mode="same") > 0  # within k of an unseen frame
    return seen & ~near & dynamics.stance.any(-1)


def covered_frames(dynamics: MotionDynamics, model: KinematicModel, overhang: np.ndarray | None = None) -> np.ndarray:
    """[T] the frames where every foot on the ground stands on a plate (module docstring); overhang
    [T,L] where a foot of `wrench_links` overhangs its plate (`overhanging`)."""
    T = len(dynamics.time)
    covered = np.ones(T, dtype=bool)
    for side in SIDES:
        foot = f"{side}Foot"
        if foot not in model.link_names:
            continue
        ground = _stance_from_events(dynamics.notes.get("events") or [], side, T)
        if ground is None:
            ground = contact_mask(link_origins(model, dynamics.trajectory, (foot,))[:, 0], dynamics.time)
        on_plate = dynamics.stance[:, dynamics.wrench_links.index(foot)] if foot in dynamics.wrench_links else \
            np.zeros(T, dtype=bool)
        if overhang is not None and foot in dynamics.wrench_links:
            on_plate = on_plate & ~overhang[:, dynamics.wrench_links.index(foot)]
        covered &= ~ground | on_plate
    return covered


def _stance_from_events(events: list[dict], side: str, frames: int) -> np.ndarray | None:
    """[T] the side's foot on the ground from the gait events ("Foot Strike" to "Foot Off" of its side;
    before its first event, the opposite of that event's); None without events of that side."""
    mine = [e for e in events if e.get("context") == side and e.get("label") in ("Foot Strike", "Foot Off")]
    if not mine:
        return None
    ground = np.zeros(frames, dtype=bool)
    state = mine[0]["label"] == "Foot Off"  # before a foot off, the foot was down
    start = 0
    for event in mine:
        ground[start:event["frame"]] = state
        state, start = event["label"] == "Foot Strike", event["frame"]
    ground[start:] = state
    return ground


def gait_cycles(dynamics: MotionDynamics, side: str) -> list[tuple[int, int]]:
    """The gait cycles [start, stop) of `side` (frames, from one "Foot Strike" of its side to the next)
    whose stance is on a plate (its foot loads one within 5 frames of the strike); empty without events."""
    foot = dynamics.foot(side)
    if foot is None:
        return []
    strikes = [e["frame"] for e in dynamics.notes.get("events") or []
               if e.get("context") == side and e.get("label") == "Foot Strike"]
    on = dynamics.stance[:, dynamics.wrench_links.index(foot)]
    return [(a, b) for a, b in zip(strikes, strikes[1:]) if on[max(a - 5, 0):a + 6].any()]


def stance_phases(dynamics: MotionDynamics) -> list[tuple[str, int, int]]:
    """The runs [start, stop) of frames each link with a ground reaction stands on a plate."""
    from ..io.foot_contacts import runs

    return [(link, a, b) for k, link in enumerate(dynamics.wrench_links) for a, b in runs(dynamics.stance[:, k])]


def summary(dynamics: MotionDynamics) -> dict:
    """The numbers a report gives: residual statistics over the covered frames with a plate loaded, and
    each side's sagittal peaks over its plate stances."""
    loaded = dynamics.covered & dynamics.stance.any(-1) if dynamics.wrench_links else np.zeros(len(dynamics.time), bool)
    force = np.linalg.norm(dynamics.residual_force(), axis=-1)
    moment = np.linalg.norm(dynamics.residual_moment(), axis=-1)
    stat = lambda x: None if not np.isfinite(x).any() else dict(  # noqa: E731
        rms=float(np.sqrt(np.nanmean(x ** 2))), max=float(np.nanmax(x)), median=float(np.nanmedian(x)))
    out: dict = dict(frames=len(dynamics.time), mass_kg=dynamics.mass, covered_loaded_frames=int(loaded.sum()),
                     residual_force_per_weight=dict(covered=stat(force[loaded]) if loaded.any() else None, all=stat(force)),
                     residual_moment_n_m_per_kg=dict(covered=stat(moment[loaded]) if loaded.any() else None,
                                                     all=stat(moment)),
                     unknown_frames=int((~np.isfinite(dynamics.base_wrench).all(-1)).sum()),
                     stance=[dict(link=link, start_frame=a, stop_frame=b) for link, a, b in stance_phases(dynamics)])
    peaks = {}
    for side in SIDES:
        foot = dynamics.foot(side)
        if foot is None or f"j{side}Hip_roty" not in dynamics.joint_names:
            continue
        on = dynamics.stance[:, dynamics.wrench_links.index(foot)]
        if not on.any():
            continue
        for joint in JOINTS:
            moment_j, power = (x[on] for x in dynamics.sagittal(side, joint))
            peaks[f"{side} {joint.lower()}"] = dict(
                moment_max_n_m_per_kg=float(np.nanmax(moment_j)), moment_min_n_m_per_kg=float(np.nanmin(moment_j)),
                power_max_w_per_kg=float(np.nanmax(power)), power_min_w_per_kg=float(np.nanmin(power)))
    out["sagittal_in_stance"] = peaks
    return out

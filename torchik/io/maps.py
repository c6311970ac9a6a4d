"""Link maps: from a source's segments to a model's links, with constant frame offsets.

A map is a TOML file (the built-in ones: torchik/data/maps/, also shown as models/maps/). For each
model link it names the source segment and the constant rotation C between their frames,
R_link = R_segment C, given as one of

- `link_in_segment_rpy = [r, p, y]`: C = R(rpy), the link frame in the segment frame;
- `segment_in_link_rpy = [r, p, y]`: C = R(rpy)^T (how robot models publish "fake" frames);
- `calibrate = true`: C = R_segment(k)^T R_link(reference pose), from a reference frame k of the
  recording in which the subject holds the map's `reference_pose` ("tpose": the human models'
  zero configuration; "npose": arms down), facing the heading of the base segment's
  `base_forward_axis` ("x", "-z", ...: the base segment's axis that points forward in that pose;
  as the IMU placers of Xsens MVN and OpenSense do from a static pose);
- `calibrate = "twist"`: only the turn about the z axis calibrated so, C = Rz(psi) the turn closest
  to that C, so that the link's z axis is the segment's: for anatomical frames whose z axis runs
  from joint centre to joint centre (Plug-in Gait's femur and tibia), whose direction the static
  pose must not override (a subject does not stand with the model's straight, vertical legs).

Angular velocities are world-frame and unchanged by a constant offset; the base position is the
base segment's. A link whose segments the recording lacks (a clinical lower-body marker set has no
trunk, head or arms) is left out of the mapped recording, to the model: no target pulls it. Only
the base's segment is needed. The mapped recording says in meta["link_map"] which map and which
frame it used, and which links it left out.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from importlib.resources.abc import Traversable
from pathlib import Path

import numpy as np
import torch

from ..data import maps_folder
from ..method import so3
from ..method.kinematics import KinematicModel
from .recording import Recording, RecordingError


@dataclass(frozen=True)
class LinkEntry:
    link: str
    segment: str  # the source segment (the first of `alternatives` until resolved against a recording)
    offset: np.ndarray | None  # C [3,3], or None when it is to be calibrated
    alternatives: tuple[str, ...] = ()  # segments that can stand for the link, in order of preference
    twist_only: bool = False  # calibrate = "twist": only the turn about z is calibrated, the z axes kept one


@dataclass(frozen=True)
class LinkMap:
    """A parsed map: entries in the model's link order, the base link and segment, calibration settings."""

    name: str
    model: str
    entries: tuple[LinkEntry, ...]
    base_link: str
    base_segment: str
    reference_pose: str | None
    base_forward_axis: str | None
    source: str
    calibration: dict | None = None  # where the calibrated offsets came from
    calibration_frame: int | str = 0  # the default reference frame: an index, or "rest" (a BVH's rest pose)
    left_out: tuple[str, ...] = ()  # links the recording it was resolved against has no segment for

    @property
    def links(self) -> tuple[str, ...]:
        return tuple(e.link for e in self.entries)


def _rpy(values, where: str) -> np.ndarray:
    if not (isinstance(values, list) and len(values) == 3):
        raise RecordingError(f"{where}: expected [roll, pitch, yaw] in radians, got {values!r}")
    return so3.rpy_to_matrix(torch.tensor([float(v) for v in values], dtype=torch.float64)).numpy()


HEADING_AXES = ("x", "y", "z", "-x", "-y", "-z")  # a base segment's axis that points forward in the reference pose


def heading_direction(R: np.ndarray, axis: str) -> np.ndarray:
    """The world direction [3] of a segment's signed axis ("x", "-z", ...), R [3,3] segment to world."""
    if axis not in HEADING_AXES:
        raise RecordingError(f"heading axis {axis!r}: expected one of {', '.join(HEADING_AXES)}")
    return (-1.0 if axis.startswith("-") else 1.0) * R[:, "xyz".index(axis[-1])]


def calibration_frame(text: str) -> int | str:
    """A map's reference frame as written by a user: a frame index, or 'rest' (a BVH's rest pose).
    ValueError otherwise."""
    if text == "rest":
        return text
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"expected a frame index or 'rest', got {text!r}") from None


def built_in_maps() -> list[str]:
    """The names of the maps torchik ships."""
    return sorted(p.name.removesuffix(".toml") for p in maps_folder().iterdir() if p.name.endswith(".toml"))


def load_map(name_or_path: str | Path) -> LinkMap:
    """A map by file path or built-in name (a file in torchik/data/maps/ without its suffix)."""
    path: Path | Traversable = Path(name_or_path)
    if not Path(name_or_path).suffix:
        path = maps_folder() / f"{name_or_path}.toml"
    if not path.is_file():
        raise RecordingError(f"no link map {str(name_or_path)!r}; built-in maps: {', '.join(built_in_maps())}")
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise RecordingError(f"{path}: not valid TOML: {exc}") from None
    for key in ("name", "model", "base", "links"):
        if key not in spec:
            raise RecordingError(f"{path}: missing '{key}'")
    entries = []
    for link, item in spec["links"].items():
        where = f"{path}: links.{link}"
        if "source" not in item:
            raise RecordingError(f"{where}: missing 'source'")
        given = [k for k in ("link_in_segment_rpy", "segment_in_link_rpy", "calibrate") if k in item]
        if len(given) > 1:
            raise RecordingError(f"{where}: give one of link_in_segment_rpy, segment_in_link_rpy, calibrate")
        if not given:
            offset = np.eye(3)
        elif given[0] == "link_in_segment_rpy":
            offset = _rpy(item["link_in_segment_rpy"], where)
        elif given[0] == "segment_in_link_rpy":
            offset = _rpy(item["segment_in_link_rpy"], where).T
        elif item["calibrate"] not in (True, "twist"):
            raise RecordingError(f"{where}: calibrate must be true or \"twist\", got {item['calibrate']!r}")
        else:
            offset = None
        alternatives = item["source"] if isinstance(item["source"], list) else [item["source"]]
        if not alternatives or not all(isinstance(a, str) for a in alternatives):
            raise RecordingError(f"{where}: 'source' must be a segment name or a list of them")
        # `optional = true`, which older maps give, is what every link is now: left out when no segment is there
        entries.append(LinkEntry(link, alternatives[0], offset, tuple(alternatives), item.get("calibrate") == "twist"))
    base = spec["base"]
    if base.get("link") not in spec["links"]:
        raise RecordingError(f"{path}: base.link {base.get('link')!r} is not one of the mapped links")
    calibration = spec.get("calibration", {})
    pose = calibration.get("reference_pose")
    if calibration.get("base_forward_axis") not in (None, *HEADING_AXES):
        raise RecordingError(f"{path}: calibration.base_forward_axis must be one of {', '.join(HEADING_AXES)}")
    if any(e.offset is None for e in entries) and pose not in ("tpose", "npose"):
        raise RecordingError(f"{path}: calibrated links need calibration.reference_pose = 'tpose' or 'npose'")
    base_entry = next(e for e in entries if e.link == base["link"])
    return LinkMap(spec["name"], spec["model"], tuple(entries), base["link"], base_entry.segment,
                   pose, calibration.get("base_forward_axis"), str(path), None, calibration.get("frame", 0))


def _find(alternatives: tuple[str, ...], names: tuple[str, ...]) -> str | None:
    """The recording's segment for the first alternative it has: by exact name, else by the name after
    a namespace (`mixamorig:Hips` is `Hips`); None when it has none."""
    plain: dict[str, str] = {}
    for name in names:
        plain.setdefault(name.rsplit(":", 1)[-1], name)
    for wanted in alternatives:
        if wanted in names:
            return wanted
        if wanted in plain:
            return plain[wanted]
    return None


def _base_source(link_map: LinkMap, names: tuple[str, ...]) -> str | None:
    """The recording's segment for the map's base link (None when it has none)."""
    base = next(e for e in link_map.entries if e.link == link_map.base_link)
    return _find(base.alternatives or (base.segment,), names)


def missing_segments(link_map: LinkMap, names) -> list[str]:
    """The segments (one name per link: its first alternative) that recordings with these segment
    names lack for this map: their links are left to the model."""
    names = tuple(names)
    return [e.segment for e in link_map.entries if _find(e.alternatives or (e.segment,), names) is None]


def resolve(link_map: LinkMap, names) -> LinkMap:
    """The map against a recording's segment names: each link's source the recording's own name for
    it (alternatives and namespaces resolved), the links it has no segment for left out (in
    `left_out`). RecordingError when it lacks the base's segment: there would be nothing to track."""
    names = tuple(names)
    base_segment = _base_source(link_map, names)
    if base_segment is None:
        raise RecordingError(f"map {link_map.name!r} needs segment {link_map.base_segment!r}, its base link "
                             f"{link_map.base_link!r}, that the recording lacks: nothing to track without it; "
                             f"it has {list(names)}")
    entries, left_out = [], list(link_map.left_out)
    for e in link_map.entries:
        found = _find(e.alternatives or (e.segment,), names)
        if found is None:
            left_out.append(e.link)
        else:
            entries.append(replace(e, segment=found, alternatives=(found,)))
    return replace(link_map, entries=tuple(entries), base_segment=base_segment, left_out=tuple(left_out))


def model_family(model: KinematicModel) -> str:
    """What a map's `model` names for this model: "icub", or "human" for Human66 and Human48."""
    return "icub" if "icub" in (model.name or "").lower() else "human"


def default_map(names, model: KinematicModel) -> str | None:
    """The map a recording with these segment names needs when none is given: "auto" when the
    segments are not the model's links (its base link is not among them), else None."""
    return None if model.base_link in tuple(names) else "auto"


def choose_map(names, family: str = "human") -> str:
    """The built-in map (its name) for a recording with these segment names, into models of `family`:
    of the maps whose base segment the recording has, the one mapping the most links (the links it
    lacks are left to the model). RecordingError naming the closest map and the segments it misses
    when the recording has no built-in map's base."""
    names = tuple(names)
    candidates = []
    for name in built_in_maps():
        link_map = load_map(name)
        if link_map.model == family:
            missing = missing_segments(link_map, names)
            mapped = len(link_map.entries) - len(missing)
            candidates.append((_base_source(link_map, names) is None, -mapped, name, link_map.base_segment, missing))
    if not candidates:
        raise RecordingError(f"no built-in map into {family} models")
    no_base, _, best, base, missing = min(candidates)
    if no_base:
        raise RecordingError(f"no built-in map fits the recording's segments {list(names)}; the closest, {best!r}, "
                             f"misses its base segment {base!r} and {len(missing) - 1} more: give --map FILE.toml "
                             f"(see models/maps/ for the format)")
    return best


def reference_configuration(model: KinematicModel, pose: str) -> torch.Tensor:
    """Joint positions [1,n] of a reference pose: 'tpose' (zero) or 'npose' (human models' arms down)."""
    s = torch.zeros(1, model.n_dof, dtype=model.dtype, device=model.device)
    if pose == "npose":
        for name, angle in (("jRightShoulder_rotx", math.pi / 2), ("jLeftShoulder_rotx", -math.pi / 2)):
            if name not in model.joint_names:
                raise RecordingError(f"an N-pose needs {name}; {model.name} has no such joint")
            s[0, model.joint_names.index(name)] = angle
    return s


def calibrate(link_map: LinkMap, recording: Recording, model: KinematicModel, frame: int | str | None = None,
              heading_axis: str | None = None) -> LinkMap:
    """The map with every `calibrate = true` offset computed from `frame` of `recording`, in which the
    subject holds the map's reference pose (for instance a static trial's frame), or from the BVH
    skeleton's rest pose (frame "rest"). Default: the map's calibration.frame, else 0. heading_axis:
    the base segment's axis pointing forward in that frame ("x", "-z", ...; default the map's
    base_forward_axis). Apply the result to that recording or to other trials of the same session."""
    todo = [i for i, e in enumerate(link_map.entries) if e.offset is None]
    if not todo:
        return link_map
    link_map = resolve(link_map, recording.links)
    todo = [i for i, e in enumerate(link_map.entries) if e.offset is None]
    index = {name: i for i, name in enumerate(recording.links)}
    frame = link_map.calibration_frame if frame is None else frame
    ids = [index[e.segment] for e in link_map.entries]
    p0, R0, _ = model.zero_configuration(1)
    if link_map.reference_pose is None:
        raise RecordingError(f"map {link_map.name!r} calibrates offsets but names no calibration.reference_pose")
    kin = model(p0, R0, reference_configuration(model, link_map.reference_pose), link_map.links, jacobian=False)
    heading = np.eye(3)
    if frame == "rest":
        rest = recording.meta.get("rest_pose")
        if not rest:
            raise RecordingError("calibration on the rest pose needs a BVH whose rest pose is a standing posture; "
                                 "this recording has none: calibrate on a frame index instead")
        R_source = np.asarray(rest["orientation"])[ids]
        up, left = np.asarray(rest["up"]), np.asarray(rest["left"])
        heading = np.stack((np.cross(left, up), left, up), axis=1)  # columns: forward, left, up
        k: int | str = "rest"
        time_s = None
    else:
        k = int(frame)
        if not 0 <= k < len(recording.time):
            raise RecordingError(f"calibration frame {k} is outside the recording's {len(recording.time)} frames")
        R_source = recording.orientation[k, ids]  # [L,3,3]
        time_s = float(recording.time[k])
        if np.isnan(R_source).any():
            raise RecordingError(f"calibration frame {k} has missing segments; choose a frame where all are seen")
    heading_axis = heading_axis or link_map.base_forward_axis
    if frame != "rest" and heading_axis:
        axis = heading_direction(R_source[link_map.links.index(link_map.base_link)], heading_axis)
        heading = so3.rpy_to_matrix(torch.tensor([0.0, 0.0, math.atan2(axis[1], axis[0])], dtype=torch.float64)).numpy()
    R_reference = heading @ kin.rotation[0].cpu().numpy()  # the model in the pose, facing the subject's way
    entries = list(link_map.entries)
    for i in todo:
        e = entries[i]
        offset = R_source[i].T @ R_reference[i]
        entries[i] = replace(e, offset=twist_about_z(offset) if e.twist_only else offset)  # keeps alternatives
    calibrated = dict(frame=k, time_s=time_s, reference_pose=link_map.reference_pose,
                      recording=recording.meta.get("source"), heading_axis=heading_axis)
    return replace(link_map, entries=tuple(entries), calibration=calibrated)


def twist_about_z(C: np.ndarray) -> np.ndarray:
    """The turn about z, Rz(psi) [3,3], nearest C [3,3] (the largest trace of C^T Rz(psi))."""
    psi = math.atan2(C[1, 0] - C[0, 1], C[0, 0] + C[1, 1])
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def apply_map(recording: Recording, link_map: LinkMap, model: KinematicModel | None = None,
              calibration_frame: int | str | None = None, heading_axis: str | None = None) -> Recording:
    """The recording in the model's link names and frames. A map with offsets still to calibrate is
    calibrated on this recording's `calibration_frame` (an index or "rest"; default: the map's
    calibration.frame, else 0) facing `heading_axis` (default the map's), which needs `model`."""
    link_map = resolve(link_map, recording.links)
    index = {name: i for i, name in enumerate(recording.links)}
    if recording.base_link != link_map.base_segment:
        raise RecordingError(f"map {link_map.name!r} takes the base position from segment {link_map.base_segment!r}; "
                             f"the recording's base is {recording.base_link!r} "
                             f"(read it with base_link={link_map.base_segment!r})")
    if any(e.offset is None for e in link_map.entries):
        if model is None:
            raise RecordingError(f"map {link_map.name!r} calibrates offsets: give the model (or calibrate() first)")
        link_map = calibrate(link_map, recording, model, calibration_frame, heading_axis)
    ids = [index[e.segment] for e in link_map.entries]
    offsets = np.stack([_given(e.offset) for e in link_map.entries])
    R = recording.orientation[:, ids] @ offsets
    known = ~np.isnan(R).any(axis=(-1, -2))
    if known.any():
        R[known] = so3.project(torch.from_numpy(R[known])).numpy()
    meta = dict(recording.meta, link_map=dict(name=link_map.name, file=link_map.source, calibration=link_map.calibration,
                                              segments={e.link: e.segment for e in link_map.entries},
                                              left_out=list(link_map.left_out)))
    return Recording(time=recording.time, links=link_map.links, orientation=R,
                     angular_velocity=recording.angular_velocity[:, ids], base_link=link_map.base_link,
                     base_position=recording.base_position, base_linear_velocity=recording.base_linear_velocity,
                     meta=meta, position=None if recording.position is None else recording.position[:, ids],
                     external_wrench=_mapped_wrench(recording, ids))


def _mapped_wrench(recording: Recording, ids: list[int]) -> np.ndarray | None:
    """The segments' external wrenches [T,n,6] on the links mapped from them: on the first link a
    segment gives, once (its moment is about the world origin: a link's frame does not change it)."""
    if recording.external_wrench is None:
        return None
    first = [ids.index(i) == k for k, i in enumerate(ids)]
    return np.where(np.array(first)[:, None], recording.external_wrench[:, ids], 0.0)


def map_recording(recording: Recording, map_name: str | Path, model: KinematicModel, static: Recording | None = None,
                  calibration_frame: int | str | None = None,
                  heading_axis: str | None = None) -> tuple[Recording, LinkMap]:
    """A recording through a map (a built-in name, a .toml file, or "auto": `choose_map`'s) into `model`'s links: the map's
    offsets calibrated on `static`, a static trial, when given (else on the recording itself,
    for a map that calibrates), the subject facing the base segment's `heading_axis` there (default
    the map's base_forward_axis). Returns the mapped recording and the map used."""
    if str(map_name) == "auto":
        map_name = choose_map(recording.links, model_family(model))
    link_map = load_map(map_name)
    if static is not None:
        link_map = calibrate(link_map, static, model, calibration_frame, heading_axis)
    return apply_map(recording, link_map, model, calibration_frame, heading_axis), link_map


def _given(offset: np.ndarray | None) -> np.ndarray:
    """An offset that calibration has filled in."""
    assert offset is not None
    return offset

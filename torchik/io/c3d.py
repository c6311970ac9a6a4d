"""C3D (Vicon Plug-in Gait outputs) to a Recording, read with ezc3d.

Plug-in Gait writes, for each segment <SEG> (PEL pelvis, TRX thorax, HED head and, with L/R
prefixes, CL clavicle, HU humerus, RA radius, HN hand, FE femur, TI tibia, FO foot, TO toe), four
virtual points: origin <SEG>O and the ends of its anterior, lateral and proximal axes <SEG>A,
<SEG>L, <SEG>P. A - O, L - O, P - O form a right-handed triad, so R = [A-O, L-O, P-O] / norms is
the segment's rotation in the lab (z up), projected onto SO(3) (the triads are orthogonal to
about 1e-6 in the files we have seen; the largest deviation is kept in meta).

A point whose residual is negative (the C3D convention for "not measured") or whose coordinates
are all zero (how some exporters mark occlusions) is missing: the segment's rotation is NaN for
that frame, never interpolated. Angular and linear velocities are central differences; they are
NaN next to a gap.

Where the file has force plates (FORCE_PLATFORM), the reader adds each foot's `external_wrench`:
the plates' ground reactions (force_plates.py) at the point frames, given to the foot nearest
each contact (foot_contacts.py, the heel and toe markers LHEE-LTOE, RHEE-RTOE or, without them,
the ankle joint centre and the foot's origin), with the plates and contacts in meta["force_plates"],
and what the plates weigh the subject at where it stands still on them (weighing.py) in
meta["skeleton"]["weighed"], beside PROCESSING:Bodymass.
Vicon's gait events (EVENT: "Foot Strike", "Foot Off", per side) are kept in meta["events"], at this
file's frames.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import InputError, optional
from ..method import so3
from . import analog
from .foot_contacts import assign_contacts, link_wrenches
from .force_plates import CONTACT_THRESHOLD, GroundReactions, ground_reactions
from .recording import Recording, RecordingError, angular_velocity_from_orientations, readable_file
from .weighing import weigh

PLUG_IN_GAIT = ("PEL", "TRX", "HED", "LCL", "LHU", "LRA", "LHN", "RCL", "RHU", "RRA", "RHN",
                "LFE", "LTI", "LFO", "LTO", "RFE", "RTI", "RFO", "RTO")
UNIT_SCALE = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
# each foot segment's ends for the plates' contacts: heel and toe markers, else the ankle joint centre and the foot's origin
FOOT_POINTS = {"LFO": (("LHEE", "LTOE"), ("LTIO", "LFOO")), "RFO": (("RHEE", "RTOE"), ("RTIO", "RFOO"))}


def _labels(points_parameters: dict) -> list[str]:
    """POINT:LABELS, continued in LABELS2, LABELS3, ... when there are more than 255 points."""
    labels = list(points_parameters["LABELS"]["value"])
    k = 2
    while f"LABELS{k}" in points_parameters:
        labels += list(points_parameters[f"LABELS{k}"]["value"])
        k += 1
    return [label.strip() for label in labels]


# Plug-in Gait's subject lengths (PROCESSING, in the file's units) by the segment they measure
_PROCESSING_LENGTHS = {"RFE": "RFemurLength", "LFE": "LFemurLength", "RTI": "RTibiaLength", "LTI": "LTibiaLength",
                       "RFO": "RFootLength", "LFO": "LFootLength"}
# segments measured between two joint centres that are bone origins: the clavicle's origin is the
# shoulder joint, the humerus's the elbow, the radius's the wrist
_ORIGIN_LENGTHS = {"RHU": ("RCLO", "RHUO"), "LHU": ("LCLO", "LHUO"), "RRA": ("RHUO", "RRAO"), "LRA": ("LHUO", "LRAO")}


# each segment's proximal joint centre, where a model's link has its origin: the hip joint centre,
# and the origins of the parent bones (Plug-in Gait puts a bone's origin at its distal joint)
PROXIMAL_JOINT = {"PEL": "PELO", "RFE": "RHJC", "LFE": "LHJC", "RTI": "RFEO", "LTI": "LFEO", "RFO": "RTIO", "LFO": "LTIO",
                  "RHU": "RCLO", "LHU": "LCLO", "RRA": "RHUO", "LRA": "LHUO", "RHN": "RRAO", "LHN": "LRAO"}


def _plug_in_gait_skeleton(parameters, xyz: np.ndarray, valid: np.ndarray, index: dict, unit: str) -> dict:
    """The subject's measures a Plug-in Gait file holds: height (m) and mass (kg) from PROCESSING,
    segment lengths (m) by Plug-in Gait segment, from PROCESSING or as the median distance between
    the joint centres that bound the segment, and the distance between the hip joint centres (m)."""
    processing = parameters.get("PROCESSING", {})

    def value(name):
        entry = processing.get(name)
        return float(np.asarray(entry["value"]).ravel()[0]) if entry is not None else None

    lengths = {seg: value(name) * UNIT_SCALE[unit] for seg, name in _PROCESSING_LENGTHS.items() if value(name)}
    for seg, (a, b) in _ORIGIN_LENGTHS.items():
        if a in index and b in index:
            seen = valid[:, index[a]] & valid[:, index[b]]
            if seen.any():
                lengths[seg] = float(np.median(np.linalg.norm(xyz[seen, index[a]] - xyz[seen, index[b]], axis=-1)))
    height = value("Height")
    skeleton = dict(format="c3d", height=height * UNIT_SCALE[unit] if height else None, mass=value("Bodymass"),
                    lengths=lengths)
    if "LHJC" in index and "RHJC" in index:  # the hip joint centres (Plug-in Gait's, from the pelvis markers)
        seen = valid[:, index["LHJC"]] & valid[:, index["RHJC"]]
        if seen.any():
            skeleton["hip_width"] = float(np.median(np.linalg.norm(xyz[seen, index["LHJC"]] - xyz[seen, index["RHJC"]],
                                                                   axis=-1)))
    return skeleton


def _events(parameters: dict, first_frame: int, rate: float, frames: int) -> list[dict]:
    """The file's EVENT group (Vicon's gait events: "Foot Strike", "Foot Off" with context "Left" or
    "Right") within its frames: label, context, the frame (from 0, in this file) and its time (s, the
    recording's). EVENT:TIMES holds (minutes, seconds) of the capture, whose frame f (from 0) is at f /
    rate; this file starts at capture frame `first_frame`."""
    group = parameters.get("EVENT", {})
    if "TIMES" not in group or "LABELS" not in group:
        return []
    times = np.asarray(group["TIMES"]["value"], dtype=np.float64).reshape(2, -1)
    labels = [str(x).strip() for x in group["LABELS"]["value"]]
    contexts = [str(x).strip() for x in group.get("CONTEXTS", {}).get("value", [""] * len(labels))]
    events = []
    for k in range(min(len(labels), times.shape[1])):  # a few events
        frame = int(round((60.0 * times[0, k] + times[1, k]) * rate)) - first_frame
        if 0 <= frame < frames:
            events.append(dict(label=labels[k], context=contexts[k] if k < len(contexts) else "", frame=frame,
                               time_s=frame / rate))
    return sorted(events, key=lambda e: e["frame"])


def _declared_frames(path: Path, parameters: dict) -> int | None:
    """The frame count the file's header declares (None when it cannot say). ezc3d rewrites its
    parsed header from the frames it could read, so a cut file looks whole there: the raw header's
    first and last frame words are read instead (byte order from the parameter block's processor
    type: 86 is MIPS, big-endian; Intel and DEC are little-endian)."""
    with open(path, "rb") as f:
        header = f.read(512)
        if len(header) < 512:
            return None
        f.seek(max(header[0] - 1, 0) * 512 + 3)  # byte 0: the parameter block's number, from 1
        processor = f.read(1)
    if not processor:
        return None
    order = ">" if processor[0] == 86 else "<"
    first, last = np.frombuffer(header[6:10], dtype=f"{order}u2").tolist()
    if last == 0xFFFF:  # more frames than a header word holds: TRIAL:ACTUAL_END_FIELD has the last (low, high)
        words = list(np.asarray(parameters.get("TRIAL", {}).get("ACTUAL_END_FIELD", {}).get("value", [])).ravel())
        if len(words) < 2:
            return None
        last = int(words[0]) % 65536 + int(words[1]) % 65536 * 65536
    return last - first + 1 if last >= first else None


def _open(path: Path):
    """The file read by ezc3d (analogs scaled by it), or RecordingError."""
    ezc3d = optional("ezc3d", "io", "reading C3D files")
    try:
        return ezc3d.c3d(str(path), extract_forceplat_data=False)
    except Exception as exc:  # ezc3d raises plain exceptions for truncated or foreign files
        raise RecordingError(f"{path}: not a readable C3D file ({type(exc).__name__}: {exc})") from None


def _point_unit(path: Path, parameters: dict, units: str | None) -> str:
    """`units`, else POINT:UNITS; RecordingError when neither is one of UNIT_SCALE."""
    declared = list(parameters.get("UNITS", {}).get("value", []))
    unit = units or (declared[0].strip().lower() if declared else None)
    if unit is None:
        raise RecordingError(f"{path}: the file declares no POINT:UNITS; give units= one of {list(UNIT_SCALE)}")
    if unit not in UNIT_SCALE:
        raise RecordingError(f"{path}: unknown units {unit!r}; give units= one of {list(UNIT_SCALE)}")
    return unit


def read_ground_reactions(path: str | Path, units: str | None = None, threshold: float = CONTACT_THRESHOLD,
                          method: analog.Method = "butterworth", cutoff: float | None = None) -> GroundReactions:
    """The ground reactions of a C3D file's force plates at its point frames (force_plates.py;
    `method` and `cutoff`: analog.to_frames's). RecordingError names the file and the problem."""
    path = readable_file(path)
    c3d = _open(path)
    unit = _point_unit(path, c3d["parameters"]["POINT"], units)
    try:
        return ground_reactions(c3d, UNIT_SCALE[unit], threshold, method, cutoff)
    except InputError as exc:
        raise RecordingError(f"{path}: {exc}") from None


def _feet(xyz: np.ndarray, valid: np.ndarray, index: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each foot's ends (FOOT_POINTS) the file marks: link -> heel [T,3], toe [T,3] (m, NaN where unseen)."""
    seen = lambda name: np.where(valid[:, index[name], None], xyz[:, index[name]], np.nan)  # noqa: E731
    feet = {}
    for link, choices in FOOT_POINTS.items():
        ends = next((pair for pair in choices if all(name in index for name in pair)), None)
        if ends is not None:
            feet[link] = (seen(ends[0]), seen(ends[1]))
    return feet


def _external_wrench(reactions: GroundReactions, links: tuple[str, ...], xyz: np.ndarray, valid: np.ndarray,
                     index: dict) -> tuple[np.ndarray, dict]:
    """Each link's plate wrench [T,n,6] (foot_contacts.py) and what meta says of the plates."""
    feet = _feet(xyz, valid, index)
    contacts = assign_contacts(reactions, feet)
    lost = sorted({c.link for c in contacts if c.link is not None and c.link not in links})
    meta = dict(reactions.to_json(), contacts=[c.to_json() for c in contacts], feet=list(feet),
                wrench="force N, moment N m about the world origin, world frame, on the body")
    if lost:
        meta["links_absent"] = lost
    return link_wrenches(reactions, contacts, links), meta


def read_c3d(path: str | Path, base_link: str = "PEL", units: str | None = None, forces: bool = True) -> Recording:
    """Read the Plug-in Gait segments of a C3D file. units: 'mm', 'cm' or 'm' when the file's POINT:UNITS
    is missing or wrong; forces: the force plates' wrenches on the feet (`external_wrench`), where the
    file has plates. RecordingError names the file and the problem."""
    path = readable_file(path)
    c3d = _open(path)
    parameters = c3d["parameters"]["POINT"]
    labels = _labels(parameters)
    points = c3d["data"]["points"]  # [4, P, T]
    declared_frames = _declared_frames(path, c3d["parameters"])
    if declared_frames is not None and points.shape[2] != declared_frames:
        raise RecordingError(f"{path}: truncated: the header declares {declared_frames} frames, the file holds "
                             f"{points.shape[2]}")
    if points.shape[1] != len(labels):
        raise RecordingError(f"{path}: {points.shape[1]} points but {len(labels)} labels")
    unit = _point_unit(path, parameters, units)
    rate = float(np.asarray(parameters["RATE"]["value"]).ravel()[0])
    index = {label: i for i, label in enumerate(labels)}
    segments = [s for s in PLUG_IN_GAIT if all(s + axis in index for axis in "OALP")]
    if base_link not in segments:
        raise RecordingError(f"{path}: no Plug-in Gait triad for {base_link!r} (points {base_link}O/A/L/P); "
                             f"segments found: {segments or 'none'}")
    xyz = points[:3].transpose(2, 1, 0) * UNIT_SCALE[unit]  # [T,P,3] metres
    residual = c3d["data"]["meta_points"]["residuals"][0].T if "residuals" in c3d["data"]["meta_points"] else None
    valid = np.isfinite(xyz).all(-1) & (np.abs(xyz).sum(-1) > 0)
    if residual is not None:
        valid &= residual >= 0
    T = xyz.shape[0]

    def corners(segment):
        ids = [index[segment + axis] for axis in "OALP"]
        return xyz[:, ids], valid[:, ids].all(-1)

    rotations, present, worst = [], [], 0.0
    for segment in segments:  # 19 segments at most, in a reader: fine
        p, ok = corners(segment)
        axes = p[:, 1:] - p[:, :1]  # [T,3 axes,3]
        axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True).clip(min=1e-12)
        R = np.swapaxes(axes, -1, -2)  # columns: anterior, lateral, proximal
        if ok.any():
            deviation = np.abs(np.swapaxes(R[ok], -1, -2) @ R[ok] - np.eye(3)).max()
            worst = max(worst, float(deviation))
        rotations.append(np.where(ok[:, None, None], R, np.nan))
        present.append(ok)
    R = np.stack(rotations, axis=1)  # [T,n,3,3]
    known = ~np.isnan(R).any(axis=(-1, -2))
    if known.any():
        R[known] = so3.project(torch.from_numpy(R[known])).numpy()
    time = np.arange(T) / rate
    base_origin, base_ok = xyz[:, index[base_link + "O"]], valid[:, index[base_link + "O"]]
    base_position = np.where(base_ok[:, None], base_origin, np.nan)
    velocity = np.gradient(base_position, time, axis=0) if T > 1 else np.zeros((T, 3))
    missing = {s: int((~ok).sum()) for s, ok in zip(segments, present) if (~ok).any()}
    skeleton = _plug_in_gait_skeleton(c3d["parameters"], xyz, valid, index, unit)
    meta = dict(source=str(path), format="c3d", frame_rate=rate, units=dict(position=unit, converted_to="m"),
                clock="shared",  # one camera system samples every marker: no segment is late on another
                angular_velocity="derived",  # the orientations' central difference: no gyro
                first_frame=int(c3d["header"]["points"]["first_frame"]), triad_max_deviation=worst,
                missing_frames=missing, skeleton=skeleton,
                events=_events(c3d["parameters"], int(c3d["header"]["points"]["first_frame"]), rate, T),
                note="segment frames are Plug-in Gait's (anterior, lateral, proximal): calibrate them with a link map")
    position = np.full((T, len(segments), 3), np.nan)  # NaN: a segment without a joint centre, or not seen
    for i, segment in enumerate(segments):
        point = PROXIMAL_JOINT.get(segment)
        if point in index:
            position[:, i] = np.where(valid[:, index[point], None], xyz[:, index[point]], np.nan)
    wrench = None
    if forces:
        try:
            reactions = ground_reactions(c3d, UNIT_SCALE[unit])
        except InputError as exc:
            raise RecordingError(f"{path}: {exc} (forces=False reads the motion without the plates)") from None
        skeleton["weighed"] = weigh(reactions, _feet(xyz, valid, index), base_position, time).to_json()
        if reactions.plates:
            wrench, meta["force_plates"] = _external_wrench(reactions, tuple(segments), xyz, valid, index)
        elif reactions.skipped:
            meta["force_plates"] = reactions.to_json()
    return Recording(time=time, links=tuple(segments), orientation=R, position=position,
                     angular_velocity=angular_velocity_from_orientations(R, time), base_link=base_link,
                     base_position=base_position, base_linear_velocity=velocity, meta=meta, external_wrench=wrench)

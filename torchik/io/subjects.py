"""A subject's own Human66/Human48 from a recording, as the paper's pipeline builds it from the Xsens
session: what the file says of the body (meta["skeleton"], kept by the readers and by the recording
format, so a converted .npz serves as well as the source file) becomes a HumanSubject.

- MVNX: every segment's joints in its parent's frame (`<points><point label="jL5S1"><pos_b>`), so
  every joint placement is the file's; the segment lengths follow from them.
- BVH: the bone offsets, through the link map (the length of a model segment is the distance from
  its source joint to the source joint of the segment it carries, summed along the bones between).
- C3D (Plug-in Gait static trial): height and femur, tibia and foot lengths from the file's
  PROCESSING parameters; the mass the plates weigh the subject at where it stands still on them
  (io/weighing.py: measured, where PROCESSING:Bodymass is typed), else Bodymass; upper arm and
  forearm lengths between the joint centres at the clavicle, humerus and radius origins; the hips'
  placement across the pelvis from the distance between the hip joint centres (LHJC, RHJC), their
  height and depth the template's scaled.

A segment length is the template's main dimension (see method.models.human): joint to the next
joint along the segment. Segments the file does not measure are scaled from the height.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..method.models.human import SEGMENTS, TEMPLATE, TEMPLATE_HEIGHT, TEMPLATE_MASS, HumanSubject
from .maps import choose_map, load_map, resolve
from .recording import Recording, RecordingError

# each segment's main length runs from its joint to this child's joint (template: equal to 1%)
LENGTH_CHILD = {p.name: c.name for p in TEMPLATE for c in TEMPLATE
                if c.parent == p.name and abs(float(np.linalg.norm(c.joint_origin)) - p.length) < 0.01 * p.length}
TEMPLATE_LENGTH = {s.name: s.length for s in TEMPLATE}
PARENT = {s.name: s.parent for s in TEMPLATE}
STATURE = ("Pelvis", "L5", "L3", "T12", "T8", "Neck", "RightUpperLeg", "RightLowerLeg", "LeftUpperLeg", "LeftLowerLeg")
LENGTH_RANGE = (0.005, 1.5)  # m: HumanSubject's
HIP_WIDTH = (0.05, 0.5)  # m between the hip joint centres: a child's to a large adult's, with room
WEIGHED = "the static trial's plates"  # how a mass the plates weigh begins its mass_from


@dataclass(frozen=True)
class BuiltSubject:
    """A subject from a recording and where each of its numbers came from."""

    subject: HumanSubject
    source: str
    from_file: dict[str, float]  # segment -> length (m) the file gave
    scaled: tuple[str, ...]  # segments scaled from the height
    rejected: dict[str, float]  # lengths the file gave outside LENGTH_RANGE, not used
    height_from: str
    mass_from: str
    link_map: str | None

    def report(self) -> dict:
        return dict(source=self.source, height_m=self.subject.height, height_from=self.height_from,
                    mass_kg=self.subject.mass, mass_from=self.mass_from, link_map=self.link_map,
                    lengths_from_file_m=self.from_file, scaled_from_height=list(self.scaled),
                    joint_origins_from_file=sorted(self.subject.joint_origins), rejected_lengths_m=self.rejected)


def _mvnx(skeleton: dict) -> tuple[dict[str, float], dict[str, tuple[float, float, float]]]:
    points = skeleton["points"]
    origins = {}
    for name in SEGMENTS[1:]:
        parent = PARENT[name]
        if name not in points or parent not in points:
            continue
        shared = [label for label in points[name] if label.startswith("j") and label in points[parent]]
        if len(shared) == 1 and np.allclose(points[name][shared[0]], 0.0):  # the segment's origin is its joint
            x, y, z = (float(v) for v in points[parent][shared[0]])
            origins[name] = (x, y, z)
    lengths = {p: float(np.linalg.norm(origins[c])) for p, c in LENGTH_CHILD.items() if c in origins}
    return lengths, origins


def _bvh(skeleton: dict, sources: dict[str, str]) -> dict[str, float]:
    parents, offsets = skeleton["parents"], skeleton["offsets"]
    lengths = {}
    for segment, child in LENGTH_CHILD.items():
        if segment not in sources or child not in sources:
            continue
        top, joint, vector = sources[segment], sources[child], np.zeros(3)
        while joint is not None and joint != top:  # up the bones from the child's joint to the segment's
            vector += offsets[joint]
            joint = parents[joint]
        if joint == top:
            lengths[segment] = float(np.linalg.norm(vector))
    return lengths


def _hips(width: float | None, height: float) -> dict[str, tuple[float, float, float]]:
    """The hip joints in the pelvis' frame, `width` (m) apart across it (none without a width, or one
    beyond HIP_WIDTH); their other coordinates the template's scaled to `height`."""
    if width is None or not HIP_WIDTH[0] <= width <= HIP_WIDTH[1]:
        return {}
    k = height / TEMPLATE_HEIGHT
    return {s.name: (s.joint_origin[0] * k, math.copysign(width / 2, s.joint_origin[1]), s.joint_origin[2] * k)
            for s in TEMPLATE if s.name in ("RightUpperLeg", "LeftUpperLeg")}


def _mass(skeleton: dict, mass: float | None, weighed: bool) -> tuple[float, str]:
    """The subject's mass (kg) and where it came from: `mass` given, else (weighed) what the file's
    plates weigh the subject at standing still on them, else the mass the file states, else the
    template's. A line on the other number, or on why the plates could not weigh the subject."""
    stated = float(skeleton["mass"]) if skeleton.get("mass") else None
    name = "PROCESSING:Bodymass" if skeleton["format"] == "c3d" else "the file's mass"
    scale: dict = skeleton.get("weighed") or {}
    if mass is not None:
        return mass, "given"
    if weighed and scale.get("mass_kg"):
        on_plates = float(scale["mass_kg"])
        line = (f"{WEIGHED}: {scale['frames']} still frames with every foot on a plate, sd "
                f"{scale['sd_kg']:.2f} kg")
        if stated:
            line += f"; {name} states {stated:.1f} kg, {100 * abs(stated / on_plates - 1):.1f} % " + (
                "more" if stated >= on_plates else "less")
        return on_plates, line
    why = f"; the plates do not weigh the subject: {scale['why_not']}" if weighed and scale.get("why_not") else ""
    if stated:
        return stated, ("the file's " + name if skeleton["format"] == "c3d" else "the file") + why
    return TEMPLATE_MASS, "the template's: the file has none; give --mass" + why


def subject_from_recording(recording: Recording, height: float | None = None, mass: float | None = None,
                           map_name: str | None = None, weighed: bool = True) -> BuiltSubject:
    """The subject a recording measures (see the module's docstring). height (m) and mass (kg) given
    override the file's; weighed: the mass the file's force plates weigh the subject at standing still on
    them (a static trial's, io/weighing.py) before the one the file states (False: the stated one, e.g.
    PROCESSING:Bodymass); map_name: the link map for BVH and C3D files (default: `choose_map`'s)."""
    skeleton = recording.meta.get("skeleton")
    source = str(recording.meta.get("source", "the recording"))
    if not skeleton:
        raise RecordingError(f"{source}: holds no skeleton (segment points, bone offsets or Plug-in Gait "
                             f"lengths) to build a subject from; read it again from its MVNX, BVH or C3D file")
    origins: dict[str, tuple[float, float, float]] = {}
    used_map = None
    if skeleton["format"] == "mvnx":
        lengths, origins = _mvnx(skeleton)
    else:
        link_map = resolve(load_map(map_name or choose_map(recording.links)), recording.links)
        used_map = link_map.name
        sources = {e.link: e.segment for e in link_map.entries}
        if skeleton["format"] == "bvh":
            lengths = _bvh(skeleton, sources)
        elif skeleton["format"] == "c3d":
            lengths = {link: skeleton["lengths"][seg] for link, seg in sources.items() if seg in skeleton["lengths"]}
        else:
            raise RecordingError(f"{source}: unknown skeleton format {skeleton['format']!r}")
    rejected = {k: v for k, v in lengths.items() if not LENGTH_RANGE[0] <= v <= LENGTH_RANGE[1]}
    lengths = {k: v for k, v in lengths.items() if k not in rejected}
    if height is not None:
        height_from = "given"
    elif skeleton.get("height"):
        height, height_from = float(skeleton["height"]), "the file"
    elif any(s in lengths for s in STATURE):
        measured = [s for s in STATURE if s in lengths]
        ratio = sum(lengths[s] for s in measured) / sum(TEMPLATE_LENGTH[s] for s in measured)
        height, height_from = TEMPLATE_HEIGHT * ratio, f"estimated: the template's, scaled as {', '.join(measured)}"
    else:
        height, height_from = TEMPLATE_HEIGHT, "the template's: the file measures no trunk or leg"
    mass, mass_from = _mass(skeleton, mass, weighed)
    if skeleton["format"] == "c3d":
        origins = _hips(skeleton.get("hip_width"), height)
    subject = HumanSubject(height=height, mass=mass, segment_lengths=lengths, joint_origins=origins)
    scaled = tuple(s for s in SEGMENTS if s not in lengths)
    return BuiltSubject(subject, source, lengths, scaled, rejected, height_from, mass_from, used_map)

"""Generate the Human66 and Human48 URDFs of any subject from height, mass and segment lengths.

The models follow robotology's human-gazebo models: 23 links named as Xsens segments, the same
tree and joint names (`jL5S1_rotx`, ...), and a zero configuration that is a T-pose with every
link frame aligned with the world (x forward, y left, z up).

- Human66: each of the 22 joints is spherical, three revolute joints about x, y, z through
  zero-mass dummy links `<Segment>_f1`, `<Segment>_f2`, limits +-10 rad (none in effect).
- Human48: the reduced axes per joint and the clinical limits of the published 48-DoF model.

Dimensions: the template is human-gazebo's subject 1 (1.68 m, 62.2 kg). Every length expressed in
a segment's frame (its shape, its centre of mass, the joints of its children) scales with that
segment's factor: height / 1.68 by default, or measured / template length when a segment length
is given. Masses are fixed fractions of body mass; inertias are those of the segment's shape
(box, cylinder, sphere) with uniform density.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import ModelError

TEMPLATE_HEIGHT = 1.68  # m, human-gazebo subject 1
TEMPLATE_MASS = 62.2  # kg


@dataclass(frozen=True)
class Segment:
    """One body segment of the template subject (lengths in metres, in the segment frame)."""

    name: str
    parent: str | None  # parent segment; None for the base (Pelvis)
    joint: str | None  # joint name stem, e.g. "jL5S1"
    joint_origin: tuple[float, float, float]  # joint position in the parent segment's frame
    shape: str  # "box" (size x y z), "cylinder" (length, radius), "sphere" (radius)
    dims: tuple[float, ...]
    center: tuple[float, float, float]  # centre of mass and of the shape
    shape_rpy: tuple[float, float, float]  # orientation of the shape (cylinders along y for arms)
    mass: float  # kg for the template subject
    length: float  # the segment's main dimension, the one a measured length replaces


_ALONG_Y = (1.5708, 0.0, 0.0)  # URDF cylinders lie along z; arm cylinders along y
_NONE = (0.0, 0.0, 0.0)


def _right_left(name, parent, joint, origin, shape, dims, center, rpy, mass, length) -> list[Segment]:
    """The right segment as given and the left one mirrored in y."""
    mirror = lambda v: (v[0], -v[1], v[2])  # noqa: E731
    left_parent = parent.replace("Right", "Left")
    return [
        Segment("Right" + name, parent, "jRight" + joint, origin, shape, dims, center, rpy, mass, length),
        Segment("Left" + name, left_parent, "jLeft" + joint, mirror(origin), shape, dims, mirror(center), rpy,
                mass, length),
    ]


_TEMPLATE = (
    Segment("Pelvis", None, None, _NONE, "box", (0.13815, 0.24914, 0.097469), (0, 0, 0.049743), _NONE, 4.976, 0.098478),
    Segment("L5", "Pelvis", "jL5S1", (-0.000206, 0, 0.098478), "box", (0.13815, 0.16323, 0.095104), (0, 0, 0.047552), _NONE, 6.3444, 0.095104),
    Segment("L3", "L5", "jL4L3", (0.000374, 0, 0.095104), "box", (0.13815, 0.16323, 0.085916), (0, 0, 0.042958), _NONE, 6.3444, 0.085916),
    Segment("T12", "L3", "jL1T12", (0, 0, 0.085916), "box", (0.13815, 0.16323, 0.085916), (0, 0, 0.042958), _NONE, 6.3444, 0.085916),
    Segment("T8", "T12", "jT9T8", (0, 0, 0.085916), "box", (0.13457, 0.052626, 0.11975), (0, 0, 0.059874), _NONE, 2.488, 0.11975),
    Segment("Neck", "T8", "jT1C7", (0, 0, 0.11975), "cylinder", (0.089252, 0.014205), (0, 0, 0.044626), _NONE, 0.7464, 0.089252),
    Segment("Head", "Neck", "jC1Head", (0.000152, 0, 0.089252), "sphere", (0.089005,), (0, 0, 0.089005), _NONE, 2.2392, 0.17801),
    *_right_left("Shoulder", "T8", "C7Shoulder", (0, -0.026313, 0.067052), "cylinder", (0.13047, 0.023574), (0, -0.065233, 0), _ALONG_Y, 1.9282, 0.13047),
    *_right_left("UpperArm", "RightShoulder", "Shoulder", (0, -0.13047, 0), "cylinder", (0.26994, 0.029449), (0, -0.13497, 0), _ALONG_Y, 1.866, 0.26994),
    *_right_left("ForeArm", "RightUpperArm", "Elbow", (0, -0.26994, 0), "cylinder", (0.22247, 0.019633), (0, -0.11124, 0), _ALONG_Y, 1.244, 0.22247),
    *_right_left("Hand", "RightForeArm", "Wrist", (7.7e-05, -0.22247, 0), "box", (0.11145, 0.16718, 0.039266), (0, -0.083588, 0), _NONE, 0.3732, 0.16718),
    *_right_left("UpperLeg", "Pelvis", "Hip", (0.000103, -0.081614, 0.001009), "cylinder", (0.44898, 0.0565), (0, 0, -0.22449), _NONE, 7.775, 0.44898),
    *_right_left("LowerLeg", "RightUpperLeg", "Knee", (3.6e-05, 0, -0.44898), "cylinder", (0.40608, 0.037388), (0, 0, -0.20304), _NONE, 2.2703, 0.40608),
    *_right_left("Foot", "RightLowerLeg", "Ankle", (0.000205, 0, -0.40608), "box", (0.17983, 0.074775, 0.078509), (0.054652, 0, -0.039254), _NONE, 0.8086, 0.17983),
    *_right_left("Toe", "RightFoot", "BallFoot", (0.14456, 0, -0.064752), "box", (0.060173, 0.074775, 0.014191), (0.030086, 0, 0), _NONE, 0.0933, 0.060173),
)
# The Xsens segment order, which is also the order of links and joints in the published URDFs.
SEGMENTS = (
    "Pelvis", "L5", "L3", "T12", "T8", "Neck", "Head",
    "RightShoulder", "RightUpperArm", "RightForeArm", "RightHand",
    "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand",
    "RightUpperLeg", "RightLowerLeg", "RightFoot", "RightToe",
    "LeftUpperLeg", "LeftLowerLeg", "LeftFoot", "LeftToe",
)
TEMPLATE: tuple[Segment, ...] = tuple(sorted(_TEMPLATE, key=lambda s: SEGMENTS.index(s.name)))
# A frame fixed in each hand at its centre of mass, as in the published models.
HAND_COM = {"RightHand": (0.0, -0.096206, 0.0), "LeftHand": (0.0, 0.096206, 0.0)}

# Human48: the axes of each joint and their limits (rad), from the published 48-DoF model.
_SPINE2 = {"x": (-0.610865, 0.610865), "y": (-0.523599, 1.309)}
HUMAN48_JOINTS: dict[str, dict[str, tuple[float, float]]] = {
    "jL5S1": _SPINE2,
    "jL4L3": _SPINE2,
    "jL1T12": _SPINE2,
    "jT9T8": {"x": (-0.349066, 0.349066), "y": (-0.261799, 0.698132), "z": (-0.610865, 0.610865)},
    "jT1C7": {"x": (-0.610865, 0.610865), "y": (-0.959931, 1.5708), "z": (-1.22173, 1.22173)},
    "jC1Head": {"x": (-0.610865, 0.610865), "y": (-0.436332, 0.174533)},
    "jRightC7Shoulder": {"x": (-0.785398, 0.0872665)},
    "jRightShoulder": {"x": (-2.35619, 1.5708), "y": (-1.5708, 1.5708), "z": (-0.785398, 3.14159)},
    "jRightElbow": {"y": (-1.5708, 1.48353), "z": (0.0, 2.53073)},
    "jRightWrist": {"x": (-0.872665, 1.0472), "z": (-0.523599, 0.349066)},
    "jLeftC7Shoulder": {"x": (-0.0872665, 0.785398)},
    "jLeftShoulder": {"x": (-1.5708, 2.35619), "y": (-1.5708, 1.5708), "z": (-3.14159, 0.785398)},
    "jLeftElbow": {"y": (-1.5708, 1.48353), "z": (-2.53073, 0.0)},
    "jLeftWrist": {"x": (-1.0472, 0.872665), "z": (-0.349066, 0.523599)},
    "jRightHip": {"x": (-0.785398, 0.523599), "y": (-2.0944, 0.261799), "z": (-0.785398, 0.785398)},
    "jRightKnee": {"y": (0.0, 2.35619), "z": (-0.698132, 0.523599)},
    "jRightAnkle": {"x": (-0.610865, 0.785398), "y": (-0.523599, 0.872665), "z": (-0.436332, 0.872665)},
    "jRightBallFoot": {"y": (-0.174533, 1.5708)},
    "jLeftHip": {"x": (-0.523599, 0.785398), "y": (-2.0944, 0.261799), "z": (-0.785398, 0.785398)},
    "jLeftKnee": {"y": (0.0, 2.35619), "z": (-0.523599, 0.698132)},
    "jLeftAnkle": {"x": (-0.785398, 0.610865), "y": (-0.523599, 0.872665), "z": (-0.872665, 0.436332)},
    "jLeftBallFoot": {"y": (-0.174533, 1.5708)},
}
HUMAN66_LIMIT = 10.0  # rad: the published 66-DoF model's "no limit"
AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}


@dataclass(frozen=True)
class HumanSubject:
    """A subject: height (m), mass (kg), and optional measured segment lengths (m) by segment name.

    A measured length replaces the segment's main dimension (spine segments: joint to joint;
    limbs: joint to joint along the limb; hands, feet, toes: their length; head: its height).
    """

    height: float = TEMPLATE_HEIGHT
    mass: float = TEMPLATE_MASS
    segment_lengths: dict[str, float] = field(default_factory=dict)
    # measured joint placements (m): a segment's joint in its parent's frame, by the segment's name;
    # they replace the scaled template's (an Xsens MVNX file's pos_b points give them all)
    joint_origins: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def __post_init__(self):
        if not (0.5 <= self.height <= 2.5):
            raise ModelError(f"height {self.height} m is outside 0.5..2.5 m (give metres, not centimetres)")
        if not (5.0 <= self.mass <= 300.0):
            raise ModelError(f"mass {self.mass} kg is outside 5..300 kg")
        unknown = sorted(set(self.segment_lengths) - set(SEGMENTS))
        if unknown:
            raise ModelError(f"unknown segments {unknown}; valid: {', '.join(SEGMENTS)}")
        bad = {k: v for k, v in self.segment_lengths.items() if not (0.005 <= v <= 1.5)}
        if bad:
            raise ModelError(f"segment lengths out of 0.005..1.5 m: {bad}")
        placed = sorted(set(self.joint_origins) - set(SEGMENTS[1:]))
        if placed:
            raise ModelError(f"joint origins for {placed}: only segments with a parent have a joint; "
                             f"valid: {', '.join(SEGMENTS[1:])}")
        far = {k: v for k, v in self.joint_origins.items() if len(v) != 3 or not float(np.linalg.norm(v)) <= 1.5}
        if far:
            raise ModelError(f"joint origins must be 3 coordinates within 1.5 m of the parent's origin: {far}")

    def scale(self, segment: Segment) -> float:
        """Factor applied to every length expressed in this segment's frame."""
        if segment.name in self.segment_lengths:
            return self.segment_lengths[segment.name] / segment.length
        return self.height / TEMPLATE_HEIGHT


def _inertia(shape: str, dims: tuple[float, ...], mass: float, rpy: tuple[float, float, float]) -> np.ndarray:
    """Diagonal inertia (about the centre, segment axes) of a uniform box, cylinder or sphere."""
    if shape == "box":
        x, y, z = dims
        I = mass / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
    elif shape == "cylinder":
        length, r = dims
        side = mass * (3 * r * r + length * length) / 12.0
        I = np.array([side, side, mass * r * r / 2.0])
        if rpy == _ALONG_Y:  # the cylinder's axis is the segment's y axis
            I = I[[0, 2, 1]]
    else:
        (r,) = dims
        I = np.full(3, 0.4 * mass * r * r)
    return I


def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def human_urdf(dof: int = 66, subject: HumanSubject | None = None) -> str:
    """The URDF text of Human66 (dof=66) or Human48 (dof=48) for a subject (default: subject 1)."""
    if dof not in (66, 48):
        raise ModelError(f"human models have 66 or 48 DoF, not {dof}")
    subject = subject or HumanSubject()
    by_name = {s.name: s for s in TEMPLATE}
    mass_scale = subject.mass / TEMPLATE_MASS
    lines = ['<?xml version="1.0"?>',
             f"<!-- Human{dof}, generated by torchik.models.human for a subject of height {subject.height} m, "
             f"mass {subject.mass} kg; segment lengths {subject.segment_lengths or 'scaled from height'}"
             f"{f'; {len(subject.joint_origins)} joint origins measured' if subject.joint_origins else ''} -->",
             f'<robot name="Human{dof}">']
    joints: list[str] = []

    def link(name: str, seg: Segment | None = None) -> None:
        if seg is None:  # a dummy link between the revolute joints of one spherical joint
            lines.append(f'  <link name="{name}">\n    <inertial><mass value="0"/><origin xyz="0 0 0" rpy="0 0 0"/>'
                         f'<inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial>\n  </link>')
            return
        k = subject.scale(seg)
        dims = tuple(d * k for d in seg.dims)
        center = tuple(c * k for c in seg.center)
        mass = seg.mass * mass_scale
        I = _inertia(seg.shape, dims, mass, seg.shape_rpy)
        if seg.shape == "box":
            geometry = f'<box size="{_fmt(dims)}"/>'
        elif seg.shape == "cylinder":
            geometry = f'<cylinder length="{dims[0]:.9g}" radius="{dims[1]:.9g}"/>'
        else:
            geometry = f'<sphere radius="{dims[0]:.9g}"/>'
        origin = f'<origin xyz="{_fmt(center)}" rpy="{_fmt(seg.shape_rpy)}"/>'
        lines.append(
            f'  <link name="{name}">\n'
            f'    <inertial><mass value="{mass:.9g}"/><origin xyz="{_fmt(center)}" rpy="0 0 0"/>'
            f'<inertia ixx="{I[0]:.9g}" iyy="{I[1]:.9g}" izz="{I[2]:.9g}" ixy="0" ixz="0" iyz="0"/></inertial>\n'
            f"    <visual>{origin}<geometry>{geometry}</geometry></visual>\n"
            f"    <collision>{origin}<geometry>{geometry}</geometry></collision>\n"
            f"  </link>"
        )

    def joint(name, kind, parent, child, xyz, axis=None, limits=None) -> None:
        text = f'  <joint name="{name}" type="{kind}">\n    <origin xyz="{_fmt(xyz)}" rpy="0 0 0"/>\n' \
               f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
        if kind == "revolute":
            text += f'    <axis xyz="{_fmt(axis)}"/>\n    <limit effort="30" velocity="1.0" lower="{limits[0]:.9g}" ' \
                    f'upper="{limits[1]:.9g}"/>\n    <dynamics damping="0.1" friction="0.0"/>\n'
        joints.append(text + "  </joint>")

    for seg in TEMPLATE:
        if seg.parent is None or seg.joint is None:  # the root
            link(seg.name, seg)
            continue
        if dof == 66:
            axes = {a: (-HUMAN66_LIMIT, HUMAN66_LIMIT) for a in "xyz"}
        else:
            axes = HUMAN48_JOINTS[seg.joint]
        # the joint sits in the parent's frame, so it scales with the parent
        xyz = subject.joint_origins.get(seg.name) or tuple(c * subject.scale(by_name[seg.parent]) for c in seg.joint_origin)
        chain = [seg.parent] + [f"{seg.name}_f{i}" for i in range(1, len(axes))] + [seg.name]
        for name in chain[1:-1]:
            link(name)
        link(seg.name, seg)
        for i, (axis, lim) in enumerate(axes.items()):
            joint(f"{seg.joint}_rot{axis}", "revolute", chain[i], chain[i + 1], xyz if i == 0 else (0, 0, 0),
                  AXES[axis], lim)
        if seg.name in HAND_COM:
            link(f"{seg.name}COM")
            joint(f"j{seg.name}COM", "fixed", seg.name, f"{seg.name}COM",
                  tuple(c * subject.scale(seg) for c in HAND_COM[seg.name]))
    return "\n".join(lines + joints + ["</robot>", ""])


def write_human_models(directory: str | Path, subject: HumanSubject | None = None,
                       dofs: Sequence[int] = (66, 48)) -> list[Path]:
    """Write human66.urdf and human48.urdf (or those of `dofs`) for a subject into a directory; returns the paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for dof in dofs:
        path = directory / f"human{dof}.urdf"
        path.write_text(human_urdf(dof, subject))
        paths.append(path)
    return paths

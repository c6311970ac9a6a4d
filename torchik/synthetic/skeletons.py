"""Skeletons in other software's naming on the human models, to write the built-in scenarios as the
files users bring (`write_scenario_bvh`): the MotionBuilder HumanIK / Mixamo convention so far.

Each joint sits at its model link's origin in the zero configuration (the T-pose, every link frame
aligned with the world), so its offset from its parent joint is the difference of those origins,
and its orientation over time is its link's.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..io.bvh_writer import BvhJoint, write_bvh
from ..io.recording import Recording
from ..method.kinematics import KinematicModel

# (joint, parent joint, the human model's link): the HumanIK names, parents before children
HUMANIK = (
    ("Hips", None, "Pelvis"), ("Spine", "Hips", "L5"), ("Spine1", "Spine", "T12"), ("Spine2", "Spine1", "T8"),
    ("Neck", "Spine2", "Neck"), ("Head", "Neck", "Head"),
    *((f"{side}Shoulder", "Spine2", f"{side}Shoulder") for side in ("Right", "Left")),
    *((f"{side}Arm", f"{side}Shoulder", f"{side}UpperArm") for side in ("Right", "Left")),
    *((f"{side}ForeArm", f"{side}Arm", f"{side}ForeArm") for side in ("Right", "Left")),
    *((f"{side}Hand", f"{side}ForeArm", f"{side}Hand") for side in ("Right", "Left")),
    *((f"{side}UpLeg", "Hips", f"{side}UpperLeg") for side in ("Right", "Left")),
    *((f"{side}Leg", f"{side}UpLeg", f"{side}LowerLeg") for side in ("Right", "Left")),
    *((f"{side}Foot", f"{side}Leg", f"{side}Foot") for side in ("Right", "Left")),
    *((f"{side}ToeBase", f"{side}Foot", f"{side}Toe") for side in ("Right", "Left")),
)


def humanik_skeleton(model: KinematicModel, prefix: str = "", toes: bool = True) -> list[BvhJoint]:
    """The HumanIK skeleton of a human model (names with `prefix`, e.g. "mixamorig:"; without the
    ToeBase joints when toes is False)."""
    joints = [j for j in HUMANIK if toes or not j[0].endswith("ToeBase")]
    links = [link for _, _, link in joints]
    p0, R0, s0 = model.zero_configuration(1)
    origin = model(p0, R0, s0, links, jacobian=False).position[0].cpu().numpy()  # type: ignore[index]  # [J,3]
    names = [name for name, _, _ in joints]
    skeleton = []
    for i, (name, parent, link) in enumerate(joints):
        k = -1 if parent is None else names.index(parent)
        offset = origin[i] - (origin[k] if k >= 0 else 0.0 * origin[i])
        skeleton.append(BvhJoint(prefix + name, k, tuple(float(v) for v in offset), link))
    return skeleton


def write_scenario_bvh(path: str | Path, recording: Recording, model: KinematicModel, prefix: str = "",
                       toes: bool = True) -> Path:
    """A scenario's recording (in the human model's links) written as a HumanIK-named BVH file."""
    with torch.no_grad():
        skeleton = humanik_skeleton(model, prefix, toes)
    return write_bvh(path, recording, skeleton)

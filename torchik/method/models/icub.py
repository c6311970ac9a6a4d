"""The iCub humanoid (iCubGazeboV2_5 from the `icub-models` package) and its coupled shoulder limits."""

from __future__ import annotations

from pathlib import Path

import torch

from ...errors import ModelError, optional
from ..kinematics import KinematicModel, LinearLimits

ICUB_ROBOT = "iCubGazeboV2_5"

# Coupled limits of each arm on (shoulder pitch p, roll r, yaw y, elbow e, wrist prosup w), radians:
#   1.7105 (p - r) >= -6.0563;  -6.3979 <= 1.7105 (p - r - y) <= 1.9622;  -1.1623 <= r + y <= 3.7228;
#   r + 0.0427 y >= 0.4611;  r <= 1.7453;  2.5 e + w <= 5.2796;  -2.5 e + w >= -5.2796.
# Written as rows a . (p, r, y, e, w) <= b:
_ARM_ROWS = (
    ((-1.7105, 1.7105, 0.0, 0.0, 0.0), 6.0563, "1.7105 (p - r) >= -6.0563"),
    ((1.7105, -1.7105, -1.7105, 0.0, 0.0), 1.9622, "1.7105 (p - r - y) <= 1.9622"),
    ((-1.7105, 1.7105, 1.7105, 0.0, 0.0), 6.3979, "1.7105 (p - r - y) >= -6.3979"),
    ((0.0, 1.0, 1.0, 0.0, 0.0), 3.7228, "r + y <= 3.7228"),
    ((0.0, -1.0, -1.0, 0.0, 0.0), 1.1623, "r + y >= -1.1623"),
    ((0.0, -1.0, -0.0427, 0.0, 0.0), -0.4611, "r + 0.0427 y >= 0.4611"),
    ((0.0, 1.0, 0.0, 0.0, 0.0), 1.7453, "r <= 1.7453"),
    ((0.0, 0.0, 0.0, 2.5, 1.0), 5.2796, "2.5 e + w <= 5.2796"),
    ((0.0, 0.0, 0.0, 2.5, -1.0), 5.2796, "-2.5 e + w >= -5.2796"),
)
_ARM_JOINTS = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_prosup")


def icub_urdf_path() -> Path:
    """Path of iCubGazeboV2_5's URDF inside the installed `icub-models` package."""
    icub_models = optional("icub_models", "robots", "the iCub model")
    path = Path(icub_models.get_model_file(ICUB_ROBOT))
    if not path.is_file():
        raise ModelError(f"icub-models has no {ICUB_ROBOT} model at {path}")
    return path


def icub_coupled_limits(joint_names: tuple[str, ...]) -> LinearLimits:
    """Both arms' coupled limits as `A s <= b` over a model's joint order. A: [18, n], b: [18]."""
    index = {name: i for i, name in enumerate(joint_names)}
    A, b, names = [], [], []
    for side in ("r", "l"):
        cols = [index[f"{side}_{j}"] for j in _ARM_JOINTS]
        for coefficients, bound, text in _ARM_ROWS:
            row = [0.0] * len(joint_names)
            for c, a in zip(cols, coefficients):
                row[c] = a
            A.append(row)
            b.append(bound)
            names.append(f"{side}: {text}")
    return LinearLimits(torch.tensor(A, dtype=torch.float64), torch.tensor(b, dtype=torch.float64), tuple(names))


def load_icub(dtype=torch.float64, device="cpu") -> KinematicModel:
    """iCub with its 32 revolute joints, joint limits and coupled shoulder limits."""
    model = KinematicModel.from_urdf(icub_urdf_path(), name="iCub", dtype=dtype, device=device)
    model.linear_limits = icub_coupled_limits(model.joint_names).to(dtype, device)
    return model

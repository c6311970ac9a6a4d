"""The models torchik ships: Human66, Human48 (generated for any subject) and iCub.

`load_model(name)` returns a compiled KinematicModel; `MODELS` lists the names.
"""

from __future__ import annotations

import torch

from ...errors import ModelError
from ..kinematics import KinematicModel
from .human import SEGMENTS, HumanSubject, human_urdf, write_human_models
from .icub import icub_coupled_limits, icub_urdf_path, load_icub

MODELS = ("human66", "human48", "icub")

# The links tracked by default: the 23 Xsens segments, and on iCub the links the human-to-iCub
# retargeting maps them to.
TRACKED_LINKS = {
    "human66": SEGMENTS,
    "human48": SEGMENTS,
    "icub": ("root_link", "chest", "head", "r_upper_arm", "r_forearm", "r_hand", "l_upper_arm", "l_forearm",
             "l_hand", "r_upper_leg", "r_lower_leg", "r_foot", "l_upper_leg", "l_lower_leg", "l_foot"),
}


def load_model(name: str, subject: HumanSubject | None = None, dtype=torch.float64, device="cpu") -> KinematicModel:
    """A model by name ('human66', 'human48', 'icub'); human models for `subject` (default subject 1)."""
    key = name.lower()
    if key in ("human66", "human48"):
        text = human_urdf(int(key[-2:]), subject)
        return KinematicModel.from_urdf(text, name=f"Human{key[-2:]}", dtype=dtype, device=device)
    if key == "icub":
        if subject is not None:
            raise ModelError("a human subject was given for the iCub model")
        return load_icub(dtype=dtype, device=device)
    raise ModelError(f"unknown model {name!r}; valid models: {', '.join(MODELS)}")


__all__ = ["MODELS", "TRACKED_LINKS", "load_model", "HumanSubject", "human_urdf", "write_human_models",
           "icub_urdf_path", "icub_coupled_limits", "load_icub", "SEGMENTS"]

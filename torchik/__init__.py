"""torchik: real-time, model-based motion tracking by dynamical inverse kinematics on SO(3)."""

from .errors import InputError, ModelError, TorchikError, UnknownLinkError
from .kinematics import KinematicModel, LinearLimits, LinkKinematics

__version__ = "0.1.0"
__all__ = ["KinematicModel", "LinearLimits", "LinkKinematics", "TorchikError", "ModelError",
           "UnknownLinkError", "InputError"]

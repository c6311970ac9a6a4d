"""Motion data: the recording format and readers for Xsens MVNX and BVH (C3D to follow)."""

from .recording import Recording, RecordingError, angular_velocity_from_orientations, load_recording, save_recording
from .mvnx import read_mvnx
from .bvh import read_bvh

__all__ = ["Recording", "RecordingError", "load_recording", "save_recording", "read_mvnx", "read_bvh",
           "angular_velocity_from_orientations"]

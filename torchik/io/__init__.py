"""Motion data: the recording format and readers for Xsens MVNX, BVH and C3D (Plug-in Gait)."""

from .recording import Recording, RecordingError, angular_velocity_from_orientations, load_recording, save_recording
from .mvnx import read_mvnx
from .bvh import read_bvh
from .c3d import read_c3d
from .maps import LinkMap, apply_map, calibrate, load_map, map_recording

__all__ = ["Recording", "RecordingError", "load_recording", "save_recording", "read_mvnx", "read_bvh", "read_c3d", "LinkMap", "load_map", "apply_map", "calibrate", "map_recording",
           "angular_velocity_from_orientations"]

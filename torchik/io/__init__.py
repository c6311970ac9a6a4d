"""Motion data: the recording format, readers for Xsens MVNX, BVH and C3D (Plug-in Gait), link
maps, the conversion of a recording to tracker targets, and the files torchik writes."""

from .bvh import read_bvh
from .c3d import read_c3d
from .files import replacing, write_json
from .formats import READERS, open_recording, read
from .maps import LinkMap, apply_map, calibrate, load_map, map_recording
from .mvnx import read_mvnx
from .recording import Recording, RecordingError, angular_velocity_from_orientations, save_recording
from .recording_file import RecordingFile, load_recording
from .targets import recording_targets
from .trajectory import TrajectoryWriter, save_trajectory

__all__ = ["Recording", "RecordingError", "load_recording", "save_recording", "read", "READERS", "read_mvnx",
           "RecordingFile", "open_recording", "TrajectoryWriter",
           "read_bvh", "read_c3d", "LinkMap", "load_map", "apply_map", "calibrate", "map_recording",
           "angular_velocity_from_orientations", "recording_targets", "save_trajectory", "replacing", "write_json"]

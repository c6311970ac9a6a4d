"""Motion data: the recording format, readers for Xsens MVNX, BVH, C3D (Plug-in Gait) and OpenSense
quaternion tables, link maps, the conversion of a recording to tracker targets, and the files
torchik writes (trajectories; OpenSim motions and orientation errors)."""

from .bvh import read_bvh
from .c3d import read_c3d
from .files import replacing, write_json
from .formats import READERS, open_recording, read
from .maps import LinkMap, apply_map, calibrate, load_map, map_recording
from .mvnx import read_mvnx
from .opensense import read_opensense, write_opensense
from .opensim_out import read_motion
from .recording import Recording, RecordingError, angular_velocity_from_orientations, save_recording
from .recording_file import RecordingFile, load_recording
from .targets import recording_targets
from .trajectory import TrajectoryWriter, save_trajectory

__all__ = ["Recording", "RecordingError", "load_recording", "save_recording", "read", "READERS", "read_mvnx",
           "RecordingFile", "open_recording", "TrajectoryWriter",
           "read_bvh", "read_c3d", "read_opensense", "write_opensense", "read_motion",
           "LinkMap", "load_map", "apply_map", "calibrate", "map_recording",
           "angular_velocity_from_orientations", "recording_targets", "save_trajectory", "replacing", "write_json"]

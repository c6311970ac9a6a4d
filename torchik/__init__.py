"""torchik: real-time, model-based motion tracking by dynamical inverse kinematics on SO(3).

    import torchik as tk

    model, links = tk.load_model("human66"), tk.TRACKED_LINKS["human66"]
    recording = tk.read("walk.mvnx")                 # or tk.scenario("walking", model, links)
    trajectory, report = tk.track(model, recording, links)

The package has four layers, each importing only from those below it: `method/` (the paper's
algorithm), `io/` and `synthetic/` (data), `pipelines/` (track, retarget, diagnosis, cohort,
experiment, bench, rrd), `cli/` (the `torchik` command).
"""

from .data import version
from .errors import InputError, ModelError, TorchikError, UnknownLinkError
from .io import (
    Recording,
    RecordingError,
    load_map,
    load_recording,
    map_recording,
    read,
    recording_targets,
    save_recording,
    save_trajectory,
)
from .method import so3
from .method.constraints import ContactLimit, Limit
from .method.dynamics import InverseDynamics, inverse_dynamics, trajectory_dynamics
from .method.kinematics import KinematicModel, LinearLimits, LinkKinematics
from .method.kinematics.mass import centre_of_mass
from .method.limits import LimitSettings
from .method.metrics import angular_velocity_rmse, mnte, orientation_error
from .method.models import MODELS, TRACKED_LINKS, HumanSubject, load_model
from .method.settings import TrackerSettings
from .method.state import State, StepDiagnostics, TargetSequence, Trajectory
from .method.targets import Targets
from .method.tasks import (
    CentreOfMassTask,
    ContactTask,
    OrientationTask,
    PositionTask,
    PostureTask,
    RelativePositionTask,
    StepContext,
    Task,
    TaskTerms,
)
from .method.tracker import DynamicalIK
from .pipelines.diagnosis.loop import diagnose
from .pipelines.memory import keep_freed_memory
from .pipelines.retarget import retarget
from .pipelines.track import track_recording as track
from .synthetic.motion import periodic_motion, targets_from_motion
from .synthetic.scenarios import SCENARIOS, scenario

__version__ = version()  # pyproject.toml's, as installed
__all__ = [
    "__version__",
    # models and kinematics
    "load_model", "MODELS", "TRACKED_LINKS", "HumanSubject", "KinematicModel", "LinearLimits", "LinkKinematics",
    "so3", "centre_of_mass", "inverse_dynamics", "trajectory_dynamics", "InverseDynamics",
    # the tracker
    "DynamicalIK", "TrackerSettings", "LimitSettings", "State", "StepDiagnostics", "Targets", "TargetSequence", "Trajectory",
    "mnte", "angular_velocity_rmse", "orientation_error",
    # tasks and limits beyond the paper's
    "Task", "TaskTerms", "StepContext", "OrientationTask", "PositionTask", "PostureTask", "CentreOfMassTask",
    "RelativePositionTask", "ContactTask", "Limit", "ContactLimit",
    # data
    "read", "Recording", "load_recording", "save_recording", "save_trajectory", "load_map", "map_recording",
    "recording_targets", "scenario", "SCENARIOS", "periodic_motion", "targets_from_motion",
    # pipelines
    "track", "retarget", "diagnose", "log_trajectory", "keep_freed_memory",
    # errors
    "TorchikError", "ModelError", "UnknownLinkError", "InputError", "RecordingError",
]


def __getattr__(name: str):
    # rerun is an optional dependency (torchik[viz]): imported when a recording is written, not with torchik
    if name == "log_trajectory":
        from .pipelines.rrd import log_trajectory

        return log_trajectory
    raise AttributeError(f"module 'torchik' has no attribute {name!r}")

"""What a diagnosis leaves for `torchik track`: the calibration file and the augmented URDF.

The calibration file (JSON, `format: torchik-calibration/1`) lists the measurement effects found,
in the order they were added, each as `Effect.to_json()` writes it (kind, target, params, ...), and
`fit`: where the values and standard errors come from (the joint fit at the end, jointfit.py).
Applying it undoes them in a recording of the same session, after the link map if there was one
(its targets are the model's links):

    torchik track --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48 \
                  --sensor-calibration DIR/calibration.json --urdf DIR/model.urdf
"""

from __future__ import annotations

import json
from pathlib import Path

from ...errors import InputError
from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from . import drift, frames, gyro, joints, placement, position, posture

FORMAT = "torchik-calibration/1"

EFFECT_TYPES = {"gyro_bias": gyro.GyroBias, "gyro_scale": gyro.GyroScale, "stream_delay": gyro.StreamDelay,
                "misalignment": placement.Misalignment, "sensor_delay": placement.SensorDelay,
                "heading_drift": drift.HeadingDrift, "missing_dof": joints.MissingDof,
                "joint_limit": joints.JointLimit, "position_offset": position.PositionOffset,
                "static_pose": posture.StaticPose, "flipped_frame": frames.FlippedFrame,
                "swapped_segments": frames.SwappedSegments}


def apply_calibration(recording: Recording, calibration: dict) -> Recording:
    """Undo the measurement effects of a calibration (Diagnosis.calibration(), or its JSON file) in a
    recording of the same sensors (the same session)."""
    for item in calibration["effects"]:
        recording = EFFECT_TYPES[item["kind"]](item["kind"], item["target"], dict(item["params"])).correct(recording)
    return recording


def load_calibration(path: str | Path) -> dict:
    """A calibration file, checked: its format, known effect kinds. Raises InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such calibration file (torchik diagnose writes DIR/calibration.json)")
    try:
        calibration = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc})") from None
    if not isinstance(calibration, dict) or calibration.get("format") != FORMAT:
        raise InputError(f"{path}: not a torchik calibration file (expected format {FORMAT!r})")
    unknown = sorted({item.get("kind") for item in calibration.get("effects", [])} - set(EFFECT_TYPES))
    if unknown:
        raise InputError(f"{path}: unknown effects {unknown}; known: {', '.join(EFFECT_TYPES)}")
    return calibration


def apply_calibration_file(recording: Recording, path: str | Path) -> Recording:
    """apply_calibration with a calibration file; its sensors must be the recording's links."""
    calibration = load_calibration(path)
    targets = {name for item in calibration["effects"]
               for name in item["params"].get("links", [item["target"]])}
    missing = sorted(targets - set(recording.links))
    if missing:
        raise InputError(f"{path}: calibrates sensors {missing} that the recording lacks (its links: "
                         f"{', '.join(recording.links)}); apply it after the same --map as the diagnosis")
    return apply_calibration(recording, calibration)


def load_urdf_model(path: str | Path, name: str = "", device="cpu") -> KinematicModel:
    """A model from a URDF file (e.g. the model.urdf a diagnosis writes), named `name`+."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such URDF file")
    return KinematicModel.from_urdf(path, name=f"{name}+" if name else path.stem, device=device)

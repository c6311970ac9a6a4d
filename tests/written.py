"""Files the tests write themselves, laid out as the real recordings in ../shared/data are (see its
README), from built-in scenarios whose truth is known: a Vicon Plug-in Gait static and dynamic
trial (C3D, written with ezc3d), an Xsens MVN export (MVNX, torchik.io.mvnx_writer) and a HumanIK
BVH (torchik.synthetic.skeletons). On a clone without ../shared they are what the readers, the
maps and the commands that read files run on.

- C3D: every Plug-in Gait segment's four virtual points (origin and the ends of its 92 mm
  anterior, lateral and proximal axes, each segment's frame off the model link's by the misalignment
  of its markers), the hip joint centres, skin markers, model outputs (angles; the kinetic ones
  never measured: no force plate, residual -1 throughout), unlabelled trajectories (`*12`), more
  than 255 labels (LABELS2),
  millimetres, the subject's PROCESSING parameters, occlusions as Vicon writes them (residual -1).
- MVNX: segments with their joints' points, 17 sensors strapped on at known rotations, the joints,
  the identity, tpose and tpose-isb calibration frames, then the normal frames.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from torchik.io.maps import load_map, reference_configuration
from torchik.io.mvnx_writer import MvnxSensor, write_mvnx
from torchik.io.recording import Recording
from torchik.method import so3
from torchik.method.models import TRACKED_LINKS
from torchik.method.models.human import TEMPLATE, HumanSubject
from torchik.synthetic.scenarios import scenario

AXIS_MM = 92.0  # the length of a Plug-in Gait triad's axes in the real files
BY_NAME = {s.name: s for s in TEMPLATE}


def _kinematics(model, p: torch.Tensor, R: torch.Tensor, s: torch.Tensor, links):
    with torch.no_grad():
        return model(p, R, s, tuple(links), jacobian=False)


def with_origins(recording: Recording, model) -> Recording:
    """A scenario's recording with every link's origin (`position`), from the model at its true configuration."""
    base = recording.links.index(recording.base_link)
    kin = _kinematics(model, torch.from_numpy(recording.base_position),
                      torch.from_numpy(recording.orientation[:, base]), torch.from_numpy(recording.joint_positions),
                      recording.links)
    return Recording(**{**vars(recording), "position": kin.position.numpy()})


def walk(model, name: str = "walking", seconds: float = 2.0, rate: float = 100.0, seed: int = 0) -> Recording:
    """A built-in scenario on every tracked link of `model`, with the links' origins."""
    return with_origins(scenario(name, model, TRACKED_LINKS[model.name.lower()], seconds, rate, seed=seed), model)


def standing_height(model) -> float:
    """The base's height with the lowest link origin on the floor, in the zero configuration."""
    p0, R0, s0 = model.zero_configuration(1)
    return float(-_kinematics(model, p0, R0, s0, model.link_names).position[0, :, 2].min())


def standing(model, pose: str, frames: int, rate: float) -> Recording:
    """A static trial: the subject still in a reference pose ('npose': arms down; 'tpose'), facing +x."""
    links = TRACKED_LINKS[model.name.lower()]
    p0, R0, _ = model.zero_configuration(1)
    p0[0, 2] = standing_height(model)
    s = reference_configuration(model, pose)
    kin = _kinematics(model, p0, R0, s, links)
    ones = np.ones(frames)
    return Recording(time=np.arange(frames) / rate, links=links,
                     orientation=np.einsum("t,nij->tnij", ones, kin.rotation[0].numpy()),
                     angular_velocity=np.zeros((frames, len(links), 3)), base_link=model.base_link,
                     base_position=np.einsum("t,i->ti", ones, p0[0].numpy()),
                     base_linear_velocity=np.zeros((frames, 3)), joint_names=model.joint_names,
                     joint_positions=np.einsum("t,j->tj", ones, s[0].numpy()),
                     position=np.einsum("t,ni->tni", ones, kin.position[0].numpy()),
                     meta=dict(source=f"torchik static {pose}", frame_rate=rate))


# ------------------------------------------------------------------------------------------------ MVNX

XSENS_SENSORS = ("Pelvis", "T8", "Head", "RightShoulder", "RightUpperArm", "RightForeArm", "RightHand", "LeftShoulder",
                 "LeftUpperArm", "LeftForeArm", "LeftHand", "RightUpperLeg", "RightLowerLeg", "RightFoot",
                 "LeftUpperLeg", "LeftLowerLeg", "LeftFoot")  # MVN Link, full body


def sensor_placements(seed: int = 7) -> list[MvnxSensor]:
    """The 17 sensors, each strapped on at its own rotation (up to about 0.6 rad) from its segment's frame."""
    g = torch.Generator().manual_seed(seed)
    turns = 0.35 * torch.randn(len(XSENS_SENSORS), 3, generator=g, dtype=torch.float64)
    return [MvnxSensor(name, so3.exp(w).numpy()) for name, w in zip(XSENS_SENSORS, turns)]


def xsens_skeleton(model) -> tuple[dict[str, dict[str, tuple[float, ...]]], list[tuple[str, str, str]]]:
    """The MVNX points (each segment's own joint at its origin, its children's joints, a few landmarks;
    m, in the segment's frame) and joints (label, parent, child) of a human model: its joint placements
    are the differences of the link origins in the zero configuration, where every link frame is the world's."""
    names = [s.name for s in TEMPLATE]
    p0, R0, s0 = model.zero_configuration(1)
    origin = dict(zip(names, _kinematics(model, p0, R0, s0, names).position[0].numpy()))
    points: dict[str, dict[str, tuple[float, ...]]] = {"Pelvis": {"pHipOrigin": (0.0, 0.0, 0.0)}}
    joints = []
    for seg in TEMPLATE[1:]:
        assert seg.parent is not None and seg.joint is not None
        points.setdefault(seg.name, {})[seg.joint] = (0.0, 0.0, 0.0)
        points.setdefault(seg.parent, {})[seg.joint] = tuple(float(v) for v in origin[seg.name] - origin[seg.parent])
        joints.append((seg.joint, seg.parent, seg.name))
    points["Head"]["pTopOfHead"] = (0.0, 0.0, float(2 * BY_NAME["Head"].dims[0]))
    return points, joints


def xsens_calibration(model, links) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The identity and T-pose frames (the human models' zero configuration, standing on the floor: every
    segment frame the world's) and tpose-isb (the T-pose with the arms' frames in ISB axes: a quarter
    turn about x, the y axis along the bone)."""
    p0, R0, s0 = model.zero_configuration(1)
    p0[0, 2] = standing_height(model)
    kin = _kinematics(model, p0, R0, s0, links)
    R, p = kin.rotation[0].numpy(), kin.position[0].numpy()
    quarter = {"Right": so3.exp(torch.tensor([-math.pi / 2, 0, 0], dtype=torch.float64)).numpy(),
               "Left": so3.exp(torch.tensor([math.pi / 2, 0, 0], dtype=torch.float64)).numpy()}

    def isb(link: str, R_link: np.ndarray) -> np.ndarray:
        if not link.endswith(("Shoulder", "UpperArm", "ForeArm", "Hand")):
            return R_link
        return R_link @ quarter["Right" if link.startswith("Right") else "Left"]

    return {"identity": (R, p), "tpose": (R, p), "tpose-isb": (np.stack([isb(*x) for x in zip(links, R)]), p)}


def xsens_mvnx(path: str | Path, model, recording: Recording) -> Path:
    """`recording` (a human model's scenario with its origins) as an MVN export: segments, sensors, joints,
    calibration frames, normal frames."""
    points, joints = xsens_skeleton(model)
    return write_mvnx(path, recording, points, sensor_placements(), joints, xsens_calibration(model, recording.links),
                      label="MVN System 1")


# ------------------------------------------------------------------------------------------------- C3D

PIG_LINK = {e.segment: e.link for e in load_map("plugin_gait_to_human").entries}  # PEL -> Pelvis, ...
# each segment's origin: (link, point in the link's frame as a multiple of a template length) — Plug-in
# Gait puts a bone's origin at its distal joint (the femur's at the knee), the pelvis's between the hips
PIG_ORIGIN = {"PEL": ("Pelvis", None), "TRX": ("T8", None), "HED": ("Head", (0.0, 0.0, 0.5)),
              **{f"{s[0]}{seg}": (f"{s}{link}", None) for s in ("Right", "Left") for seg, link in
                 (("CL", "UpperArm"), ("HU", "ForeArm"), ("RA", "Hand"), ("FE", "LowerLeg"), ("TI", "Foot"),
                  ("FO", "Toe"))},
              "RHN": ("RightHand", (0.0, -1.0, 0.0)), "LHN": ("LeftHand", (0.0, 1.0, 0.0)),
              "RTO": ("RightToe", (1.0, 0.0, 0.0)), "LTO": ("LeftToe", (1.0, 0.0, 0.0))}
# skin markers: (link, position in the link's frame, m, template subject) and the segments each defines
MARKERS = {
    "LFHD": ("Head", (0.08, 0.05, 0.12), ("HED",)), "RFHD": ("Head", (0.08, -0.05, 0.12), ("HED",)),
    "LBHD": ("Head", (-0.08, 0.05, 0.12), ("HED",)), "RBHD": ("Head", (-0.08, -0.05, 0.12), ("HED",)),
    "C7": ("T8", (-0.06, 0.0, 0.12), ("TRX",)), "CLAV": ("T8", (0.08, 0.0, 0.1), ("TRX",)),
    "STRN": ("T8", (0.1, 0.0, 0.0), ("TRX",)), "T10": ("T12", (-0.08, 0.0, 0.04), ("TRX",)),
    "LASI": ("Pelvis", (0.08, 0.13, 0.09), ("PEL",)), "RASI": ("Pelvis", (0.08, -0.13, 0.09), ("PEL",)),
    "SACR": ("Pelvis", (-0.09, 0.0, 0.1), ("PEL",)),
    **{f"{s[0]}{name}": (f"{s}{link}", (x, sign * y, z), tuple(f"{s[0]}{seg}" for seg in segments))
       for s, sign in (("Right", 1.0), ("Left", -1.0)) for name, link, (x, y, z), segments in (
           ("SHO", "Shoulder", (0.0, -0.12, 0.05), ("CL", "HU")), ("ELB", "UpperArm", (-0.03, -0.27, 0.0), ("HU", "RA")),
           ("WRA", "ForeArm", (0.02, -0.22, 0.0), ("RA", "HN")), ("FIN", "Hand", (0.0, -0.09, 0.0), ("HN",)),
           ("THI", "UpperLeg", (0.0, -0.07, -0.25), ("FE",)), ("KNE", "UpperLeg", (0.0, -0.06, -0.45), ("FE", "TI")),
           ("TIB", "LowerLeg", (0.0, -0.05, -0.2), ("TI",)), ("ANK", "LowerLeg", (0.0, -0.04, -0.41), ("TI", "FO")),
           ("HEE", "Foot", (-0.05, 0.0, -0.05), ("FO",)), ("TOE", "Toe", (0.0, 0.0, 0.0), ("FO", "TO")))},
}
ANGLES = tuple(f"{s}{joint}Angles" for s in "LR" for joint in ("Hip", "Knee", "Ankle", "Shoulder", "Elbow", "Wrist"))
KINETICS = tuple(f"{s}{joint}{kind}" for kind in ("Force", "Moment", "Power") for s in "LR"
                 for joint in ("Ankle", "Knee", "Hip", "Waist", "Neck", "Shoulder", "Elbow", "Wrist"))
UNLABELLED = tuple(f"*{k}" for k in range(100))  # what Vicon could not label: seen now and then, away from the body


def pig_misalignment(segment: str) -> np.ndarray:
    """How far a Plug-in Gait segment's frame is from the model link's when the subject stands in the
    N-pose (its markers' placement: a few degrees; the pelvis tilted forward, its heading kept; the
    femur and tibia only turned about their long axes, which run through the joint centres as the
    model's thigh and shank do)."""
    if segment == "PEL":
        return so3.exp(torch.tensor([0.0, 0.2, 0.0], dtype=torch.float64)).numpy()
    g = torch.Generator().manual_seed(sum(map(ord, segment)))
    turn = 0.08 * torch.randn(3, generator=g, dtype=torch.float64)
    if segment[1:] in ("FE", "TI"):
        turn[:2] = 0.0
    return so3.exp(turn).numpy()


def pig_frames(model, recording: Recording) -> dict[str, np.ndarray]:
    """Each Plug-in Gait segment's rotation [T,3,3] over `recording`: its link's, R_link R_npose^T M with
    R_npose the link's in the model's N-pose and M the segment's misalignment. So the segment frames are
    the world's (up to M) when the subject stands in the N-pose facing +x, the map's calibration pose."""
    p0, R0, _ = model.zero_configuration(1)
    npose = _kinematics(model, p0, R0, reference_configuration(model, "npose"), list(PIG_LINK.values())).rotation[0]
    index = {link: i for i, link in enumerate(recording.links)}
    return {seg: recording.orientation[:, index[link]] @ npose[k].numpy().T @ pig_misalignment(seg)
            for k, (seg, link) in enumerate(PIG_LINK.items())}


def processing(model, subject: HumanSubject) -> dict[str, float]:
    """Plug-in Gait's PROCESSING parameters of the subject (mm, kg): what the Vicon session measured."""
    length = {name: 1000.0 * s.length * subject.scale(s) for name, s in BY_NAME.items()}
    return {"Height": 1000.0 * subject.height, "Bodymass": subject.mass, "MarkerDiameter": 14.0,
            **{f"{side[0]}{what}Length": length[f"{side}{link}"] for side in ("Right", "Left")
               for what, link in (("Femur", "UpperLeg"), ("Tibia", "LowerLeg"), ("Foot", "Foot"))}}


def plug_in_gait_c3d(path: str | Path, model, recording: Recording, subject: HumanSubject | None = None,
                     occluded: dict[str, slice] | None = None, zeroed: dict[str, slice] | None = None) -> Path:
    """`recording` (a human model's scenario with its origins, or a static trial) written as a Vicon
    Plug-in Gait C3D at 'path' (ezc3d). occluded: marker -> frames where Vicon lost it (the marker and
    every segment it defines written with residual -1); zeroed: point label -> frames written as zeros
    (how some exporters mark a gap)."""
    import ezc3d

    subject = subject or HumanSubject()
    T = len(recording.time)
    index = {link: i for i, link in enumerate(recording.links)}
    R_link, origin = recording.orientation, recording.position
    assert origin is not None

    def point(link: str, local) -> np.ndarray:  # [T,3] a point fixed in a link, m
        return origin[:, index[link]] + R_link[:, index[link]] @ np.asarray(local, dtype=np.float64)

    columns: dict[str, np.ndarray] = {}
    for seg, R in pig_frames(model, recording).items():
        link, along = PIG_ORIGIN[seg]
        scale = BY_NAME[link].length * subject.scale(BY_NAME[link])
        O = 1000.0 * (point(link, tuple(scale * a for a in along)) if along else origin[:, index[link]])
        columns[seg + "O"] = O
        for k, axis in enumerate("ALP"):
            columns[seg + axis] = O + AXIS_MM * R[:, :, k]
    for side in ("Right", "Left"):
        columns[f"{side[0]}HJC"] = 1000.0 * origin[:, index[f"{side}UpperLeg"]]
    size = subject.height / 1.68
    for name, (link, local, _) in MARKERS.items():
        columns[name] = 1000.0 * point(link, tuple(size * v for v in local))
    base = recording.links.index(recording.base_link)
    columns["CentreOfMass"] = 1000.0 * recording.base_position + np.array([0.0, 0.0, 80.0])
    for i, name in enumerate(ANGLES):  # degrees, stored as points: any three numbers the reader must ignore
        columns[name] = np.degrees(so3.log(torch.from_numpy(R_link[:, base])).numpy()) + i
    for name in KINETICS:
        columns[name] = np.zeros((T, 3))
    for k, name in enumerate(UNLABELLED):
        columns[name] = np.array([3000.0 + 10 * k, -2000.0, 10.0 * k]) + np.zeros((T, 3))
    labels = list(columns)
    points = np.ones((4, len(labels), T))
    points[:3] = np.stack([columns[label] for label in labels], 1).transpose(2, 1, 0)
    residual = np.zeros((1, len(labels), T))
    residual[0, [labels.index(k) for k in KINETICS]] = -1.0  # no force plate: the kinetics never measured
    for k, name in enumerate(UNLABELLED):
        residual[0, labels.index(name), np.arange(T) % len(UNLABELLED) != k] = -1.0
    for marker, frames in (occluded or {}).items():
        for label in [marker, *(seg + axis for seg in MARKERS[marker][2] for axis in "OALP")]:
            residual[0, labels.index(label), frames] = -1.0
            points[:3, labels.index(label), frames] = 0.0
    for label, frames in (zeroed or {}).items():
        points[:3, labels.index(label), frames] = 0.0

    c3d = ezc3d.c3d()
    rate = recording.frame_rate
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c3d.add_parameter("POINT", "UNITS", ["mm"])
    c3d.add_parameter("TRIAL", "CAMERA_RATE", [rate])
    c3d.add_parameter("SUBJECTS", "NAMES", ["HC000"])
    c3d.add_parameter("MANUFACTURER", "COMPANY", ["Vicon"])
    for name, value in processing(model, subject).items():
        c3d.add_parameter("PROCESSING", name, [value])
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residual, "camera_masks": np.zeros((7, len(labels), T), dtype=bool)}
    path = Path(path)
    c3d.write(str(path))
    return path

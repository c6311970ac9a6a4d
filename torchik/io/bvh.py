"""BVH (Biovision hierarchy) to a Recording.

- Rotations are Euler angles in degrees, in the order each joint's CHANNELS lists them:
  `Zrotation Xrotation Yrotation` means R = Rz(z) Rx(x) Ry(y) (child frame to parent frame).
- A joint's translation from its parent is its position channels when it has them (Bandai's
  exporter writes the full translation there), otherwise its OFFSET.
- Units: centimetres, metres, inches, or CMU's 1/0.45 inch, told apart by the height of the posed
  skeleton in the first frame (the ranges a person's height can take in each do not overlap);
  `units=` or `scale=` overrides, and an undecidable file is an error asking for them.
- The BVH world is Y-up; torchik's is z-up, x forward: (X, Y, Z)_bvh -> (Z, X, Y).
- Segment frames are the bones' own, not anatomical ones: a link map calibrates the constant
  offset to a model's links.
- Angular velocity: central differences on SO(3); base velocity: central differences.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..method import so3
from .recording import Recording, RecordingError, angular_velocity_from_orientations, readable_file

UNITS = {"cm": 0.01, "m": 1.0, "inch": 0.0254, "cmu": 0.0254 / 0.45}
HEIGHT_RANGE_M = (1.05, 2.25)  # vertical extent of a person's joints, metres: disjoint across UNITS
Y_UP_TO_Z_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


@dataclass
class _Joint:
    name: str
    parent: int
    offset: np.ndarray
    channels: list[str]
    first_channel: int


def _axis_rotation(axis: str, degrees: np.ndarray) -> np.ndarray:
    """[T] angles -> [T,3,3] rotation about x, y or z."""
    a = np.radians(degrees)
    c, s, one, zero = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    rows = {"X": (one, zero, zero, zero, c, -s, zero, s, c),
            "Y": (c, zero, s, zero, one, zero, -s, zero, c),
            "Z": (c, -s, zero, s, c, zero, zero, zero, one)}[axis]
    return np.stack(rows, -1).reshape(a.shape + (3, 3))


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _parse(path: Path) -> tuple[list[_Joint], np.ndarray, float]:
    """The joints, the motion [T,channels] and the frame time of a BVH file."""
    lines = path.read_text(errors="replace").splitlines()
    joints, n_channels, k = _hierarchy(path, lines)
    motion, dt = _motion(path, lines, k, joints, n_channels)
    return joints, motion, dt


def _hierarchy(path: Path, lines: list[str]) -> tuple[list[_Joint], int, int]:
    """The HIERARCHY section: the joints, their channel count, and the index of the line after MOTION."""
    joints: list[_Joint] = []
    stack: list[int] = []
    n_channels = 0
    k = 0
    pending: _Joint | None = None
    in_end_site = 0

    def fail(message: str):  # k has already moved past the line at fault
        raise RecordingError(f"{path}: line {k}: {message}")

    while k < len(lines):
        tokens = lines[k].split()
        k += 1
        if not tokens:
            continue
        word = tokens[0].upper()
        if word == "HIERARCHY":
            continue
        if word in ("ROOT", "JOINT"):
            if len(tokens) < 2:
                fail(f"{word} without a name")
            pending = _Joint(" ".join(tokens[1:]), stack[-1] if stack else -1, np.zeros(3), [], 0)
        elif word == "END":
            in_end_site = 1
        elif word == "{":
            if in_end_site:
                in_end_site = 2
            elif pending is not None:
                joints.append(pending)
                stack.append(len(joints) - 1)
                pending = None
            else:
                fail("'{' without a joint")
        elif word == "}":
            if in_end_site == 2:
                in_end_site = 0
            elif stack:
                stack.pop()
            else:
                fail("unbalanced '}'")
        elif word == "OFFSET":
            if in_end_site:
                continue
            if not stack or len(tokens) != 4:
                fail("OFFSET needs three numbers inside a joint")
            try:
                joints[stack[-1]].offset = np.array(tokens[1:], dtype=np.float64)
            except ValueError:
                fail(f"OFFSET values must be numbers, got {tokens[1:]}")
        elif word == "CHANNELS":
            if not stack:
                fail("CHANNELS outside a joint")
            if len(tokens) < 2 or not tokens[1].isdigit():
                fail("CHANNELS needs a count, then the channel names")
            count = int(tokens[1])
            names = tokens[2:]
            if len(names) != count:
                fail(f"CHANNELS {count} lists {len(names)} channels")
            bad = [c for c in names if c[1:].lower() not in ("position", "rotation") or c[0].upper() not in "XYZ"]
            if bad:
                fail(f"unknown channels {bad}")
            joints[stack[-1]].channels = names
            joints[stack[-1]].first_channel = n_channels
            n_channels += count
        elif word == "MOTION":
            break
        else:
            fail(f"unexpected {tokens[0]!r}")
    if not joints:
        raise RecordingError(f"{path}: no ROOT joint; is this a BVH file?")
    if stack:
        raise RecordingError(f"{path}: the hierarchy ends with {len(stack)} unclosed joint(s)")
    return joints, n_channels, k


def _motion(path: Path, lines: list[str], k: int, joints: list[_Joint], n_channels: int) -> tuple[np.ndarray, float]:
    """The MOTION section from line k: the values [T,channels] and the frame time."""
    header: dict[str, Any] = {}  # frames (int), dt (float)
    while k < len(lines) and len(header) < 2:
        text = lines[k].strip()
        k += 1
        try:
            if text.lower().startswith("frames:"):
                header["frames"] = int(text.split(":")[1])
            elif text.lower().startswith("frame time:"):
                header["dt"] = float(text.split(":")[1])
        except ValueError:
            raise RecordingError(f"{path}: line {k}: expected a number in {text!r}") from None
    if len(header) < 2:
        raise RecordingError(f"{path}: MOTION needs 'Frames:' and 'Frame Time:'")
    if header["frames"] < 1:
        raise RecordingError(f"{path}: the file announces {header['frames']} frames")
    rows = [line.split() for line in lines[k:] if line.strip()]
    if len(rows) < header["frames"]:
        raise RecordingError(f"{path}: {header['frames']} frames announced, {len(rows)} found (truncated?)")
    for i, row in enumerate(rows[: header["frames"]]):
        if len(row) != n_channels:
            raise RecordingError(f"{path}: line {k + i + 1} (frame {i}): {len(row)} values, expected {n_channels}")
    try:
        motion = np.array(rows[: header["frames"]], dtype=np.float64)
    except ValueError:
        frame: int = next(f for f, values in enumerate(rows) if not all(_is_number(v) for v in values))
        column: int = next(c for c, v in enumerate(rows[frame]) if not _is_number(v))
        joint = next(j for j in reversed(joints) if j.first_channel <= column)
        raise RecordingError(f"{path}: line {k + frame + 1} (frame {frame}): {rows[frame][column]!r} is not a number "
                             f"({joint.name} {joint.channels[column - joint.first_channel]})") from None
    if header["dt"] <= 0:
        raise RecordingError(f"{path}: Frame Time must be positive, got {header['dt']}")
    return motion, header["dt"]


def _forward_kinematics(joints: list[_Joint], motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations [T,J,3,3] and positions [T,J,3] in the file's units and axes."""
    T, J = motion.shape[0], len(joints)
    R = np.empty((T, J, 3, 3))
    p = np.empty((T, J, 3))
    for j, joint in enumerate(joints):  # a reader, not the tracking step: a loop over joints is fine
        local_R = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
        translation = np.broadcast_to(joint.offset, (T, 3)).copy()
        positions = {}
        for c, name in enumerate(joint.channels):
            values = motion[:, joint.first_channel + c]
            if name[1:].lower() == "rotation":
                local_R = local_R @ _axis_rotation(name[0].upper(), values)
            else:
                positions["XYZ".index(name[0].upper())] = values
        if positions:
            for axis, values in positions.items():
                translation[:, axis] = values
        if joint.parent < 0:
            R[:, j], p[:, j] = local_R, translation
        else:
            Rp = R[:, joint.parent]
            R[:, j] = Rp @ local_R
            p[:, j] = p[:, joint.parent] + (Rp @ translation[..., None])[..., 0]
    return R, p


def _plain(name: str) -> str:
    """A joint's name without its namespace (Mixamo's `mixamorig:Head` is `Head`)."""
    return name.rsplit(":", 1)[-1]


def _rest_pose(joints: list[_Joint], n_channels: int, to_world: np.ndarray, names) -> dict | None:
    """The skeleton with every rotation channel at zero, as a calibration reference: the joints'
    world rotations and the subject's up and left directions (hips to head; right-side joints to
    left-side ones). None when the rest pose is not a standing posture (bones all along one line)."""
    zero = np.zeros((1, n_channels))
    for j in joints:  # translations at their offsets
        for c, name in enumerate(j.channels):
            if name[1:].lower() == "position":
                zero[0, j.first_channel + c] = j.offset["XYZ".index(name[0].upper())]
    R, p = _forward_kinematics(joints, zero)
    R, p = to_world @ R[0], p[0] @ to_world.T
    left_side = [i for i, n in enumerate(names) if re.search(r"(^L|Left|_L$|^l_)", n)]
    right_side = [i for i, n in enumerate(names) if re.search(r"(^R|Right|_R$|^r_)", n)]
    head = [i for i, n in enumerate(names) if _plain(n).lower() in ("head", "neck")]
    if not (left_side and right_side and head):
        return None
    hips = p[0]
    up = p[head[0]] - hips
    left = p[left_side].mean(0) - p[right_side].mean(0)
    left = left - up * (left @ up) / (up @ up)
    if np.linalg.norm(up) < 1e-9 or np.linalg.norm(left) < 1e-3 * np.linalg.norm(up):
        return None
    feet = [i for i, n in enumerate(names) if re.search(r"foot|ankle|toe", n, re.IGNORECASE)]
    down = p[feet].mean(0) - hips if feet else -up
    if down @ up > -0.7 * np.linalg.norm(down) * np.linalg.norm(up):
        return None  # the legs do not hang below the hips: not a standing posture (e.g. bones all along x)
    return dict(orientation=R.tolist(), up=(up / np.linalg.norm(up)).tolist(), left=(left / np.linalg.norm(left)).tolist())


def read_bvh(path: str | Path, units: str = "auto", scale: float | None = None, up: str = "y",
             base_link: str | None = None) -> Recording:
    """Read a BVH file. units: 'auto', 'cm', 'm', 'inch' or 'cmu' (or give `scale`, metres per unit);
    up: the file's vertical axis ('y' or 'z'); base_link: default the hips/pelvis joint, else the root."""
    path = readable_file(path)
    joints, motion, dt = _parse(path)
    # a NaN (or Inf) value is a sample the exporter did not have: the joints it moves are missing in
    # that frame (NaN rotations, as MVNX marks them), never a value for the tracker
    motion = np.where(np.isfinite(motion), motion, np.nan)
    R, p = _forward_kinematics(joints, motion)
    if up == "y":
        to_world = Y_UP_TO_Z_UP
    elif up == "z":
        to_world = np.eye(3)
    else:
        raise RecordingError(f"{path}: up must be 'y' or 'z', got {up!r}")
    p = p @ to_world.T
    R = to_world @ R
    if scale is None:
        complete = np.isfinite(p).all(axis=(1, 2))
        if not complete.any():
            raise RecordingError(f"{path}: no frame has every joint's position: cannot tell the units; give scale=")
        extent = float(np.ptp(p[int(np.argmax(complete)), :, 2]))  # the first frame with every joint
        if units == "auto":
            fits = [u for u, s in UNITS.items() if HEIGHT_RANGE_M[0] <= extent * s <= HEIGHT_RANGE_M[1]]
            if len(fits) != 1:
                raise RecordingError(
                    f"{path}: cannot tell the units: the skeleton is {extent:.3g} units tall in the first frame; "
                    f"give units= one of {list(UNITS)} or scale= metres per unit")
            units = fits[0]
        if units not in UNITS:
            raise RecordingError(f"{path}: unknown units {units!r}; valid: {list(UNITS)}")
        scale = UNITS[units]
    p = p * scale
    names = tuple(j.name for j in joints)
    if base_link is None:
        named = [n for n in names if _plain(n).lower() in ("hips", "pelvis", "hip")]
        base_link = named[0] if named else names[0]
    elif base_link not in names:
        raise RecordingError(f"{path}: base link {base_link!r} is not a joint; joints: {list(names)}")
    # round-off in long products of Euler rotations: back onto SO(3)
    known = np.isfinite(R).all(axis=(-1, -2))  # [T,J]
    R = np.where(known[..., None, None], R, np.nan)
    R[known] = so3.project(torch.from_numpy(R[known])).numpy()
    missing = {name: int(m) for name, m in zip(names, (~known).sum(0)) if m}
    rest = _rest_pose(joints, motion.shape[1], to_world, tuple(j.name for j in joints))
    time = np.arange(motion.shape[0]) * dt
    base = names.index(base_link)
    velocity = np.gradient(p[:, base], time, axis=0) if len(time) > 1 else np.zeros((len(time), 3))
    meta = dict(source=str(path), format="bvh", units=units if units != "auto" else None, metres_per_unit=scale,
                clock="shared",  # one frame of every joint: motion capture, sampled together
                angular_velocity="derived",  # the orientations' central difference: no gyro
                up=up, frame_rate=1.0 / dt,
                channels={j.name: j.channels for j in joints}, rest_pose=rest, missing_frames=missing,
                # the bones: each joint's parent and OFFSET (m, torchik's axes), what builds a subject's model
                skeleton=dict(format="bvh", parents={j.name: names[j.parent] if j.parent >= 0 else None for j in joints},
                              offsets={j.name: (to_world @ j.offset * scale).tolist() for j in joints}),
                note="segment frames are the BVH bones' own: calibrate them to a model with a link map")
    return Recording(time=time, links=names, orientation=R,
                     angular_velocity=angular_velocity_from_orientations(R, time),
                     base_link=base_link, base_position=p[:, base].copy(), base_linear_velocity=velocity, meta=meta,
                     position=p)

"""A recording written as an Xsens MVNX file (version 4), laid out as MVN Analyze exports it: what
makes an MVN export from a built-in scenario (the human models use Xsens' segment names and
frames), for tests and for tools that only read MVNX.

The file holds, as a real export does:

- the segments, each with its points (`<pos_b>`: joints and landmarks in the segment's frame, m);
- the sensors (labelled by the segment each is strapped to) and the joints (`connector1`, the
  parent's segment/point, `connector2` the child's);
- the calibration frames (`identity`, `tpose`, `tpose-isb`, ...: each segment's orientation and
  position in that pose);
- one normal frame per sample (`index`, `time` in whole ms, a time code) with every segment's
  `orientation` (quaternion w, x, y, z, segment to global), `position`, `velocity`,
  `acceleration` (global, m, m/s, m/s^2), `angularVelocity`, `angularAcceleration` (global, rad/s,
  rad/s^2) and every sensor's `sensorOrientation` (the segment's orientation times the sensor's
  placement on it).

Numbers are written with 6 decimals, as MVN writes them: 5e-7 in a quaternion component, a few
1e-6 rad in a rotation. Velocities of the segments other than the base, and the accelerations,
are central differences of what is written (MVN's own come from its filter).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .files import replacing
from .recording import Recording, RecordingError
from .targets import central_differences


@dataclass(frozen=True)
class MvnxSensor:
    """An IMU strapped to a segment: `placement` [3,3] is the sensor's frame in the segment's frame."""

    segment: str
    placement: np.ndarray


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Rotation matrices [...,3,3] to unit quaternions [...,4] (w, x, y, z) with w >= 0 (Shepperd's
    method: of the four ways to solve for q, the one whose pivot 4 q_k^2 is largest)."""
    m = np.asarray(R, dtype=np.float64)
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = (np.moveaxis(m[..., i, :], -1, 0) for i in range(3))
    candidates = np.stack((
        np.stack((1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01), -1),  # 4w q
        np.stack((m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20), -1),  # 4x q
        np.stack((m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21), -1),  # 4y q
        np.stack((m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22), -1),  # 4z q
    ), -2)  # [...,4,4]
    best = np.argmax(np.diagonal(candidates, axis1=-2, axis2=-1), axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _row(values: np.ndarray | tuple[float, ...]) -> str:
    text = " ".join(f"{v:.6f}" for v in np.asarray(values, dtype=np.float64).ravel())
    return text.replace("-0.000000", "0.000000")


def write_mvnx(path: str | Path, recording: Recording, points: dict[str, dict[str, tuple[float, ...]]],
               sensors: list[MvnxSensor] | tuple[MvnxSensor, ...] = (),
               joints: list[tuple[str, str, str]] | tuple[tuple[str, str, str], ...] = (),
               calibration: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
               label: str = "torchik", configuration: str = "FullBody") -> Path:
    """Write `recording` (every segment's orientation, angular velocity and `position`, sampled on
    one clock) as an MVNX file at `path`; returns the path.

    points: segment -> point label -> (x, y, z) in the segment's frame (m). sensors: the IMUs, in
    the file's order. joints: (label, parent segment, child segment), each point `label` of both
    segments. calibration: pose name ("identity", "tpose", "tpose-isb") -> (orientation [n,3,3],
    position [n,3]) of the segments in that pose. RecordingError for what an MVNX file cannot hold:
    no segment positions, gaps, times off one frame clock, a sensor or joint on no segment."""
    links = list(recording.links)
    index = {name: i for i, name in enumerate(links)}
    if recording.position is None:
        raise RecordingError("an MVNX file gives every segment's position; the recording has none")
    T, n = len(recording.time), len(links)
    R, w, p = recording.orientation, recording.angular_velocity, recording.position
    if not (np.isfinite(R).all() and np.isfinite(w).all() and np.isfinite(p).all()):
        raise RecordingError("an MVNX export has no gaps; the recording has missing (NaN) samples")
    rate = recording.frame_rate if T > 1 else float(recording.meta.get("frame_rate", 60.0))
    frame_index = np.rint((recording.time - recording.time[0]) * rate).astype(np.int64)
    if T > 1 and np.abs(frame_index / rate - (recording.time - recording.time[0])).max() > 1e-6 / rate:
        raise RecordingError(f"MVNX frames are on one clock of {rate:g} Hz; the recording's times are not")
    strays = [s.segment for s in sensors if s.segment not in index] + \
        [f"{lbl} ({a}, {b})" for lbl, a, b in joints if a not in index or b not in index]
    strays += [s for s in points if s not in index]
    if strays:
        raise RecordingError(f"sensors, joints or points on segments the recording lacks: {strays}; it has {links}")

    base = index[recording.base_link]
    time = recording.time
    velocity = central_differences(p, time) if T > 1 else np.zeros_like(p)
    velocity[:, base] = recording.base_linear_velocity
    acceleration = central_differences(velocity, time) if T > 1 else np.zeros_like(p)
    angular_acceleration = central_differences(w, time) if T > 1 else np.zeros_like(w)
    quaternion = matrix_to_quaternion(R)  # [T,n,4]
    placement = np.stack([np.asarray(s.placement, dtype=np.float64) for s in sensors]) if sensors else np.zeros((0, 3, 3))
    sensor_quaternion = matrix_to_quaternion(R[:, [index[s.segment] for s in sensors]] @ placement) if sensors else None

    start = datetime(2024, 1, 1, tzinfo=timezone.utc)
    epoch_ms = int(start.timestamp() * 1000)
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             '<mvnx xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xmlns="http://www.xsens.com/mvn/mvnx" '
             'xsi:schemaLocation="http://www.xsens.com/mvn/mvnx http://www.xsens.com/mvn/mvnx/schema.xsd" version="4">',
             '\t<mvn version="2019.0.0" build="torchik.io.mvnx_writer"/>',
             "\t<comment></comment>",
             f'\t<subject label="{label}" frameRate="{rate:g}" segmentCount="{n}" '
             f'recDate="{start.strftime("%a %b %d %H:%M:%S.000 %Y")}" originalFilename="{Path(path).name}" '
             f'configuration="{configuration}" userScenario="singleLevel">',
             "\t\t<comment></comment>",
             "\t\t<segments>"]
    for i, name in enumerate(links):
        lines.append(f'\t\t\t<segment label="{name}" id="{i + 1}">')
        lines.append("\t\t\t\t<points>")
        for point, xyz in points.get(name, {}).items():
            lines += [f'\t\t\t\t\t<point label="{point}">', f"\t\t\t\t\t\t<pos_b>{_row(xyz)}</pos_b>",
                      "\t\t\t\t\t</point>"]
        lines += ["\t\t\t\t</points>", "\t\t\t</segment>"]
    lines.append("\t\t</segments>")
    lines += ["\t\t<sensors>", *(f'\t\t\t<sensor label="{s.segment}"/>' for s in sensors), "\t\t</sensors>"]
    lines.append("\t\t<joints>")
    for lbl, parent, child in joints:
        lines += [f'\t\t\t<joint label="{lbl}">', f"\t\t\t\t<connector1>{parent}/{lbl}</connector1>",
                  f"\t\t\t\t<connector2>{child}/{lbl}</connector2>", "\t\t\t</joint>"]
    lines.append("\t\t</joints>")
    lines.append(f'\t\t<frames segmentCount="{n}" sensorCount="{len(sensors)}" jointCount="{len(joints)}">')
    for pose, (orientation, position) in (calibration or {}).items():
        lines += [f'\t\t\t<frame time="0" tc="00:00:00:00" ms="0" type="{pose}">',
                  f"\t\t\t\t<orientation>{_row(matrix_to_quaternion(orientation))}</orientation>",
                  f"\t\t\t\t<position>{_row(position)}</position>", "\t\t\t</frame>"]
    for k in range(T):
        ms = int(round(1000 * (time[k] - time[0])))
        seconds, frame = divmod(int(frame_index[k]), max(int(round(rate)), 1))
        tc = f"{seconds // 3600:02d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}:{frame:02d}"
        lines.append(f'\t\t\t<frame time="{ms}" index="{frame_index[k]}" tc="{tc}" ms="{epoch_ms + ms}" type="normal">')
        lines += [f"\t\t\t\t<orientation>{_row(quaternion[k])}</orientation>",
                  f"\t\t\t\t<position>{_row(p[k])}</position>",
                  f"\t\t\t\t<velocity>{_row(velocity[k])}</velocity>",
                  f"\t\t\t\t<acceleration>{_row(acceleration[k])}</acceleration>",
                  f"\t\t\t\t<angularVelocity>{_row(w[k])}</angularVelocity>",
                  f"\t\t\t\t<angularAcceleration>{_row(angular_acceleration[k])}</angularAcceleration>"]
        if sensor_quaternion is not None:
            lines.append(f"\t\t\t\t<sensorOrientation>{_row(sensor_quaternion[k])}</sensorOrientation>")
        lines.append("\t\t\t</frame>")
    lines += ["\t\t</frames>", "\t</subject>", "</mvnx>"]
    path = Path(path)
    with replacing(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    return path

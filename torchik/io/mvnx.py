"""Xsens MVNX (versions 3 and 4) to a Recording.

Conventions (checked on a real MVN 2019 export, see ../shared/data/README.md): `orientation` is a
quaternion w, x, y, z, segment to global; `angularVelocity` is in the global frame, rad/s;
`position` and `velocity` are global, m and m/s. Normal frames carry `index` (frames since the
start; time = index / frameRate, exact) and `time` (ms, rounded, used when there is no index).
The calibration frames (`identity`, `tpose`, `tpose-isb`) go into meta["calibration"].

The file is parsed as a stream (ElementTree.iterparse, elements cleared once read), so memory holds
the numbers, never the XML tree of a large file.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import torch

from ..method import so3
from .recording import Recording, RecordingError, readable_file

FIELDS = ("orientation", "angularVelocity", "position", "velocity")
WIDTH = {"orientation": 4, "angularVelocity": 3, "position": 3, "velocity": 3}


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _numbers(text: str | None, count: int, what: str, where: str) -> np.ndarray:
    try:
        values = np.array((text or "").split(), dtype=np.float64)
    except ValueError:
        raise RecordingError(f"{where}: {what} holds values that are not numbers") from None
    if values.size != count:
        raise RecordingError(f"{where}: {what} holds {values.size} numbers, expected {count}")
    return values


def _points(segment: ET.Element, where: str) -> dict[str, list[float]]:
    """A <segment>'s <points>: label -> pos_b, the point in the segment frame (m)."""
    found: dict[str, list[float]] = {}
    for point in segment.iter():
        label = point.get("label")
        if _local(point.tag) == "point" and label:
            pos = next((c for c in point if _local(c.tag) == "pos_b"), None)
            if pos is not None:
                found[label] = _numbers(pos.text, 3, f"point {label}", where).tolist()
    return found


def read_mvnx(path: str | Path, base_link: str = "Pelvis") -> Recording:
    """Read an MVNX file. Raises RecordingError naming the file and the frame or line at fault."""
    path = readable_file(path)
    segments: list[str] = []
    frame_rate, version, subject = None, None, {}
    times: list[float] = []
    data: dict[str, list] = {name: [] for name in FIELDS}
    calibration = {}
    points: dict[str, dict[str, list[float]]] = {}
    try:
        for event, elem in ET.iterparse(path, events=("start", "end")):
            tag = _local(elem.tag)
            if event == "start":
                if tag == "mvnx":
                    version = elem.get("version")
                elif tag == "subject":
                    subject = dict(elem.attrib)
                    frame_rate = float(elem.get("frameRate")) if elem.get("frameRate") else None
                continue
            if tag == "segment" and elem.get("label"):
                segments.append(elem.get("label"))
                points[elem.get("label")] = _points(elem, f"{path}: segment {elem.get('label')}")
                elem.clear()
            elif tag == "frame":
                n = len(segments)
                kind = elem.get("type", "normal")
                where = f"{path}: frame {elem.get('index', kind)}"
                values = {_local(child.tag): child.text for child in elem}
                if kind == "normal":
                    missing = [f for f in FIELDS if f not in values]
                    if missing:
                        raise RecordingError(f"{where}: missing {missing}")
                    # index / frame rate is exact; `time` is rounded to whole milliseconds
                    if elem.get("index") is not None and frame_rate:
                        times.append(int(elem.get("index")) / frame_rate)
                    else:
                        times.append(float(elem.get("time")) / 1000.0)
                    for f in FIELDS:
                        data[f].append(_numbers(values[f], WIDTH[f] * n, f, where))
                else:  # calibration poses: orientation and position only
                    calibration[kind] = {
                        f: _numbers(values[f], WIDTH[f] * n, f, where).tolist()
                        for f in ("orientation", "position") if f in values}
                elem.clear()
    except ET.ParseError as exc:
        line, column = exc.position
        raise RecordingError(f"{path}: malformed XML at line {line}, column {column}: {exc}") from None
    except (ValueError, TypeError) as exc:  # a frame's index, time or the frame rate that is not a number
        raise RecordingError(f"{path}: after {len(times)} frames: {exc}") from None
    if not segments:
        raise RecordingError(f"{path}: no <segment> definitions; is this an MVNX file?")
    if not times:
        raise RecordingError(f"{path}: no normal frames")
    if base_link not in segments:
        raise RecordingError(f"{path}: base link {base_link!r} is not a segment; segments: {segments}")
    T, n = len(times), len(segments)
    quaternion = np.stack(data["orientation"]).reshape(T, n, 4)
    norm = np.linalg.norm(quaternion, axis=-1, keepdims=True)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        t, i = np.argwhere(np.abs(norm[..., 0] - 1.0) > 1e-3)[0]
        raise RecordingError(f"{path}: frame {t}: quaternion of {segments[i]} has norm {norm[t, i, 0]:.4f}, not 1")
    rotation = so3.quaternion_to_matrix(torch.from_numpy(quaternion / norm)).numpy()
    position = np.stack(data["position"]).reshape(T, n, 3)
    velocity = np.stack(data["velocity"]).reshape(T, n, 3)
    base = segments.index(base_link)
    time = np.asarray(times)
    if np.any(np.diff(time) <= 0):
        k = int(np.argmax(np.diff(time) <= 0)) + 1
        raise RecordingError(f"{path}: frame {k}: time {time[k]} s does not follow {time[k - 1]} s")
    meta = dict(source=str(path), format="mvnx", mvnx_version=version, frame_rate=frame_rate,
                subject={k: v for k, v in subject.items() if k in ("label", "frameRate", "segmentCount", "configuration",
                                                                     "recDate", "userScenario")},
                units=dict(time="s", position="m", angular_velocity="rad/s"),
                calibration=calibration,
                # each segment's joints and landmarks in its own frame (m): what builds the subject's model
                skeleton=dict(format="mvnx", points=points))
    return Recording(time=time, links=tuple(segments), orientation=rotation,
                     angular_velocity=np.stack(data["angularVelocity"]).reshape(T, n, 3),
                     base_link=base_link, base_position=position[:, base].copy(),
                     base_linear_velocity=velocity[:, base].copy(), meta=meta, position=position)

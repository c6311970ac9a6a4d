"""OpenSense (OpenSim's IMU pipeline) quaternion tables to a Recording, and back.

An OpenSense orientation table is an OpenSim `.sto` file (opensim_table.py) with `DataType=Quaternion`
and `DataRate` in its header, a `time` column and one column per IMU, named for the body it is
strapped to (`pelvis_imu`, `torso_imu`, `femur_r_imu`, `tibia_r_imu`, `calcn_r_imu`, `humerus_r_imu`,
`radius_r_imu`, `hand_r_imu`, ... and `_l_`), each cell a unit quaternion `w,x,y,z` (scalar first):
the rotation from the IMU's frame to the world of its orientation filter. Any subset of IMUs may be
there; an empty cell, `nan`, or an all-zero quaternion is a sample not measured (NaN in the
recording, never filled in).

World: torchik's is z up. An Xsens filter's world is z up too, and OpenSense rotates it into
OpenSim's y-up ground by `sensor_to_opensim_rotations` (space-fixed x, y, z angles, default
(-pi/2, 0, 0)); a table whose data were put in another world says which rotation takes them to
OpenSim's ground by a header line `sensor_to_opensim_rotations=rx ry rz` (or the reader's
argument), and the reader undoes it: R_torchik = Rx(pi/2) R_s2o R_table.

Angular velocity: a gyroscope table beside the orientations, as OpenSense's IMUDataReader writes
it (`<trial>_angular_velocity.sto` next to `<trial>_orientations.sto`: `DataType=Vec3`, the same
IMU columns, rad/s in each IMU's frame), rotated into the world; without one, the orientations'
central difference, and `meta["angular_velocity"] = "derived"` says so (what the diagnosis reads).

Positions: an IMU set measures none. `base_position` and `base_linear_velocity` are NaN, and
`meta["base_position"] = "not measured"`: the tracker holds the base still or leaves it free
(base_position.py), it never takes zeros as data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..method import so3
from .base_position import NOT_MEASURED
from .mvnx_writer import matrix_to_quaternion
from .opensim_table import OpenSimTable, read_table, write_table
from .recording import Recording, RecordingError, angular_velocity_from_orientations

XSENS_TO_OPENSIM = (-math.pi / 2, 0.0, 0.0)  # OpenSense's default sensor_to_opensim_rotations (z up -> y up)
OPENSIM_TO_TORCHIK = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # Rx(pi/2): y up -> z up
BASE_IMU = "pelvis_imu"
NORM_TOLERANCE = 1e-2  # a quaternion further from unit norm is not an orientation (written to 4 decimals: 1e-4)
GYRO_SUFFIX = "_angular_velocity"


def read_opensense(path: str | Path, base_imu: str = BASE_IMU, sensor_to_opensim: tuple[float, float, float] | None = None,
                   gyro: str | Path | None = None) -> Recording:
    """An OpenSense quaternion table (.sto) as a Recording of its IMUs (links: the column names).

    base_imu: the IMU that is the recording's base (default pelvis_imu; the first column when the
    table has no pelvis_imu). sensor_to_opensim: (rx, ry, rz) rad, space-fixed, the rotation from
    the table's world to OpenSim's ground (default: the header's `sensor_to_opensim_rotations`,
    else OpenSense's default for z-up filters, which leaves the data as they are). gyro: a
    gyroscope table (default: `<trial>_angular_velocity.sto` beside a `<trial>_orientations.sto`,
    when it exists). RecordingError naming the file, line and column at fault."""
    table = read_table(path)
    kind = table.header_value("DataType")
    if kind is not None and kind.lower() != "quaternion":
        raise RecordingError(f"{table.path}: DataType={kind}; an OpenSense orientation table has DataType=Quaternion")
    if not table.labels:
        raise RecordingError(f"{table.path}: no IMU columns after 'time'")
    declared = table.header_value("sensor_to_opensim_rotations")
    if sensor_to_opensim is None and declared is not None:
        sensor_to_opensim = _angles(declared, f"{table.path}: sensor_to_opensim_rotations")
    to_world = _to_torchik(sensor_to_opensim or XSENS_TO_OPENSIM)
    quaternion = np.stack([table.column(label, 4) for label in table.labels], axis=1)  # [T,n,4]
    R = to_world @ _rotations(quaternion, table)
    gyro_path = Path(gyro) if gyro is not None else _gyro_beside(table.path)
    if gyro_path is not None:
        angular_velocity = _world_rates(read_table(gyro_path), table, R)
        rates = dict(angular_velocity="gyroscope", gyroscope_file=str(gyro_path))
    else:
        angular_velocity = angular_velocity_from_orientations(R, table.time)
        rates = dict(angular_velocity="derived")  # the orientations' central difference: no gyro
    base = base_imu if base_imu in table.labels else table.labels[0]
    T = len(table.time)
    rate = table.header_value("DataRate")
    missing = {name: int(m) for name, m in zip(table.labels, np.isnan(R).any(axis=(-1, -2)).sum(0)) if m}
    meta = dict(source=str(table.path), format="opensense", frame_rate=_rate(rate, table),
                units=dict(time="s", angular_velocity="rad/s"), header=table.header,
                sensor_to_opensim_rotations=list(sensor_to_opensim or XSENS_TO_OPENSIM),
                clock="per_sensor",  # each IMU's filter streams on its own
                base_position=NOT_MEASURED, missing_frames=missing, **rates,
                note="IMU frames: calibrate them to the model's links with a link map (opensense_to_human)")
    return Recording(time=table.time, links=table.labels, orientation=R, angular_velocity=angular_velocity,
                     base_link=base, base_position=np.full((T, 3), np.nan), base_linear_velocity=np.full((T, 3), np.nan),
                     meta=meta)


def write_opensense(path: str | Path, time: np.ndarray, names, orientation: np.ndarray, rate: float | None = None,
                    header: dict[str, str] | None = None) -> Path:
    """An OpenSense quaternion table: time [T] s, names [n] (IMU column labels), orientation [T,n,3,3]
    (IMU to a z-up world; NaN: an empty sample, written nan). rate: the header's DataRate (default
    the median frame rate). header: more `key=value` lines."""
    q = matrix_to_quaternion(orientation)
    rate = rate if rate is not None else float(1.0 / np.median(np.diff(time))) if len(time) > 1 else 0.0
    lines = dict(DataRate=f"{rate:.6f}", DataType="Quaternion", version="3", OpenSimVersion="4.6", **(header or {}))
    return write_table(path, time, names, q, lines)


def _angles(text: str, where: str) -> tuple[float, float, float]:
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        values = []
    if len(values) != 3:
        raise RecordingError(f"{where}: expected three angles in radians, got {text!r}")
    return values[0], values[1], values[2]


def _to_torchik(sensor_to_opensim) -> np.ndarray:
    """The rotation [3,3] from the table's world to torchik's (z up): Rx(pi/2) R_s2o, R_s2o =
    Rz(rz) Ry(ry) Rx(rx) (OpenSim's space-fixed x, y, z sequence)."""
    R_s2o = so3.rpy_to_matrix(torch.tensor(sensor_to_opensim, dtype=torch.float64)).numpy()
    return OPENSIM_TO_TORCHIK @ R_s2o


def _rotations(quaternion: np.ndarray, table: OpenSimTable) -> np.ndarray:
    """[T,n,4] quaternions (w, x, y, z) to rotations [T,n,3,3]; NaN where a sample is missing (NaN or all
    zero). RecordingError naming the line and column of one too far from unit norm."""
    norm = np.linalg.norm(quaternion, axis=-1)
    missing = np.isnan(norm) | (norm == 0)
    bad = ~missing & (np.abs(norm - 1.0) > NORM_TOLERANCE)
    if bad.any():
        t, i = np.argwhere(bad)[0]
        raise RecordingError(f"{table.path}: line {table.lines[t]}, column {table.labels[i]!r}: quaternion of norm "
                             f"{norm[t, i]:.4f}, not 1")
    unit = np.where(missing[..., None], 0.0, quaternion / np.where(missing, 1.0, norm)[..., None])
    R = so3.quaternion_to_matrix(torch.from_numpy(unit)).numpy()
    R[missing] = np.nan
    return R


def _gyro_beside(path: Path) -> Path | None:
    """OpenSense's gyroscope table for an orientation table `<trial>_orientations.sto`, when it is there."""
    stem = path.stem
    if not stem.endswith("_orientations"):
        return None
    candidate = path.with_name(stem.removesuffix("_orientations") + GYRO_SUFFIX + path.suffix)
    return candidate if candidate.is_file() else None


def _world_rates(gyro: OpenSimTable, orientations: OpenSimTable, R: np.ndarray) -> np.ndarray:
    """The gyroscope table's rates (IMU frames) in the world [T,n,3]: R w. Its frames must be the
    orientations' (the same times); an IMU it lacks has NaN rates."""
    if len(gyro.time) != len(orientations.time) or not np.allclose(gyro.time, orientations.time, atol=1e-9):
        raise RecordingError(f"{gyro.path}: its {len(gyro.time)} times are not those of {orientations.path} "
                             f"({len(orientations.time)})")
    w = np.full(R.shape[:-1], np.nan)
    for i, label in enumerate(orientations.labels):
        if label in gyro.labels:
            w[:, i] = gyro.column(label, 3)
    return (R @ w[..., None])[..., 0]  # NaN where the rate or the orientation is missing


def _rate(declared: str | None, table: OpenSimTable) -> float:
    """The header's DataRate (Hz), else the median rate of the time stamps."""
    if declared is not None:
        try:
            return float(declared)
        except ValueError:
            raise RecordingError(f"{table.path}: DataRate={declared!r} is not a number") from None
    return float(1.0 / np.median(np.diff(table.time))) if len(table.time) > 1 else float("nan")

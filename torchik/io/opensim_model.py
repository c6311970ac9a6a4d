"""A torchik model as an OpenSim model, and OpenSim's inverse dynamics of a torchik motion: the same
segments, mass properties and motion given to another implementation (OpenSim 4.6, the optional
extra `torchik[opensim]`; opensim is imported only when a function here is called).

The model (`opensim_model`): a body per skeleton frame of the compiled tree, named after the first
link fixed to it, with that frame's lumped body (`tensors.frame_bodies`: mass, centre of mass,
inertia about the centre in the frame's axes); each joint a PinJoint from its parent frame's body
to its own, its frames turned so that their z axis is the joint's axis: Human66's three axes per
joint are three PinJoints through the two massless bodies between them, as in the URDF (each a
point of `LIGHT` kg at its origin: Simbody refuses a massless body followed by another; the torques
they add are below 1e-10 N m). The base is
free through six single-axis joints from the ground, so that every coordinate's speed is its rate
(OpenSim's InverseDynamicsTool takes each speed for its coordinate's derivative, which a FreeJoint's
rotations are not): sliders along the world's x, y, z (`base_x`, `base_y`, `base_z`, m), then pins
about z, y, x (`base_yaw`, `base_pitch`, `base_roll`), R_B = Rz(yaw) Ry(pitch) Rx(roll) as torchik's
motion files write it (`opensim_out.py`). The ground is torchik's world (z up): gravity is set to
torchik's.

The motion (`opensim_motion`): torchik's (p_B, R_B, s; nu, nu_dot in MIXED) as OpenSim's
coordinates, speeds and their derivatives, in `coordinate_names(model)`' order. The joints' are
torchik's; the base's angles are the Euler angles of R_B (yaw and roll unwrapped over time), their
rates E^-1 omega_B with E = [z, Rz(yaw) y, Rz(yaw) Ry(pitch) x] the axes the three pins turn about,
and their second derivatives E^-1 (omega_dot_B - E_dot rates).

The generalized forces come back in the same order: the joints' torques are torchik's (each the
torque the parent exerts on the child about the joint's axis); the base's are the force on the
whole body (world axes), then the moment about the base's origin projected on the three pins' axes,
E^T n_B (`base_forces` turns torchik's base wrench into them).

Ground reactions (`external_loads`): an ExternalForce per link, force, point and torque all in the
ground (`<link>_force_v*`, `<link>_force_p*`, `<link>_torque_*`), the point the link's origin and the
torque the moment about it, as torchik's `inverse_dynamics` takes them. OpenSim interpolates them in
time with cubic splines through the samples, exact at the samples' times.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
import torch

from ..errors import InputError, MissingDependencyError, optional
from ..method import so3
from ..method.dynamics.inverse import GRAVITY
from ..method.kinematics import KinematicModel
from .opensim_table import read_table, write_table

BASE_COORDINATES = ("base_x", "base_y", "base_z", "base_yaw", "base_pitch", "base_roll")
GROUND_AXES = np.eye(3)
LIGHT = 1e-12  # kg: a massless body's point mass (Simbody refuses two massless bodies in a row)
LOAD_COLUMNS = ("force_vx", "force_vy", "force_vz", "force_px", "force_py", "force_pz", "torque_x", "torque_y", "torque_z")


def require_opensim() -> Any:
    """The opensim module, or MissingDependencyError saying how to install it."""
    try:
        return optional("opensim", "opensim", "OpenSim's inverse dynamics")
    except MissingDependencyError as exc:
        raise MissingDependencyError(f"{exc} (or pip install opensim==4.6)") from None


def coordinate_names(model: KinematicModel) -> tuple[str, ...]:
    """The OpenSim model's coordinates in torchik's order: the base's six, then the joints'."""
    return BASE_COORDINATES + tuple(model.joint_names)


def body_names(model: KinematicModel) -> tuple[str, ...]:
    """[F] each skeleton frame's body: the first link fixed to it (`frame<f>` for a frame without one)."""
    tree = model.tree
    first: dict[int, str] = {}
    for link, frame in zip(tree.link_names, tree.link_anchor):
        first.setdefault(frame, link)
    return tuple(first.get(f, f"frame{f}") for f in range(tree.n_frames))


def opensim_model(model: KinematicModel, subject: int = 0, name: str | None = None,
                  gravity: Sequence[float] = GRAVITY) -> Any:
    """An opensim.Model of `model`'s subject `subject` (the module's docstring), its system not yet
    initialised (add forces, then `initSystem`)."""
    osim = require_opensim()
    tree, t = model.tree, model._tensors
    if not 0 <= subject < model.n_subjects:
        raise InputError(f"subject {subject}: the model holds {model.n_subjects}")
    host = lambda x: x[..., subject].detach().cpu().double().numpy()  # noqa: E731
    mass, moment, inertia = host(t.body_mass), host(t.body_first_moment), host(t.body_inertia)
    offset_R, offset_p = host(t.geometry.offset_rotation), host(t.geometry.offset_position)
    out = osim.Model()
    out.setName(name or model.name or "torchik")
    out.setGravity(osim.Vec3(*gravity))
    names = body_names(model)
    bodies = []
    for f in range(tree.n_frames):
        m = max(float(mass[f]), LIGHT)
        c = moment[f] / m
        I = inertia[f] - m * (c @ c * np.eye(3) - np.outer(c, c))  # about the centre of mass
        body = osim.Body(names[f], m, osim.Vec3(*c), osim.Inertia(I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))
        out.addBody(body)
        bodies.append(body)
    # the base: sliders along x, y, z (a slider moves along its frames' x), pins about z, y, x
    parent = out.getGround()
    for k, coordinate in enumerate(BASE_COORDINATES):
        child = bodies[0] if k == 5 else osim.Body(f"{names[0]}_{coordinate}", LIGHT, osim.Vec3(0), osim.Inertia(0))
        if k < 5:
            out.addBody(child)
        axis = GROUND_AXES[k % 3] if k < 3 else GROUND_AXES[5 - k]
        kind = osim.SliderJoint if k < 3 else osim.PinJoint
        turn = _turn_to(axis, np.array([1.0, 0.0, 0.0]) if k < 3 else np.array([0.0, 0.0, 1.0]))
        joint = kind(f"ground_{coordinate}" if k == 0 else coordinate, parent, osim.Vec3(0), turn, child,
                     osim.Vec3(0), turn)
        _name_coordinate(joint, coordinate)
        out.addJoint(joint)
        parent = child
    z = np.array([0.0, 0.0, 1.0])
    for f in range(1, tree.n_frames):
        joint_name = tree.joint_names[tree.frame_joint[f]]
        turn = _turn_to(tree.axes[f], z)
        above = offset_R[f] @ _matrix(turn)
        pin = osim.PinJoint(joint_name, bodies[tree.frame_parent[f]], osim.Vec3(*offset_p[f]), osim.Vec3(*_xyz(above)),
                            bodies[f], osim.Vec3(0), turn)
        _name_coordinate(pin, joint_name)
        out.addJoint(pin)
    out.finalizeConnections()
    return out


def _name_coordinate(joint: Any, name: str) -> None:
    coordinate = joint.upd_coordinates(0)
    coordinate.setName(name)
    coordinate.setRangeMin(-1e3)
    coordinate.setRangeMax(1e3)
    coordinate.setDefaultClamped(False)


def _turn_to(axis: np.ndarray, along: np.ndarray) -> Any:
    """The body-fixed x-y-z angles (opensim.Vec3) of a rotation Q with Q along = axis (unit vectors)."""
    osim = require_opensim()
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    v, c = np.cross(along, axis), float(along @ axis)
    if c < -1.0 + 1e-12:  # opposite: half a turn about a perpendicular
        perpendicular = np.cross(along, [1.0, 0.0, 0.0] if abs(along[0]) < 0.9 else [0.0, 1.0, 0.0])
        p = perpendicular / np.linalg.norm(perpendicular)
        Q = 2 * np.outer(p, p) - np.eye(3)
    else:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        Q = np.eye(3) + K + K @ K / (1.0 + c)
    return osim.Vec3(*_xyz(Q))


def _xyz(R: np.ndarray) -> np.ndarray:
    """Body-fixed x-y-z angles of R = Rx(a) Ry(b) Rz(c), as OpenSim's frames take them."""
    b = np.arcsin(np.clip(R[0, 2], -1.0, 1.0))
    if abs(R[0, 2]) < 1.0 - 1e-12:
        a, c = np.arctan2(-R[1, 2], R[2, 2]), np.arctan2(-R[0, 1], R[0, 0])
    else:  # gimbal lock: a and c turn about one axis
        a, c = np.arctan2(R[2, 1], R[1, 1]), 0.0
    return np.array([a, b, c])


def _matrix(angles: Any) -> np.ndarray:
    """The rotation of body-fixed x-y-z angles (an opensim.Vec3 or three numbers)."""
    a, b, c = (float(angles[k]) for k in range(3))
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


class OpenSimMotion(NamedTuple):
    """A motion in OpenSim's coordinates (`coordinate_names` order), each [T,6+n]: values q (m, rad),
    speeds u = q_dot and their derivatives u_dot."""

    q: np.ndarray
    u: np.ndarray
    u_dot: np.ndarray


def opensim_motion(base_position: torch.Tensor | np.ndarray, base_rotation: torch.Tensor | np.ndarray,
                   joint_positions: torch.Tensor | np.ndarray, velocity: torch.Tensor | np.ndarray,
                   acceleration: torch.Tensor | np.ndarray) -> OpenSimMotion:
    """torchik's motion, base_position [T,3], base_rotation [T,3,3], joint_positions [T,n], velocity and
    acceleration [T,6+n] (MIXED), as OpenSim's coordinates (the module's docstring)."""
    p, R, s, nu, nu_dot = (np.asarray(torch.as_tensor(x).detach().cpu().double())
                           for x in (base_position, base_rotation, joint_positions, velocity, acceleration))
    rpy = so3.matrix_to_rpy(torch.from_numpy(R)).numpy()
    yaw, pitch, roll = np.unwrap(rpy[:, 2]), rpy[:, 1], np.unwrap(rpy[:, 0])
    E = pin_axes(yaw, pitch)  # [T,3,3] columns: the axes the yaw, pitch and roll pins turn about
    rates = np.linalg.solve(E, nu[:, 3:6, None])[..., 0]
    z = np.array([0.0, 0.0, 1.0])
    e2, e3 = E[..., 1], E[..., 2]
    w1 = rates[:, :1] * z  # the yaw pin's body's angular velocity, then the pitch pin's
    w2 = w1 + rates[:, 1:2] * e2
    E_dot_rates = rates[:, 1:2] * np.cross(w1, e2) + rates[:, 2:3] * np.cross(w2, e3)
    accelerations = np.linalg.solve(E, (nu_dot[:, 3:6] - E_dot_rates)[..., None])[..., 0]
    q = np.concatenate((p, np.stack((yaw, pitch, roll), -1), s), -1)
    u = np.concatenate((nu[:, :3], rates, nu[:, 6:]), -1)
    u_dot = np.concatenate((nu_dot[:, :3], accelerations, nu_dot[:, 6:]), -1)
    return OpenSimMotion(q, u, u_dot)


def pin_axes(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """[T,3,3] the world axes of the base's yaw, pitch and roll pins (columns: z, Rz(yaw) y,
    Rz(yaw) Ry(pitch) x) at angles yaw, pitch [T]."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    columns = (np.stack((zero, zero, one), -1), np.stack((-sy, cy, zero), -1), np.stack((cy * cp, sy * cp, -sp), -1))
    return np.stack(columns, -1)


def base_forces(base_wrench: np.ndarray, q: np.ndarray) -> np.ndarray:
    """[T,6] torchik's base wrench [T,6] (force; moment about the base's origin, world axes) as the
    OpenSim model's base generalized forces at its coordinates q [T,6+n]: the force, then E^T n_B."""
    E = pin_axes(q[:, 3], q[:, 4])
    return np.concatenate((base_wrench[:, :3], np.einsum("tij,ti->tj", E, base_wrench[:, 3:])), -1)


def external_loads(path: str | Path, time: np.ndarray, bodies: Sequence[str], wrenches: np.ndarray,
                   points: np.ndarray) -> Path:
    """OpenSim's ExternalLoads: `path` (.xml) and its data `<path stem>.mot` beside it, an ExternalForce
    on each of `bodies` [L] with force and moment wrenches [T,L,6] (N, N m about points [T,L,3], m,
    all in the ground's axes) at times [T] (s). Unknown samples (NaN) are written as zero."""
    osim = require_opensim()
    path = Path(path)
    T, L = len(time), len(bodies)
    if wrenches.shape != (T, L, 6) or points.shape != (T, L, 3):
        raise InputError(f"wrenches {wrenches.shape}, points {points.shape}: expected ({T}, {L}, 6) and ({T}, {L}, 3)")
    data = path.with_suffix(".mot")
    values = np.concatenate((wrenches[..., :3], points, wrenches[..., 3:]), -1)
    write_table(data, time, [f"{body}_{column}" for body in bodies for column in LOAD_COLUMNS],
                np.nan_to_num(values).reshape(T, -1), dict(version="1", inDegrees="no", DataType="double"),
                name="External Loads")
    loads = osim.ExternalLoads()
    for body in bodies:
        force = osim.ExternalForce()
        force.setName(f"{body}_ground_reaction")
        force.set_applied_to_body(body)
        force.set_force_expressed_in_body("ground")
        force.set_point_expressed_in_body("ground")
        force.set_force_identifier(f"{body}_force_v")
        force.set_point_identifier(f"{body}_force_p")
        force.set_torque_identifier(f"{body}_torque_")
        force.set_data_source_name(data.name)
        loads.cloneAndAppend(force)
    loads.setDataFileName(data.name)
    loads.printToXML(str(path))
    return path


def add_external_loads(model: Any, loads: str | Path) -> None:
    """Add the ExternalLoads of a file (`external_loads`) to `model`, before its `initSystem`."""
    osim = require_opensim()
    model.addModelComponent(osim.ExternalLoads(str(Path(loads).resolve()), True))


def solve(model: Any, names: Sequence[str], motion: OpenSimMotion, time: np.ndarray) -> np.ndarray:
    """[T,6+n] OpenSim's inverse dynamics (InverseDynamicsSolver) of `model` (`opensim_model`, its
    forces added, not yet initialised) at the given coordinates, speeds and their derivatives (T
    samples at `time`, columns `names`: `coordinate_names`): the generalized forces, same columns."""
    osim = require_opensim()
    state = model.initSystem()
    order = _mobility_order(model, state, names)
    solver = osim.InverseDynamicsSolver(model)
    out = np.empty_like(motion.q)
    for k in range(len(time)):
        state.setTime(float(time[k]))
        q, u = state.updQ(), state.updU()
        for i, c in enumerate(order):
            q.set(i, float(motion.q[k, c]))
            u.set(i, float(motion.u[k, c]))
        u_dot = osim.Vector(len(order), 0.0)
        for i, c in enumerate(order):
            u_dot.set(i, float(motion.u_dot[k, c]))
        forces = solver.solve(state, u_dot)
        for i, c in enumerate(order):
            out[k, c] = forces.get(i)
    return out


def _mobility_order(model: Any, state: Any, names: Sequence[str]) -> list[int]:
    """For each of the system's mobilities (q and u alike: every coordinate here is one of each, qdot =
    u), its column among `names`: found by setting each coordinate in turn (the Python bindings do not
    return the coordinates in the tree's order)."""
    coordinates = model.getCoordinateSet()
    if coordinates.getSize() != len(names) or state.getNQ() != len(names):
        raise InputError(f"the OpenSim model has {coordinates.getSize()} coordinates and {state.getNQ()} q, "
                         f"expected {len(names)}")
    order = [-1] * len(names)
    state.updQ().setToZero()
    for k, name in enumerate(names):
        coordinates.get(name).setValue(state, 1.0, False)
        q = state.getQ()
        index = next(i for i in range(q.size()) if q.get(i) != 0.0)
        order[index] = k
        coordinates.get(name).setValue(state, 0.0, False)
    return order


class ToolResult(NamedTuple):
    """OpenSim's InverseDynamicsTool on a motion: the generalized forces [T,6+n] (`coordinate_names`
    order) and the speeds [T,6+n] (m/s, rad/s) of the coordinates as the tool differentiated them."""

    forces: np.ndarray
    speeds: np.ndarray


def inverse_dynamics_tool(model: Any, names: Sequence[str], time: np.ndarray, q: np.ndarray,
                          loads: str | Path | None, folder: str | Path, cutoff: float = 6.0) -> ToolResult:
    """OpenSim's InverseDynamicsTool on the coordinates q [T,6+n] (m, rad; columns `names`) at times
    [T] of `model` (`opensim_model`, without forces), the ground reactions of the ExternalLoads file
    `loads` (`external_loads`; None: none): the tool low-passes the coordinates at `cutoff` Hz (a
    Butterworth IIR run both ways after padding the ends; -1: not at all), fits quintic GCV splines
    and differentiates them. Its files are written in `folder`. The speeds come from the same filter
    and splines (the tool does not write them)."""
    osim = require_opensim()
    folder = Path(folder).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    rotational = np.array([name not in BASE_COORDINATES[:3] for name in names])
    coordinates = folder / "coordinates.mot"
    write_table(coordinates, time, list(names), np.where(rotational, np.rad2deg(q), q),
                dict(version="1", inDegrees="yes", DataType="double"), name="Coordinates")
    tool = osim.InverseDynamicsTool()
    tool.setModel(model)
    tool.setCoordinatesFileName(str(coordinates))
    tool.setLowpassCutoffFrequency(cutoff)
    if loads is not None:
        tool.setExternalLoadsFileName(str(Path(loads).resolve()))
    tool.setStartTime(float(time[0]))
    tool.setEndTime(float(time[-1]))
    tool.setResultsDir(str(folder))
    tool.setOutputGenForceFileName("inverse_dynamics.sto")
    tool.run()
    table = read_table(folder / "inverse_dynamics.sto")
    suffix = lambda name: "_force" if name in BASE_COORDINATES[:3] else "_moment"  # noqa: E731
    forces = np.column_stack([table.column(name + suffix(name), 1)[:, 0] for name in names])
    storage = osim.Storage(str(coordinates))
    if cutoff >= 0:
        storage.pad(storage.getSize() // 2)
        storage.lowpassIIR(cutoff)
    model.getSimbodyEngine().convertDegreesToRadians(storage)
    splines = osim.GCVSplineSet(5, storage)
    speeds = np.array([[splines.evaluate(splines.getIndex(name), 1, float(t)) for name in names] for t in table.time])
    return ToolResult(forces, speeds)

"""Rerun recordings (.rrd) of a tracked sequence: the body moving with the estimate, each target's
measured frame beside the estimated link frame, and the diagnostics as time series, on one time
line "time" (seconds). Logged by columns: one `send_columns` per entity, never a loop over time,
and the link poses of all time steps from batched kinematics.

Entities, for each logged subject i of the batch:

    /subject/<i>/estimate/<link>           Transform3D: the estimated link pose; axes on the tracked links
    /subject/<i>/estimate/<link>/visual    the link's URDF visual shapes (boxes, cylinders, spheres;
                                           meshes at visual/mesh<k>), fixed in the link frame
    /subject/<i>/skeleton                  LineStrips3D: a bone from each tracked link to its nearest
                                           tracked ancestor
    /subject/<i>/target/<link>             Transform3D and longer axes: the measured rotation, at the
                                           measured position where there is one, else at the estimate's
    /subject/<i>/errors/<mnte|rmse>        Scalars: the paper's metrics (those the diagnostics hold)
    /subject/<i>/residual/<position|orientation>/<link>
                                           Scalars: the step's |r| (m, or sin of the angle)
    /subject/<i>/joints/<joint>            Scalars: angle (rad), and lower and upper limit where the
                                           joint has effective ones
    /subject/<i>/solver/<active_constraints|solved|dropped|projected>
    /subject/<i>/diagnostics/<name>        Scalars: any other per-subject diagnostic [T,B]
    /timing/<step_time|kinematics_time|qp_time>   Scalars: ms for the whole batch's step
    /aggregate/<group>/<name>              Scalars: mean and max over all subjects (batches only)

A blueprint in the same file opens it on the 3D view beside error, residual, joint and solver plots.
Open with `rerun FILE.rrd`.
"""

from __future__ import annotations

import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch

from ..errors import InputError, optional
from ..io.files import PartFile
from ..method.kinematics import KinematicModel
from ..method.state import TargetSequence, Trajectory
from .evaluation import time_chunks
from .visuals import Visual, log_visuals, quaternion_xyzw, visuals  # noqa: F401  (visuals: part of this module's API)

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb
else:
    rr = optional("rerun", "viz", "writing rerun recordings")
    rrb = optional("rerun.blueprint", "viz", "writing rerun recordings")

GROUPS = {"mnte": "errors", "rmse": "errors", "active_constraints": "solver", "solved": "solver",
          "dropped": "solver", "projected": "solver"}  # per-subject diagnostics [T,B]; others: "diagnostics"
BATCH_SERIES = ("step_time", "kinematics_time", "qp_time")  # [T] seconds for the whole batch
NO_LIMIT = 19.9  # rad: URDFs write +-10 rad for "no limit" (as KinematicModel.summary counts)
PALETTE = ((80, 140, 220), (230, 120, 50), (90, 180, 90), (200, 80, 160), (150, 110, 60), (60, 170, 180))


def log_trajectory(path: str | Path, model: KinematicModel, links: Sequence[str], trajectory: Trajectory,
                   targets: TargetSequence | None = None, *, position_links: Sequence[str] | None = None,
                   urdf: str | Path | None = None, subjects: Sequence[int] | None = None, app_id: str = "torchik",
                   axis_length: float = 0.08, chunk: int = 4096, progress: bool = False) -> Path:
    """Write `trajectory` (time [T], states [T,B,...], diagnostics) as a rerun recording at `path`.

    links: the orientation targets' links (the order of targets.rotation and of residual_norm's
    orientation part); position_links: the position targets' (default: the base link).
    targets: the measured sequence (time [T0 >= T], rotation [T0,B,n_o,3,3], position [T0,B,n_p,3]),
    cut to the trajectory's length (an interrupted run); None logs the estimate only.
    urdf: the model's URDF (a file or its text) whose visual shapes draw the body (default: the
    model's source file when it has one; without one the body is the skeleton only).
    subjects: which of the B subjects get their own entity tree (default all); the aggregate
    covers all. chunk: time steps logged at a time (`RrdWriter`), rows per kinematics call.
    progress: a bar once the writing has lasted a second. The file is written beside `path` and
    moved onto it when complete: an interrupted call leaves no partial file. Returns the path.
    """
    T, B = trajectory.joint_positions.shape[:2]
    if targets is not None:
        _check_targets(targets, T, B, len(links), len(position_links) if position_links is not None else 1)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=T, desc=f"writing {Path(path).name}", unit="step", leave=False, delay=1.0)
    try:
        with RrdWriter(path, model, links, position_links=position_links, urdf=urdf, subjects=subjects, app_id=app_id,
                       axis_length=axis_length, chunk=chunk) as writer:
            for start in range(0, max(T, 1), chunk):
                writer.write(trajectory.part(start, start + chunk),
                             None if targets is None else targets.part(start, min(start + chunk, T)))
                if bar is not None:
                    bar.update(min(chunk, T - start))
            return writer.commit()
    finally:
        if bar is not None:
            bar.close()


class RrdWriter:
    """A rerun recording written as a run goes: `write` each part of the trajectory (with its
    targets) in order, then `commit`; the file streams to a hidden path beside `path`, moved onto it
    by `commit` (leaving the `with` block without it leaves nothing). Arguments as `log_trajectory`'s;
    memory is one part's."""

    def __init__(self, path: str | Path, model: KinematicModel, links: Sequence[str], *,
                 position_links: Sequence[str] | None = None, urdf: str | Path | None = None,
                 subjects: Sequence[int] | None = None, app_id: str = "torchik", axis_length: float = 0.08,
                 chunk: int = 4096):
        self.model, self.links = model, tuple(links)
        self.position_links = tuple(position_links) if position_links is not None else (model.base_link,)
        if urdf is None and Path(model.source).is_file():
            urdf = model.source
        self.shapes = visuals(urdf) if urdf is not None else {}
        unknown = sorted(set(self.shapes) - set(model.link_names))
        if unknown:
            raise InputError(f"urdf: links {unknown} are not in model {model.name!r}: is it the model's URDF?")
        # every link that is tracked or drawn, tracked ones first
        self.drawn = self.links + tuple(n for n in model.link_names if n in self.shapes and n not in self.links)
        self.subjects = None if subjects is None else list(subjects)
        self.app_id, self.axis_length, self.chunk = app_id, axis_length, chunk
        self.file = PartFile(path)
        self.rec: rr.RecordingStream | None = None
        self.batch = 0
        self.named: set[str] = set()  # the series whose names are logged (once, static)

    def write(self, trajectory: Trajectory, targets: TargetSequence | None = None) -> None:
        """A part of the run: trajectory [t,B,...] with its diagnostics, targets [t,B,...] or None."""
        T, B = trajectory.joint_positions.shape[:2]
        if trajectory.time.shape != (T,):
            raise InputError(f"trajectory.time: expected shape [{T}], got {list(trajectory.time.shape)}")
        if targets is not None:
            _check_targets(targets, T, B, len(self.links), len(self.position_links))
        per_subject, per_batch = _split_diagnostics(trajectory.diagnostics, T, B, len(self.links) + len(self.position_links))
        rec = self.rec if self.rec is not None else self._open(B, targets is not None)
        if B != self.batch:
            raise InputError(f"a part of {B} subjects; the recording's earlier parts had {self.batch}")
        columns = _Columns.of(self.model, self.links, self.drawn, trajectory, per_subject, self.chunk)
        for i in self.subjects or ():
            self._log_subject(columns, i, targets, trajectory.time)
        for name, values in per_batch.items():
            self._scalars(f"/timing/{name}", columns.time, values * 1e3, [f"{name.replace('_', ' ')} (ms)"])
        if B > 1:
            for name, values in per_subject.items():
                with warnings.catch_warnings():  # a step where every subject's value is NaN stays NaN
                    warnings.simplefilter("ignore", RuntimeWarning)
                    summary = np.stack((np.nanmean(values, axis=1), np.nanmax(values, axis=1)), axis=1)
                self._scalars(f"/aggregate/{GROUPS.get(name, 'diagnostics')}/{name}", columns.time, summary,
                              ["mean", "max"])
        rec.flush()  # to the file: what rerun holds stays one part's

    def commit(self) -> Path:
        """The recording closed (with its footer) and moved onto the path; returns it."""
        if self.rec is None:
            raise InputError("no part of the trajectory was written")
        self.rec.flush()
        self.rec.disconnect()
        self.rec = None
        return self.file.commit()

    def close(self) -> None:
        """Stop writing; without commit, the file is removed."""
        if self.rec is not None:
            self.rec.disconnect()
            self.rec = None
        self.file.discard()

    def __enter__(self) -> "RrdWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _open(self, B: int, targets: bool) -> rr.RecordingStream:
        """The file started: blueprint, name, coordinates and what does not change over time."""
        self.subjects = list(range(B)) if self.subjects is None else self.subjects
        if not self.subjects or not all(0 <= i < B for i in self.subjects):
            raise InputError(f"subjects: expected indices in [0, {B}), got {self.subjects}")
        # a fresh id: one per process (the default) would make viewers merge the files
        rec = rr.RecordingStream(self.app_id, recording_id=uuid.uuid4())
        rec.save(self.file.part, default_blueprint=blueprint(self.subjects, aggregate=B > 1))
        self.rec, self.batch = rec, B
        rec.send_recording_name(self.file.path.stem)
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for i in self.subjects:
            root, color = f"/subject/{i}", PALETTE[i % len(PALETTE)]
            for k, link in enumerate(self.drawn):
                name = f"{root}/estimate/{rr.escape_entity_path_part(link)}"
                if k < len(self.links):
                    rec.log(name, rr.TransformAxes3D(self.axis_length), static=True)
                log_visuals(rec, f"{name}/visual", self.shapes.get(link, ()), color)
            rec.log(f"{root}/skeleton", rr.LineStrips3D.from_fields(radii=[0.01], colors=[color]), static=True)
            for link in self.links if targets else ():
                rec.log(f"{root}/target/{rr.escape_entity_path_part(link)}", rr.TransformAxes3D(1.5 * self.axis_length),
                        static=True)
        return rec

    def _log_subject(self, c: "_Columns", i: int, targets: TargetSequence | None, target_time: torch.Tensor) -> None:
        """Subject i's part: link poses, skeleton, targets, diagnostics, residuals, joints."""
        rec, root, model = self.rec, f"/subject/{i}", self.model
        assert rec is not None  # opened by the first write
        T, time = len(c.joint_positions), c.time
        for k, link in enumerate(self.drawn):
            rec.send_columns(f"{root}/estimate/{rr.escape_entity_path_part(link)}", [time], rr.Transform3D.columns(
                translation=c.position[:, i, k], quaternion=c.quaternion[:, i, k]))
        rec.send_columns(f"{root}/skeleton", [time], rr.LineStrips3D.columns(
            strips=c.bones[:, i].reshape(-1, 2, 3)).partition(np.full(T, c.bones.shape[2])))
        if targets is not None:
            _log_targets(rec, f"{root}/target", target_time, targets, i, self.links, self.position_links,
                         c.position[:, i, :len(self.links)])
        for name, values in c.per_subject.items():
            self._scalars(f"{root}/{GROUPS.get(name, 'diagnostics')}/{name}", time, values[:, i])
        for j, link in enumerate(self.position_links + self.links):
            kind = "position" if j < len(self.position_links) else "orientation"
            self._scalars(f"{root}/residual/{kind}/{rr.escape_entity_path_part(link)}", time, c.residual[:, i, j])
        lower, upper = (t.detach().to("cpu", torch.float64).numpy() for t in (model.lower, model.upper))
        limited = np.isfinite(lower) & np.isfinite(upper) & (upper - lower < NO_LIMIT)
        for j, joint in enumerate(model.joint_names):
            values, names = c.joint_positions[:, i, j], None
            if limited[j]:
                values = np.stack((values, np.full(T, lower[j]), np.full(T, upper[j])), axis=1)
                names = ["angle", "lower limit", "upper limit"]
            self._scalars(f"{root}/joints/{rr.escape_entity_path_part(joint)}", time, values, names)

    def _scalars(self, path: str, time: rr.TimeColumn, values: np.ndarray, names: list[str] | None = None) -> None:
        """`_send_scalars`, the series' names logged with the first part only."""
        assert self.rec is not None  # opened by the first write
        _send_scalars(self.rec, path, time, values, names if path not in self.named else None)
        self.named.add(path)


@dataclass
class _Columns:
    """What a part sends, computed once for all subjects: the drawn links' poses [T,B,D,3(,4)]
    (float32), the bones [T,B,E,2,3], the joints [T,B,n], the residual norms [T,B,targets] and the
    per-subject diagnostics."""

    time: rr.TimeColumn
    position: np.ndarray
    quaternion: np.ndarray
    bones: np.ndarray
    joint_positions: np.ndarray
    residual: np.ndarray
    per_subject: dict[str, np.ndarray]

    @staticmethod
    def of(model: KinematicModel, links: tuple[str, ...], drawn: tuple[str, ...], trajectory: Trajectory,
           per_subject: dict[str, np.ndarray], chunk: int) -> "_Columns":
        rotation, position = _link_poses(model, drawn, trajectory, chunk)  # [T,B,D,3,3], [T,B,D,3] float32
        child, parent = _bones(model, links)
        bones = torch.stack((position[:, :, child], position[:, :, parent]), dim=-2).numpy()  # [T,B,E,2,3]
        host = lambda t: t.detach().to("cpu", torch.float64).numpy()  # noqa: E731
        return _Columns(rr.TimeColumn("time", duration=host(trajectory.time)), position.numpy(),
                        quaternion_xyzw(rotation).numpy(), bones, host(trajectory.joint_positions),
                        host(trajectory.diagnostics["residual_norm"]), per_subject)


def blueprint(subjects: Sequence[int], aggregate: bool = False) -> rrb.Blueprint:
    """The layout: the 3D view on the left; on the right MNTE and angular velocity RMSE (of the
    first logged subject, or mean and max over the batch), residuals and joint angles of the first
    logged subject, solver status and step time."""
    first = f"/subject/{subjects[0]}"
    summary = "/aggregate" if aggregate else first
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial3DView(name="estimate and targets", origin="/"),
        rrb.Vertical(
            rrb.Horizontal(rrb.TimeSeriesView(name="MNTE", origin=f"{summary}/errors/mnte"),
                           rrb.TimeSeriesView(name="angular velocity RMSE (rad/s)", origin=f"{summary}/errors/rmse")),
            rrb.TimeSeriesView(name=f"residual norms, subject {subjects[0]}", origin=f"{first}/residual"),
            rrb.TimeSeriesView(name=f"joint angles (rad), subject {subjects[0]}", origin=f"{first}/joints"),
            rrb.TimeSeriesView(name="solver and step time", contents=[f"{summary}/solver/**", "/timing/**"]),
        ),
        column_shares=[3, 2],
    ))


def _check_targets(targets: TargetSequence, T: int, B: int, n_o: int, n_p: int) -> None:
    """Raise InputError unless the targets cover the trajectory's T steps, B subjects and links."""
    expected = dict(rotation=(B, n_o, 3, 3), position=(B, n_p, 3))
    for name, shape in expected.items():
        value = getattr(targets, name)
        if value.dim() != len(shape) + 1 or tuple(value.shape[1:]) != shape or value.shape[0] < T:
            raise InputError(f"targets.{name}: expected shape [T0 >= {T},{','.join(map(str, shape))}] "
                             f"(the trajectory's steps, subjects and links), got {list(value.shape)}")


def _link_poses(model: KinematicModel, links: tuple[str, ...], trajectory: Trajectory, chunk: int):
    """Estimated link rotations [T,B,L,3,3] and positions [T,B,L,3], float32 on the CPU (what the
    viewer draws), by the batched kinematics over a few whole time steps at a time."""
    T, B = trajectory.joint_positions.shape[:2]
    L = len(links)
    rotations, positions = [], []
    with torch.inference_mode():
        for _, m, p, R, s in time_chunks(model, trajectory, chunk):
            kin = m(p, R, s, links, jacobian=False)
            rotations.append(kin.rotation.to("cpu", torch.float32))
            positions.append(kin.position.to("cpu", torch.float32))
    return torch.cat(rotations).view(T, B, L, 3, 3), torch.cat(positions).view(T, B, L, 3)


def _bones(model: KinematicModel, links: tuple[str, ...]) -> tuple[list[int], list[int]]:
    """(child, parent) link indices: each link and its nearest ancestor among `links`. A link is
    above another when the joints above it are a subset of the other's (links on one rigid body:
    the earlier one is above)."""
    above = model.select(links).ancestor_mask.bool().cpu()  # [L,n]
    child, parent = [], []
    for b in range(len(links)):  # build time: L links
        ancestors = [a for a in range(len(links)) if a != b and bool((above[a] <= above[b]).all())
                     and (bool((above[a] != above[b]).any()) or a < b)]
        if ancestors:
            child.append(b)
            parent.append(max(ancestors, key=lambda a: int(above[a].sum())))
    return child, parent


def _split_diagnostics(diagnostics: dict[str, torch.Tensor], T: int, B: int, n_targets: int):
    """Per-subject scalar series {name: [T,B]} and whole-batch ones {name: [T]}, as float64 NumPy."""
    if "residual_norm" not in diagnostics or tuple(diagnostics["residual_norm"].shape) != (T, B, n_targets):
        raise InputError(f"trajectory.diagnostics['residual_norm']: expected shape [{T},{B},{n_targets}] "
                         f"(position then orientation targets)")
    per_subject: dict[str, np.ndarray] = {}
    per_batch: dict[str, np.ndarray] = {}
    for name, series in diagnostics.items():
        value = series.detach().to("cpu", torch.float64).numpy()
        if name in BATCH_SERIES:
            if value.shape != (T,):
                raise InputError(f"trajectory.diagnostics[{name!r}]: expected shape [{T}], got {list(value.shape)}")
            per_batch[name] = value
        elif name != "residual_norm":
            if value.shape != (T, B):
                raise InputError(f"trajectory.diagnostics[{name!r}]: expected shape [{T},{B}], got {list(value.shape)}")
            per_subject[name] = value
    return per_subject, per_batch


def _log_targets(rec: rr.RecordingStream, root: str, time: torch.Tensor, targets: TargetSequence, i: int,
                 links: tuple[str, ...], position_links: tuple[str, ...], estimate: np.ndarray) -> None:
    """Subject i's measured frames [T] at root/<link> (estimate: the estimated link origins
    [T,L,3], where a target without a position is drawn); steps with a non-finite target are left
    out of that link's column."""
    T = len(time)
    rotation = targets.rotation[:T, i].detach().to("cpu", torch.float64)  # [T,L,3,3]
    where = torch.from_numpy(estimate).double().clone()  # [T,L,3]: at the estimated origin ...
    for j, link in enumerate(position_links):  # ... or at the measured one
        if link in links:
            where[:, links.index(link)] = targets.position[:T, i, j].detach().to("cpu", torch.float64)
    known = (torch.isfinite(rotation).flatten(-2).all(-1) & torch.isfinite(where).all(-1)).numpy()  # [T,L]
    quaternion, at = quaternion_xyzw(torch.nan_to_num(rotation)).numpy(), where.numpy()
    seconds = time.detach().to("cpu", torch.float64).numpy()
    for k, link in enumerate(links):
        name = f"{root}/{rr.escape_entity_path_part(link)}"
        keep = known[:, k]
        rec.send_columns(name, [rr.TimeColumn("time", duration=seconds[keep])], rr.Transform3D.columns(
            translation=at[keep, k], quaternion=quaternion[keep, k]))


def _send_scalars(rec: rr.RecordingStream, path: str, time: rr.TimeColumn, values: np.ndarray,
                  names: list[str] | None = None) -> None:
    """values [T] (one series) or [T,k] (k series, named by `names`) at `path`."""
    if names is not None:
        rec.log(path, rr.SeriesLines(names=names), static=True)
    values = np.ascontiguousarray(values, dtype=np.float64)
    columns = rr.Scalars.columns(scalars=values.reshape(-1))
    rec.send_columns(path, [time], columns if values.ndim == 1 else columns.partition(np.full(len(values), values.shape[1])))

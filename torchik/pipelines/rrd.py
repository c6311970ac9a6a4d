"""Rerun recordings (.rrd) of a tracked sequence: the body moving with the estimate, each target's
measured frame beside the estimated link frame, and the diagnostics as time series, on one time
line "time" (seconds). Logged by columns: one `send_columns` per entity, never a loop over time,
and the link poses of all time steps from batched kinematics.

Entities, for each logged subject i of the batch:

    /subject/<i>/estimate/<link>           Transform3D: the estimated link pose; axes on the tracked links
    /subject/<i>/estimate/<link>/visual    the link's URDF visuals (meshes at visual/mesh<k>), fixed to it
    /subject/<i>/skeleton                  LineStrips3D: a bone from each tracked link to its nearest
                                           tracked ancestor
    /subject/<i>/target/<link>             Transform3D and longer axes: the measured rotation, at the
                                           measured position where there is one, else at the estimate's
    /subject/<i>/errors/<mnte|rmse>        Scalars: the paper's metrics (those the diagnostics hold)
    /subject/<i>/residual/<position|orientation>/<link>
                                           Scalars: the step's |r| (m, or sin of the angle)
    /subject/<i>/joints/<joint>            Scalars: angle (rad), and its limits where they are effective
    /subject/<i>/solver/<active_constraints|solved|dropped|projected>
    /subject/<i>/diagnostics/<name>        Scalars: any other per-subject diagnostic [T,B]
    /subject/<i>/tasks/<name>              Scalars: an added task's series (`log_series`: a contact's slide)
    /timing/<step_time|kinematics_time|qp_time>   Scalars: ms for the whole batch's step
    /aggregate/<group>/<name>              Scalars: mean and max over all subjects (batches only)

A blueprint opens it on the 3D view beside error, residual, joint and solver plots (`rerun FILE.rrd`).
`StepLogger` sends the same entities step by step, as a live session does (`torchik live --viewer`).
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
from .rrd_layout import blueprint
from .visuals import Visual, log_visuals, quaternion_xyzw, visuals  # noqa: F401  (visuals: part of this module's API)

if TYPE_CHECKING:
    import rerun as rr
else:
    rr = optional("rerun", "viz", "writing rerun recordings")

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
    covers all. chunk: rows per kinematics call. progress: a bar once the writing has lasted a
    second. The file is written beside `path` and moved onto it when complete: an interrupted
    call leaves no partial file. Returns the path.
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
    memory is one part's. The entities are `StepLogger`'s, the live session's."""

    def __init__(self, path: str | Path, model: KinematicModel, links: Sequence[str], *,
                 position_links: Sequence[str] | None = None, urdf: str | Path | None = None,
                 subjects: Sequence[int] | None = None, app_id: str = "torchik", axis_length: float = 0.08,
                 chunk: int = 4096):
        if urdf is None and Path(model.source).is_file():
            urdf = model.source
        self.shapes = visuals(urdf) if urdf is not None else {}
        unknown = sorted(set(self.shapes) - set(model.link_names))
        if unknown:
            raise InputError(f"urdf: links {unknown} are not in model {model.name!r}: is it the model's URDF?")
        self.model, self.links, self.position_links = model, tuple(links), position_links
        self.subjects = None if subjects is None else list(subjects)
        self.app_id, self.axis_length, self.chunk = app_id, axis_length, chunk
        self.file = PartFile(path)
        self.logger: StepLogger | None = None  # made with the recording, at the first part
        self.batch = 0

    def write(self, trajectory: Trajectory, targets: TargetSequence | None = None) -> None:
        """A part of the run: trajectory [t,B,...] with its diagnostics, targets [t,B,...] or None."""
        T, B = trajectory.joint_positions.shape[:2]
        if trajectory.time.shape != (T,):
            raise InputError(f"trajectory.time: expected shape [{T}], got {list(trajectory.time.shape)}")
        if self.logger is None:
            self._open(B)
        assert self.logger is not None and self.subjects is not None
        if B != self.batch:
            raise InputError(f"a part of {B} subjects; the recording's earlier parts had {self.batch}")
        if targets is not None:
            _check_targets(targets, T, B, len(self.links), len(self.logger.position_links))
        self.logger.log(trajectory, targets, range(B), rows=self.subjects)
        self.logger.rec.flush()  # to the file: what rerun holds stays one part's

    def log_series(self, path: str, time: np.ndarray, values: np.ndarray, names: list[str] | None = None) -> None:
        """Scalar series over the run (values [T] or [T,k] at `time` [T], s) at `path` under the first
        subject (what added tasks did: a contact's slide), written before `commit`."""
        if self.logger is None or self.subjects is None:
            raise InputError("log_series: write a part of the trajectory first")
        column = rr.TimeColumn("time", duration=np.asarray(time, dtype=np.float64))
        _send_scalars(self.logger.rec, f"/subject/{self.subjects[0]}/{path}", column, values, names)

    def commit(self) -> Path:
        """The recording closed (with its footer) and moved onto the path; returns it."""
        if self.logger is None:
            raise InputError("no part of the trajectory was written")
        self.logger.rec.flush()
        self.logger.rec.disconnect()
        self.logger = None
        return self.file.commit()

    def close(self) -> None:
        """Stop writing; without commit, the file is removed."""
        if self.logger is not None:
            self.logger.rec.disconnect()
            self.logger = None
        self.file.discard()

    def __enter__(self) -> "RrdWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _open(self, B: int) -> None:
        self.subjects = list(range(B)) if self.subjects is None else self.subjects
        if not self.subjects or not all(0 <= i < B for i in self.subjects):
            raise InputError(f"subjects: expected indices in [0, {B}), got {self.subjects}")
        rec = rr.RecordingStream(self.app_id, recording_id=uuid.uuid4())  # else one id per process: viewers merge files
        rec.save(self.file.part, default_blueprint=blueprint(self.subjects, aggregate=B > 1))
        rec.send_recording_name(self.file.path.stem)
        self.logger = StepLogger(rec, self.model, self.links, self.position_links, axis_length=self.axis_length,
                                 shapes=self.shapes, chunk=self.chunk)
        self.batch = B


class StepLogger:
    """Steps of a live session logged as they are made on an open RecordingStream (a viewer, a
    file, or both), with the entities of `log_trajectory`: batch row i as /subject/<names[i]>.
    What never changes (the visuals, the bones, the world's axes, each subject's static parts) is
    computed or sent once."""

    def __init__(self, rec: rr.RecordingStream, model: KinematicModel, links: Sequence[str],
                 position_links: Sequence[str] | None = None, urdf: str | Path | None = None, axis_length: float = 0.08,
                 shapes: dict[str, list[Visual]] | None = None, chunk: int = 4096):
        """urdf: whose visuals draw the body (default the model's file); shapes: those visuals, read
        already (`visuals(urdf)`); chunk: rows per kinematics call."""
        self.rec, self.model, self.links = rec, model, tuple(links)
        self.position_links = tuple(position_links) if position_links is not None else (model.base_link,)
        if urdf is None and Path(model.source).is_file():
            urdf = model.source
        self.shapes = shapes if shapes is not None else visuals(urdf) if urdf is not None else {}
        self.bones = _bones(model, self.links)
        self.axis_length, self.chunk = axis_length, chunk
        self.logged: set[int] = set()

    def log(self, trajectory: Trajectory, targets: TargetSequence | None, names: Sequence[int],
            rows: Sequence[int] | None = None) -> None:
        """trajectory: a few steps [T,B,...] with their diagnostics (residual_norm [T,B,n_targets],
        the per-subject ones [T,B], the batch's [T]); targets: theirs [T,B,...]; row i is subject
        names[i]; rows: the rows given their own entity tree (default all; the aggregate covers all)."""
        T, B = trajectory.joint_positions.shape[:2]
        if not self.logged:
            self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        per_subject, per_batch = _split_diagnostics(trajectory.diagnostics, T, B,
                                                    len(self.links) + len(self.position_links))
        columns = _Columns.of(self.model, self.links, self.position_links, self.shapes, trajectory, per_subject,
                              self.chunk, self.bones)
        shown = {i: names[i] for i in (range(B) if rows is None else rows)}
        new = set(shown.values()) - self.logged
        _log_batch(self.rec, columns, shown, targets, trajectory.time, per_batch, self.axis_length, new)
        self.logged |= new

@dataclass
class _Columns:
    """What log_trajectory sends, computed once for all subjects: the drawn links (tracked first)
    and their poses [T,B,D,3(,4)] (float32), the bones [T,B,E,2,3], the joints [T,B,n] with their
    effective limits, the residual norms [T,B,targets] and the per-subject diagnostics."""

    model: KinematicModel
    links: tuple[str, ...]
    position_links: tuple[str, ...]
    shapes: dict[str, list[Visual]]
    drawn: tuple[str, ...]
    time: rr.TimeColumn
    position: np.ndarray
    quaternion: np.ndarray
    bones: np.ndarray
    joint_positions: np.ndarray
    residual: np.ndarray
    limited: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    per_subject: dict[str, np.ndarray]

    @staticmethod
    def of(model: KinematicModel, links: tuple[str, ...], position_links: tuple[str, ...],
           shapes: dict[str, list[Visual]], trajectory: Trajectory, per_subject: dict[str, np.ndarray],
           chunk: int, bones: tuple[list[int], list[int]] | None = None) -> "_Columns":
        # every link that is tracked or drawn, tracked ones first
        drawn = links + tuple(name for name in model.link_names if name in shapes and name not in links)
        rotation, position = _link_poses(model, drawn, trajectory, chunk)  # [T,B,D,3,3], [T,B,D,3] float32
        child, parent = bones if bones is not None else _bones(model, links)
        segments = torch.stack((position[:, :, child], position[:, :, parent]), dim=-2).numpy()  # [T,B,E,2,3]
        host = lambda t: t.detach().to("cpu", torch.float64).numpy()  # noqa: E731
        lower, upper = host(model.lower), host(model.upper)
        return _Columns(model, links, position_links, shapes, drawn, rr.TimeColumn("time", duration=host(trajectory.time)),
                        position.numpy(), quaternion_xyzw(rotation).numpy(), segments, host(trajectory.joint_positions),
                        host(trajectory.diagnostics["residual_norm"]), np.isfinite(lower) & np.isfinite(upper) &
                        (upper - lower < NO_LIMIT), lower, upper, per_subject)


def _log_batch(rec: rr.RecordingStream, columns: _Columns, names: dict[int, int], targets: TargetSequence | None,
               target_time: torch.Tensor, per_batch: dict[str, np.ndarray], axis_length: float, new: set[int],
               after_each=None) -> None:
    """Batch row i as subject names[i] (its static parts when names[i] is in `new`), the batch's
    timing and, for a batch, the aggregate over its rows."""
    time, B = columns.time, columns.joint_positions.shape[1]
    for i, name in names.items():
        _log_subject(rec, columns, i, targets, target_time, axis_length, name, name in new)
        if after_each is not None:
            after_each()
    for series, values in per_batch.items():
        _send_scalars(rec, f"/timing/{series}", time, values * 1e3, [f"{series.replace('_', ' ')} (ms)"])
    if B > 1:
        for series, values in columns.per_subject.items():
            with warnings.catch_warnings():  # a step where every subject's value is NaN stays NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                summary = np.stack((np.nanmean(values, axis=1), np.nanmax(values, axis=1)), axis=1)
            _send_scalars(rec, f"/aggregate/{GROUPS.get(series, 'diagnostics')}/{series}", time, summary,
                          ["mean", "max"])


def _log_subject(rec: rr.RecordingStream, columns: _Columns, i: int, targets: TargetSequence | None,
                 target_time: torch.Tensor, axis_length: float, name: int, static: bool) -> None:
    """Batch row i's entity tree at /subject/<name>: link poses and visuals, skeleton, targets,
    diagnostics, residuals, joints; the parts that never change (visuals, axes, series names) when
    `static`."""
    c, root, color = columns, f"/subject/{name}", PALETTE[name % len(PALETTE)]
    T, time = len(c.joint_positions), c.time
    for k, link in enumerate(c.drawn):
        path = f"{root}/estimate/{rr.escape_entity_path_part(link)}"
        if static and k < len(c.links):
            rec.log(path, rr.TransformAxes3D(axis_length), static=True)
        if static:
            log_visuals(rec, f"{path}/visual", c.shapes.get(link, ()), color)
        rec.send_columns(path, [time], rr.Transform3D.columns(
            translation=c.position[:, i, k], quaternion=c.quaternion[:, i, k]))
    if static:
        rec.log(f"{root}/skeleton", rr.LineStrips3D.from_fields(radii=[0.01], colors=[color]), static=True)
    rec.send_columns(f"{root}/skeleton", [time], rr.LineStrips3D.columns(
        strips=c.bones[:, i].reshape(-1, 2, 3)).partition(np.full(T, c.bones.shape[2])))
    if targets is not None:
        _log_targets(rec, f"{root}/target", target_time, targets, i, c.links, c.position_links,
                     c.position[:, i, :len(c.links)], 1.5 * axis_length, static)
    for series, values in c.per_subject.items():
        _send_scalars(rec, f"{root}/{GROUPS.get(series, 'diagnostics')}/{series}", time, values[:, i])
    for j, link in enumerate(c.position_links + c.links):
        kind = "position" if j < len(c.position_links) else "orientation"
        _send_scalars(rec, f"{root}/residual/{kind}/{rr.escape_entity_path_part(link)}", time, c.residual[:, i, j])
    for j, joint in enumerate(c.model.joint_names):
        values, labels = c.joint_positions[:, i, j], None
        if c.limited[j]:
            values = np.stack((values, np.full(T, c.lower[j]), np.full(T, c.upper[j])), axis=1)
            labels = ["angle", "lower limit", "upper limit"] if static else None
        _send_scalars(rec, f"{root}/joints/{rr.escape_entity_path_part(joint)}", time, values, labels)


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
                 links: tuple[str, ...], position_links: tuple[str, ...], estimate: np.ndarray,
                 axis_length: float, static: bool = True) -> None:
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
        if static:
            rec.log(name, rr.TransformAxes3D(axis_length), static=True)
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

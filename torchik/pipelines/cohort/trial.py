"""One batch of a cohort, on a worker: read each trial, track the trials together, write each
trial's results on its own.

A trial goes through what `torchik track` does for one recording (`io.read`, the link map and
its calibration, `recording_targets`, `DynamicalIK` settled on the first frame, `tracking_errors`,
`summary`, `save_trajectory`); only the tracker's batch holds several subjects. Trials shorter than the
batch's longest are padded with their last frame held still and cut back before anything is
measured: the tracker is causal (step k reads targets up to k), so padding changes nothing.

Failures stay with their trial: a trial that does not read, map or fit is recorded as failed and
its batch goes on without it; a batch whose tracking raises is tracked again trial by trial, so
that the error lands on the trial that caused it; a trial whose state turns non-finite, or whose
MNTE after the transient is beyond DIVERGED_MNTE, is recorded as diverged.

Results: `OUT/trials/<trial>/` holds `result.json` (the summary row, the fingerprint of the spec,
the run that wrote it), `estimate.npz` (`save_trajectory`'s format) and, when asked, `trial.rrd`.
The folder is written aside and renamed into place, so it is there whole or not at all.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import time
import uuid
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...errors import InputError
from ...io.maps import map_recording
from ...io.recording import Recording
from ...io.targets import recording_targets
from ...io.trajectory import save_trajectory
from ...method.kinematics import KinematicModel
from ...method.models import TRACKED_LINKS, human_urdf, icub_urdf_path, load_model
from ...method.state import TargetSequence, Trajectory
from ...method.tracker import DynamicalIK
from ..evaluation import summary, tracking_errors, tracking_statistics
from ..track import SETTLE
from .manifest import TrialSpec, human_subject
from .plan import Batch

DIVERGED_MNTE = 0.5  # a median MNTE above it (a mean orientation error beyond 60 degrees) is no tracking
SAME_TIME = 1e-9  # relative to dt: time steps that agree this well share a batch's time line
COLUMNS = ("trial", "subject", "model", "status", "error", "frames", "duration_s", "rate_hz", "statistics_from_s",
           "mnte_median", "mnte_p99", "mnte_max", "rmse_median", "rmse_p99", "rmse_max", "joint_error_max",
           "joint_error_rms", "qp_fallbacks", "dropped_targets", "step_time_ms", "track_s", "batch", "batch_size",
           "padded_frames")


@dataclass
class Prepared:
    """A trial ready to track: its model, links, recording (in the model's links), targets
    [T,1,...] and nominal time step dt (s), as `torchik track` would have them."""

    spec: TrialSpec
    fingerprint: str
    model: KinematicModel
    links: tuple[str, ...]
    recording: Recording
    sequence: TargetSequence
    dt: float


def track_batch(batch: Batch, out: str, run: str, rrd: bool = False,
                exit_once: tuple[str, str] | None = None) -> list[dict]:
    """Track `batch` and write each trial's results under `out`; returns the summary rows.

    A task of the cohort on a Dask worker: torch on one thread (the workers are the parallelism);
    trials already written by this `run` (an earlier attempt of this task, on a worker that died)
    are not tracked again. exit_once = (trial, marker file): for tests, the worker process exits
    before writing that trial unless the marker exists, which it creates: a worker killed mid-batch."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rows, prepared = [], []
        for spec, fingerprint in zip(batch.trials, batch.fingerprints):
            stored = load_result(Path(out), spec.trial)
            if stored is not None and stored.get("run") == run:
                rows.append(stored["row"])
                continue
            try:
                prepared.append(prepare(spec, fingerprint))
            except Exception as exc:  # a trial's own failure: the batch goes on without it
                rows.append(write_failure(Path(out), spec, fingerprint, run, exc))
        for group in compatible_groups(prepared):
            rows += track_group(group, Path(out), run, batch.index, rrd, exit_once)
        return rows
    finally:
        torch.set_num_threads(threads)


def prepare(spec: TrialSpec, fingerprint: str = "") -> Prepared:
    """Read the trial's recording, map and calibrate it as `torchik track --map --calibration`
    would, and build its targets. Raises what the readers and the map raise."""
    from ...io import read

    model = subject_model(spec.model, spec.height, spec.mass, spec.segments, spec.subject_from)
    recording = read(spec.recording)
    if spec.map:
        recording = mapped(recording, spec, model)
    # the mapped links, or a built-in model's tracked links; a URDF model tracks the recording's
    links = recording.links if spec.map else TRACKED_LINKS.get(spec.model, recording.links)
    sequence = recording_targets(recording, links, dtype=model.dtype, device=model.device)
    dt = float(np.median(np.diff(recording.time))) if len(recording.time) > 1 else 0.01
    return Prepared(spec, fingerprint, model, tuple(links), recording, sequence, dt)


def mapped(recording: Recording, spec: TrialSpec, model: KinematicModel) -> Recording:
    """The recording in the model's links through the spec's map, its offsets calibrated on the
    spec's static trial when it names one (else on the recording, for a map that calibrates)."""
    from ...io import read

    if spec.map is None:
        raise InputError(f"trial {spec.trial!r}: no map to apply")
    static = read(spec.calibration) if spec.calibration else None
    return map_recording(recording, spec.map, model, static, spec.calibration_frame)[0]


@functools.lru_cache(maxsize=64)
def subject_model(name: str, height: float | None, mass: float | None, segments: tuple,
                  subject_from: str | None = None) -> KinematicModel:
    """The model of a trial (a built-in name, for a subject's anthropometry, or a URDF file), kept
    per worker: a subject's trials share one compiled model."""
    if name.endswith(".urdf"):
        return KinematicModel.from_urdf(name)
    return load_model(name, human_subject(height, mass, segments, subject_from))


def compatible_groups(prepared: list[Prepared]) -> list[list[Prepared]]:
    """Trials that share a tracker: the same links and the same time steps (each shorter trial's
    steps those of the group's first, longest, trial). Longest first in each group."""
    groups: list[list[Prepared]] = []
    for p in sorted(prepared, key=lambda p: -len(p.sequence)):
        lead = next((g for g in groups if _fits(g[0], p)), None)
        if lead is None:
            groups.append([p])
        else:
            lead.append(p)
    return groups


def _fits(lead: Prepared, p: Prepared) -> bool:
    if lead.links != p.links or abs(lead.dt - p.dt) > SAME_TIME * lead.dt:
        return False
    steps, lead_steps = np.diff(p.recording.time), np.diff(lead.recording.time)[:len(p.sequence) - 1]
    return bool(np.allclose(steps, lead_steps, rtol=0.0, atol=SAME_TIME * lead.dt))


def pad(sequence: TargetSequence, frames: int) -> TargetSequence:
    """sequence [T,1,...] to [frames,1,...]: the last targets held, their velocities zero. (The
    time line is the batch's; this one's is left as it is.)"""
    extra = frames - len(sequence)
    hold = lambda x: torch.cat((x, x[-1:].expand(extra, *x.shape[1:])))  # noqa: E731
    still = lambda x: torch.cat((x, x.new_zeros(extra, *x.shape[1:])))  # noqa: E731
    return TargetSequence(sequence.time, hold(sequence.position), still(sequence.linear_velocity),
                          hold(sequence.rotation), still(sequence.angular_velocity))


def track_together(group: list[Prepared]) -> tuple[Trajectory, float]:
    """Track a group as one batch: the subjects' models stacked, targets padded to the longest
    and concatenated [T,B,...]. Returns the batch's trajectory and its wall time (s)."""
    lead, spec = group[0], group[0].spec
    frames = len(lead.sequence)
    padded = [pad(p.sequence, frames) for p in group]
    join = lambda name: torch.cat([getattr(s, name) for s in padded], dim=1)  # noqa: E731
    sequence = TargetSequence(lead.sequence.time, join("position"), join("linear_velocity"), join("rotation"),
                              join("angular_velocity"))
    model = lead.model if len(group) == 1 else KinematicModel.stack([p.model for p in group])
    start = time.perf_counter()
    with warnings.catch_warnings():  # a gain beyond the stability bound shows in the trial's result
        warnings.simplefilter("ignore")
        tracker = DynamicalIK(model, lead.links, position_gain=spec.position_gain,
                              orientation_gain=spec.orientation_gain, dt=lead.dt, scheme=spec.scheme,
                              backend=spec.backend)
    trajectory = tracker.run(sequence, progress=False, settle=SETTLE)  # each subject at rest in its first frame
    return trajectory, time.perf_counter() - start


def subject_trajectory(trajectory: Trajectory, i: int, p: Prepared) -> Trajectory:
    """Subject i of a batch's trajectory, cut to its own frames, on its own time line: [T_i,1,...];
    the batch's per-step series (step_time ...) cut likewise."""
    frames = len(p.sequence)
    pick = lambda x: x[:frames] if x.dim() == 1 else x[:frames, i:i + 1]  # noqa: E731
    return Trajectory(p.sequence.time, pick(trajectory.base_position), pick(trajectory.base_rotation),
                      pick(trajectory.joint_positions), pick(trajectory.velocity),
                      {name: pick(value) for name, value in trajectory.diagnostics.items()})


def track_group(group: list[Prepared], out: Path, run: str, batch: int, rrd: bool,
                exit_once: tuple[str, str] | None) -> list[dict]:
    """Track a group together and write each trial; if the batch raises, each trial alone."""
    try:
        trajectory, seconds = track_together(group)
    except Exception as exc:
        if len(group) == 1:
            return [write_failure(out, group[0].spec, group[0].fingerprint, run,
                                  f"tracking failed: {type(exc).__name__}: {exc}")]
        return [row for p in group for row in track_group([p], out, run, batch, rrd, exit_once)]
    rows = []
    for i, p in enumerate(group):
        if exit_once is not None and exit_once[0] == p.spec.trial and _first_time(exit_once[1]):
            os._exit(1)  # tests: the worker dies here, its batch half written
        try:
            start = time.perf_counter()
            mine = subject_trajectory(trajectory, i, p)
            mine.diagnostics.update(tracking_errors(p.model, mine, p.sequence, p.links, p.spec.scheme))
            row = trial_row(p, mine)
            row.update(batch=batch, batch_size=len(group), padded_frames=len(group[0].sequence) - len(p.sequence),
                       track_s=seconds / len(group) + time.perf_counter() - start)
            rows.append(write_result(out, p, row, mine, run, rrd))
        except Exception as exc:
            rows.append(write_failure(out, p.spec, p.fingerprint, run, exc))
    return rows


def _first_time(marker: str) -> bool:
    try:
        Path(marker).touch(exist_ok=False)
        return True
    except FileExistsError:
        return False


def trial_row(p: Prepared, trajectory: Trajectory) -> dict:
    """The summary row of a tracked trial (trajectory [T,1,...] with mnte and rmse diagnostics):
    the statistics `torchik track` reports, from statistics_from_s (the spec's transient, or 0 for
    a trial shorter than it), over the steps with a target; status 'failed' with the reason when
    the trial diverged."""
    t, d, spec = trajectory.time, trajectory.diagnostics, p.spec
    row: dict[str, Any] = dict(trial=spec.trial, subject=spec.subject, model=spec.model, status="ok", error=None,
               frames=len(t), duration_s=float(t[-1] - t[0]), rate_hz=1.0 / p.dt,
               qp_fallbacks=int((~d["solved"]).sum()), dropped_targets=int(d["dropped"].sum()),
               step_time_ms=summary(d["step_time"], t, 0.0)["median"] * 1e3)
    stats = tracking_statistics(trajectory, p.sequence, p.recording, p.model, spec.transient)
    row["statistics_from_s"] = stats["statistics_from_s"]
    for name, key in (("mnte", "mnte"), ("rmse", "angular_velocity_rmse")):
        row.update({f"{name}_{k}": _number((stats[key] or {}).get(k)) for k in ("median", "p99", "max")})
    if "joint_error_rad" in stats:
        row.update(joint_error_max=_number(stats["joint_error_rad"]["max"]),
                   joint_error_rms=_number(stats["joint_error_rad"]["rms"]))
    state = torch.cat((trajectory.base_position, trajectory.base_rotation.flatten(-2), trajectory.joint_positions), -1)
    bad = (~torch.isfinite(state)).flatten(1).any(-1).nonzero()
    if len(bad):
        row.update(status="failed", error=f"diverged: non-finite state from t = {float(t[bad[0, 0]] - t[0]):.3f} s")
    elif row["mnte_median"] is not None and row["mnte_median"] > DIVERGED_MNTE:
        row.update(status="failed", error=f"diverged: median MNTE {row['mnte_median']:.3g} from "
                                          f"{row['statistics_from_s']:g} s "
                                          f"(above {DIVERGED_MNTE}: the estimate no longer follows)")
    return row


def _number(value) -> float | None:
    """A float for the summary; None for NaN or missing (JSON and CSV then hold an empty value)."""
    value = None if value is None else float(value)
    return value if value is not None and math.isfinite(value) else None


def write_result(out: Path, p: Prepared, row: dict, trajectory: Trajectory, run: str, rrd: bool) -> dict:
    """Write a tracked trial's folder whole (estimate.npz, result.json, trial.rrd when asked)."""
    with staged(out / "trials" / p.spec.trial) as folder:
        save_trajectory(trajectory, p.model, folder / "estimate.npz")
        if rrd or p.spec.rrd:
            from ..rrd import log_trajectory

            log_trajectory(folder / "trial.rrd", p.model, p.links, trajectory, p.sequence, urdf=model_urdf(p.spec))
        _write_json(folder, p.spec, p.fingerprint, run, row)
    return row


def write_failure(out: Path, spec: TrialSpec, fingerprint: str, run: str, error: BaseException | str) -> dict:
    """Record a failed trial: its folder holds result.json with the error, on one line."""
    message = error if isinstance(error, str) else f"{type(error).__name__}: {error}"
    row = dict.fromkeys(COLUMNS)
    row.update(trial=spec.trial, subject=spec.subject, model=spec.model, status="failed",
               error=" ".join(message.split())[:500])
    with staged(out / "trials" / spec.trial) as folder:
        _write_json(folder, spec, fingerprint, run, row)
    return row


def _write_json(folder: Path, spec: TrialSpec, fingerprint: str, run: str, row: dict) -> None:
    record = dict(row={k: row.get(k) for k in COLUMNS}, fingerprint=fingerprint, run=run, spec=asdict(spec))
    (folder / "result.json").write_text(json.dumps(record, indent=1) + "\n")


class staged:
    """`with staged(folder) as part:` write into `part`; it replaces `folder` when the block
    completes. A worker that dies meanwhile leaves the old folder (or none) and a stray
    `.<name>.*.part` that the next run removes."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.part = folder.with_name(f".{folder.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.part")

    def __enter__(self) -> Path:
        self.part.mkdir(parents=True)
        return self.part

    def __exit__(self, kind, value, traceback) -> None:
        if kind is not None:
            shutil.rmtree(self.part, ignore_errors=True)
            return
        old = self.part.with_name(self.part.name + ".old")
        if self.folder.exists():
            os.rename(self.folder, old)
        os.rename(self.part, self.folder)
        shutil.rmtree(old, ignore_errors=True)


def load_result(out: Path, trial: str) -> dict | None:
    """A trial's stored result.json (row, fingerprint, run, spec), or None when absent or unreadable."""
    try:
        return json.loads((out / "trials" / trial / "result.json").read_text())
    except (OSError, ValueError):
        return None


def model_urdf(spec: TrialSpec):
    """The URDF (text or path) that draws a trial's body in its rerun recording."""
    if spec.model == "icub":
        return icub_urdf_path()
    if spec.model in ("human66", "human48"):
        return human_urdf(int(spec.model[-2:]), spec.subject_model)
    return spec.model

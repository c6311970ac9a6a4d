"""pipelines/track: a recording tracked a chunk of k frames at a time (read from its file, outputs
written as the run goes) gives the trajectory, the report and the files of tracking it in one
chunk, whatever k; with gaps, implausible samples and position targets across chunk boundaries,
and when Ctrl-C stops the run. The states are the same to the bit; the metrics (mnte, rmse, the
position errors) are measured by batched kinematics whose BLAS sums run in an order that depends
on how many samples a call has (k's, or 4096 at most): the same to their rounding, 1e-15."""

import dataclasses
import zipfile

import numpy as np
import pytest
import torch
from test_position_targets import ENDS, with_link_origins
from test_rrd import column, read_rrd

from torchik.io import save_recording
from torchik.io.recording_file import RecordingFile
from torchik.io.trajectory import TrajectoryWriter, save_trajectory
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.settings import TrackerSettings
from torchik.method.state import Trajectory
from torchik.method.tracker import DynamicalIK
from torchik.pipelines.rrd import RrdWriter, log_trajectory
from torchik.pipelines.track import Collected, nominal_dt, track_chunks
from torchik.synthetic.scenarios import scenario

TIMINGS = ("step_time", "kinematics_time", "qp_time")  # seconds measured: never the same twice
POSITION_LINKS = ("Pelvis", *ENDS)


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    """Human48 walking 2 s at 50 Hz with link origins, faults near the chunk boundaries of k = 7 and
    13: a 1 s gap in time, absurd angular velocities, a base that jumps away and back, a missing
    link, a rotation to project. Saved as a file, to be read in chunks."""
    model = load_model("human48")
    rec = with_link_origins(scenario("walking", model, TRACKED_LINKS["human48"], duration=2.0, rate=50.0), model)
    time, w, p, R = rec.time.copy(), rec.angular_velocity.copy(), rec.base_position.copy(), rec.orientation.copy()
    time[60:] += 1.0  # a gap between frames 59 and 60
    w[12:15, 3] = 1e300  # frames 12-14 across k = 13's boundary
    p[27:29] += 5.0  # away at 27-28 (across k = 7's boundary at 28), back at 29
    R[20:23, 5] = np.nan
    R[41, 2] *= 1 + 1e-4  # nearly orthonormal: projected
    rec = dataclasses.replace(rec, time=time, angular_velocity=w, base_position=p, orientation=R)
    return model, rec, save_recording(rec, tmp_path_factory.mktemp("chunks") / "faulty.npz")


def tracked(model, source, chunk, outputs=(), settings=None):
    settings = dataclasses.replace(settings or TrackerSettings(), dt=nominal_dt(source, TrackerSettings()))
    collected = Collected()
    summary, implausible, interrupted = track_chunks(model, source, source.links, settings, [collected, *outputs],
                                                     transient=0.5, position_links=POSITION_LINKS, chunk=chunk)
    return Trajectory.concatenate(collected.parts), summary.report(settings, implausible, interrupted)


def assert_same_run(a, b):
    (ta, ra), (tb, rb) = a, b
    for name in ("time", "base_position", "base_rotation", "joint_positions", "velocity"):
        assert torch.equal(getattr(ta, name), getattr(tb, name)), name
    for name in set(ta.diagnostics) - set(TIMINGS):
        exact = name not in ("mnte", "rmse")  # the tracker's own diagnostics, or the metrics measured after it
        torch.testing.assert_close(ta.diagnostics[name], tb.diagnostics[name], rtol=0 if exact else 1e-12,
                                   atol=0 if exact else 1e-15, equal_nan=True)
    ra, rb = flat(ra), flat(rb)
    assert ra.keys() == rb.keys()
    for key in (k for k in ra if not k.startswith("step_time_ms")):
        assert ra[key] == (pytest.approx(rb[key], rel=1e-12, abs=1e-15) if isinstance(rb[key], float) else rb[key]), key


def flat(report: dict, prefix: str = "") -> dict:
    """{"mnte": {"p99": x}} as {"mnte": ..., "mnte.p99": x}: the report's figures one by one."""
    out = {}
    for key, value in report.items():
        out[prefix + key] = value if not isinstance(value, dict) else None
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
    return out


def test_chunks_of_any_size_track_as_one_chunk(faulty):
    model, rec, path = faulty
    whole = tracked(model, rec, chunk=len(rec.time))
    report = whole[1]
    assert report["implausible_samples"] == 3 + 2 and report["projected_targets"] == 1
    assert len(report["segments"]) == 2 and report["dropped_targets"] > 0 and report["failed_steps"] == 0
    for chunk in (1, 7, 13):
        assert_same_run(tracked(model, RecordingFile(path), chunk), whole)
    assert_same_run(tracked(model, rec, 7), whole)  # a recording in memory, cut in chunks


def test_the_files_written_as_the_run_goes_equal_those_written_whole(faulty, tmp_path):
    model, rec, path = faulty
    links = rec.links
    with TrajectoryWriter(tmp_path / "streamed.npz", model) as out, \
            RrdWriter(tmp_path / "streamed.rrd", model, links, position_links=POSITION_LINKS) as rrd:
        trajectory, _ = tracked(model, RecordingFile(path), 7, outputs=[out, rrd])
        out.commit()
        rrd.commit()
    save_trajectory(trajectory, model, tmp_path / "whole.npz")
    with zipfile.ZipFile(tmp_path / "streamed.npz") as a, zipfile.ZipFile(tmp_path / "whole.npz") as b:
        assert a.namelist() == b.namelist() and all(a.read(name) == b.read(name) for name in a.namelist())
    from torchik.io.targets import recording_targets

    targets = recording_targets(rec, links, POSITION_LINKS)
    log_trajectory(tmp_path / "whole.rrd", model, links, trajectory, targets, position_links=POSITION_LINKS)
    contents = ["/subject/0/errors/mnte", "/subject/0/joints/jRightKnee_roty", "/subject/0/estimate/LeftHand",
                "/subject/0/residual/position/RightFoot"]
    streamed, written = (read_rrd(tmp_path / f"{name}.rrd", contents) for name in ("streamed", "whole"))
    assert len(streamed) == len(written) == len(rec.time)
    for entity, component in [("/subject/0/errors/mnte", "Scalars:scalars"), ("/subject/0/joints/jRightKnee_roty",
                              "Scalars:scalars"), ("/subject/0/estimate/LeftHand", "Transform3D:quaternion"),
                              ("/subject/0/residual/position/RightFoot", "Scalars:scalars")]:
        assert np.array_equal(column(streamed, entity, component), column(written, entity, component), equal_nan=True)


def test_a_run_stopped_by_ctrl_c_keeps_the_same_frames_in_chunks_as_whole(faulty, monkeypatch):
    model, rec, path = faulty
    step, calls = DynamicalIK.step, []

    def interrupted_at_45(self, *args, **kwargs):  # Ctrl-C during the 45th step: in k = 7's 7th chunk
        calls.append(1)
        if len(calls) == 45:
            raise KeyboardInterrupt
        return step(self, *args, **kwargs)

    monkeypatch.setattr(DynamicalIK, "step", interrupted_at_45)
    runs = []
    for source, chunk in ((rec, len(rec.time)), (RecordingFile(path), 7), (RecordingFile(path), 11)):
        calls.clear()
        runs.append(tracked(model, source, chunk))
    assert runs[0][1]["interrupted"] and runs[0][1]["frames"] == 44
    for run in runs[1:]:
        assert_same_run(run, runs[0])

"""cohort: a generated study (40 trials, 10 subjects of different heights, Human66 and Human48) on a
real two-worker Dask cluster. The summary equals tracking each trial alone; padding changes no
trial; bad trials fail alone; a worker killed mid-batch and an interrupted run lose nothing and
a re-run tracks only what is missing; manifests read alike from CSV and TOML, and bad ones exit 2."""

import shutil
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from torchik.cli import main
from torchik.io import load_recording
from torchik.method.models import TRACKED_LINKS, HumanSubject, load_model
from torchik.method.settings import TrackerSettings
from torchik.pipelines.cohort import read_manifest, run_cohort, write_synthetic_cohort
from torchik.pipelines.cohort.plan import plan_batches
from torchik.pipelines.cohort.run import EXIT_ONCE_ENV
from torchik.pipelines.cohort.synthetic import synthetic_trials
from torchik.pipelines.cohort.trial import load_result
from torchik.pipelines.track import SETTLE, track_recording

pytestmark = pytest.mark.usefixtures("one_thread")
GOOD = 40
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def no_allocator_tuning(monkeypatch):
    """`main` without the command line's allocator tuning, which would stay with pytest's process."""
    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The generated cohort (50 Hz, 1 to 2 s a trial) and its TOML manifest."""
    return write_synthetic_cohort(tmp_path_factory.mktemp("study"))


@pytest.fixture(scope="module")
def client():
    """A LocalCluster of two single-threaded worker processes, for the whole module."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as cluster, Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def with_bad_trials(study):
    """The study plus a corrupt file, a file deleted after the manifest was read, and a trial whose
    gain (K dt = 2.2) is beyond the stability bound: the manifest's specs, last three bad."""
    folder = study.parent
    (folder / "corrupt.npz").write_bytes(b"this is not a zip archive")
    shutil.copy(folder / "s01" / "s01_t1.npz", folder / "gone.npz")
    extra = """
[[trials]]
trial = "corrupt"
subject = "s01"
recording = "corrupt.npz"
[[trials]]
trial = "gone"
subject = "s02"
recording = "gone.npz"
[[trials]]
trial = "wild"
subject = "s01"
recording = "s01/s01_t3.npz"
gain = 110.0
"""
    manifest = folder / "with_bad.toml"
    manifest.write_text(study.read_text() + extra)
    specs = read_manifest(manifest)
    (folder / "gone.npz").unlink()
    return specs


@pytest.fixture(scope="module")
def full_run(with_bad_trials, client, tmp_path_factory):
    """The study and its bad trials tracked once on the module's cluster: (results folder, CohortRun)."""
    out = tmp_path_factory.mktemp("results")
    return out, run_cohort(with_bad_trials, out, client=client)


def _alone(spec, backend=None):
    """The trial as `torchik track` tracks it: its subject's model, its recording, the same options."""
    subject = HumanSubject(height=spec.height, mass=spec.mass)
    model = load_model(spec.model, subject)
    settings = TrackerSettings(position_gain=spec.position_gain, orientation_gain=spec.orientation_gain,
                               scheme=spec.scheme, backend=backend or spec.backend)
    return track_recording(model, load_recording(spec.recording), TRACKED_LINKS[spec.model], settings,
                           transient=spec.transient, settle=SETTLE)


def test_the_summary_equals_tracking_each_trial_alone(full_run, with_bad_trials):
    """Every good trial's summary row holds the metrics `torchik track` reports for it alone (to
    1e-8 relative: alone, one subject's QP goes to PIQP, whose tolerance is 1e-9)."""
    out, result = full_run
    rows = {r["trial"]: r for r in result.rows}
    assert len(rows) == GOOD + 3 and result.tracked == GOOD + 3 and result.skipped == 0
    assert max(result.batch_sizes) > 1  # batched, not one by one
    for spec in with_bad_trials[:GOOD]:
        row = rows[spec.trial]
        _, report = _alone(spec)
        assert row["status"] == "ok" and row["frames"] == report["frames"], spec.trial
        assert (row["qp_fallbacks"], row["dropped_targets"]) == (report["qp_fallbacks"], report["dropped_targets"])
        for column, value in (("mnte_median", report["mnte"]["median"]), ("mnte_max", report["mnte"]["max"]),
                              ("rmse_median", report["angular_velocity_rmse"]["median"]),
                              ("rmse_p99", report["angular_velocity_rmse"]["p99"]),
                              ("joint_error_max", report["joint_error_rad"]["max"])):
            assert row[column] == pytest.approx(value, rel=1e-8, abs=1e-15), (spec.trial, column)
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [r["trial"] for r in table] == [s.trial for s in with_bad_trials]


def test_padding_and_batching_change_no_trial(full_run, with_bad_trials):
    """A trial padded to its batch's longest and tracked among other subjects has the estimate it
    has alone with the same QP solver, to rounding (1e-12 rad)."""
    out, result = full_run
    padded = [s for s in with_bad_trials[:GOOD] if (load_result(out, s.trial)["row"]["padded_frames"] or 0) > 0]
    assert len(padded) >= 10
    for spec in padded[:6]:
        trajectory, _ = _alone(spec, backend="batched")
        estimate = np.load(out / "trials" / spec.trial / "estimate.npz")
        assert len(estimate["time"]) == len(trajectory.time)
        assert np.abs(estimate["joint_positions"] - trajectory.joint_positions[:, 0].numpy()).max() < 1e-12
        assert np.abs(estimate["base_rotation"] - trajectory.base_rotation[:, 0].numpy()).max() < 1e-12


def test_a_corrupt_a_vanished_and_a_diverging_trial_fail_alone(full_run):
    """Each bad trial is recorded as failed with its reason; every other trial of the cohort is ok."""
    out, result = full_run
    rows = {r["trial"]: r for r in result.rows}
    assert rows["corrupt"]["status"] == "failed" and "not a torchik recording" in rows["corrupt"]["error"]
    assert rows["gone"]["status"] == "failed" and "no such file" in rows["gone"]["error"]
    assert rows["wild"]["status"] == "failed" and "diverged" in rows["wild"]["error"]
    assert result.failed == 3
    assert sum(r["status"] == "ok" for r in result.rows) == GOOD
    # the corrupt file shared a batch with good trials, which completed
    assert any(r["batch_size"] and r["batch_size"] > 1 and r["model"] == "human66" for r in result.rows)
    assert (out / "summary.csv").read_text().count("\n") == GOOD + 4


def test_a_worker_killed_mid_batch_loses_no_trial(study, full_run, client, tmp_path, monkeypatch):
    """A worker process that dies half-way through writing a batch: Dask runs the batch again
    elsewhere, the trials it had written are kept (not tracked again), and every trial completes
    with the results of the undisturbed run (to 1e-6 rad: a trial tracked alone, as the victim
    is on its second attempt, gets PIQP, whose tolerance is 1e-9)."""
    specs = read_manifest(study)[:16]
    batches = plan_batches(specs, [s.fingerprint() for s in specs], 4)
    victim = batches[1].trials[-1]  # written last in its batch: its batch-mates are on disk when it dies
    marker = tmp_path / "died"
    monkeypatch.setenv(EXIT_ONCE_ENV, f"{victim.trial}:{marker}")
    out = tmp_path / "out"
    result = run_cohort(specs, out, client=client, batch_size=4)
    assert marker.exists()  # the worker did die
    assert [r["status"] for r in result.rows] == ["ok"] * 16 and result.tracked == 16
    died_at = marker.stat().st_mtime_ns
    for mate in batches[1].trials[:-1]:
        assert (out / "trials" / mate.trial / "result.json").stat().st_mtime_ns <= died_at, mate.trial
    for spec in specs:
        mine = np.load(out / "trials" / spec.trial / "estimate.npz")["joint_positions"]
        before = np.load(full_run[0] / "trials" / spec.trial / "estimate.npz")["joint_positions"]
        assert np.abs(mine - before).max() < 1e-6, spec.trial
    client.wait_for_workers(2, timeout=60)  # the nanny has restarted the dead one


def test_a_rerun_after_interruption_tracks_only_the_missing_trials(study, client, tmp_path):
    """Ctrl-C after the first batch: the trials finished are on disk and in the summary; the
    same run again tracks exactly the others and leaves the finished ones untouched; a third
    run tracks nothing."""
    specs = read_manifest(study)
    out = tmp_path / "out"

    def stop(rows):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_cohort(specs, out, client=client, batch_size=5, on_batch=stop)
    summary = (out / "summary.csv").read_text()  # written as it stopped: what had finished then
    assert summary.count(",ok,") >= 5 and summary.count(",ok,") + summary.count(",missing,") == len(specs)
    # batches already running when it stopped finish on their workers (cancelled, they still count)
    while any(client.run(lambda dask_worker: dask_worker.state.executing_count).values()):
        time.sleep(0.1)
    done = {p.parent.name: p.stat().st_mtime_ns for p in (out / "trials").glob("*/result.json")}
    assert 5 <= len(done) < len(specs)
    again = run_cohort(specs, out, client=client, batch_size=5)
    assert (again.skipped, again.tracked) == (len(done), len(specs) - len(done))
    assert all((out / "trials" / t / "result.json").stat().st_mtime_ns == m for t, m in done.items())
    assert [r["status"] for r in again.rows] == ["ok"] * len(specs)
    assert run_cohort(specs, out, client=client).tracked == 0


def test_the_command_tracks_a_manifest_and_says_what_failed(study, client, tmp_path, capsys):
    """`torchik cohort` on a scheduler by address: the summary (CSV and Parquet) has a row per
    trial, the failed trial is named with its error, and the exit code is 1. A trial through a
    link map, one with a URDF model and one with a rerun recording are tracked as well."""
    folder = study.parent
    manifest = folder / "small.csv"
    urdf = REPO / "models" / "human48.urdf"
    manifest.write_text("trial,subject,recording,model,height,map,rrd,transient\n"
                        "a,s01,s01/s01_t1.npz,human66,1.5,xsens_to_human,,0.5\n"
                        f"b,s01,s01/s01_t2.npz,{urdf},,,,0.5\n"
                        "c,s02,s02/s02_t1.npz,human66,1.55,,true,0.5\nbroken,s02,corrupt.npz,human66,1.55,,,0.5\n")
    (folder / "corrupt.npz").write_bytes(b"garbage")
    out = tmp_path / "out"
    code = main(["cohort", str(manifest), "--out", str(out), "--scheduler", client.scheduler.address])
    printed = capsys.readouterr().out
    assert code == 1
    assert "tracked 4 trials" in printed and "trials/min" in printed and "failed: broken: RecordingError" in printed
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [(r["trial"], r["status"]) for r in table] == [("a", "ok"), ("b", "ok"), ("c", "ok"), ("broken", "failed")]
    assert (out / "trials" / "c" / "trial.rrd").stat().st_size > 0 and not (out / "trials" / "a" / "trial.rrd").exists()
    assert main(["cohort", str(manifest), "--out", str(out), "--scheduler", client.scheduler.address]) == 1
    assert "4 trials, 4 finished before" in capsys.readouterr().out


def test_without_a_client_a_local_cluster_is_started_and_closed(study, tmp_path):
    """The default: a LocalCluster of the workers asked for (forked from a fork server that has
    torchik imported), started for the run and closed after."""
    from distributed.deploy.spec import SpecCluster

    clusters = len(SpecCluster._instances)
    result = run_cohort(read_manifest(study)[:2], tmp_path / "out", workers=1)
    assert result.workers == 1 and [r["status"] for r in result.rows] == ["ok", "ok"]
    assert len([c for c in SpecCluster._instances if c.status.name != "closed"]) == clusters


def test_csv_and_toml_manifests_give_the_same_trials(study):
    """A CSV with every column on every row and the TOML with [defaults] and [subjects] read alike."""
    lines = ["trial,subject,recording,model,height,mass,transient"]
    lines += [f"{r['trial']},{r['subject']},{r['subject']}/{r['trial']}.npz,{r['model']},{r['height']},{r['mass']},0.5"
              for r in synthetic_trials()]
    csv = study.parent / "same.csv"
    csv.write_text("\n".join(lines) + "\n")
    assert read_manifest(csv) == read_manifest(study)


def test_batches_hold_one_model_and_similar_lengths(study):
    """A batch never mixes models; a group's batches differ in size by one at most and are cut
    from the trials sorted by length."""
    specs = read_manifest(study)
    batches = plan_batches(specs, [""] * len(specs), 7)
    assert sum(len(b) for b in batches) == len(specs) and max(len(b) for b in batches) <= 7
    for model in ("human66", "human48"):
        mine = [b for b in batches if b.trials[0].model == model]
        assert all({s.model for s in b.trials} == {model} for b in mine)
        assert max(len(b) for b in mine) - min(len(b) for b in mine) <= 1
        frames = sorted((b.frames for b in mine), key=lambda f: -f[0])
        assert all(min(a) >= max(b) for a, b in zip(frames, frames[1:]))


@pytest.mark.parametrize("header, row, message", [
    ("trial,subject,model", "a,s01,human66", "missing column recording"),
    ("trial,subject,recording,model", "a,s01,s01/s01_t1.npz,human99", "unknown model 'human99'"),
    ("trial,subject,recording,model", "a,s01,s01/nothing.npz,human66", "recording s01/nothing.npz: no such file"),
    ("trial,subject,recording,heigth", "a,s01,s01/s01_t1.npz,1.7", "unknown column heigth"),
    ("trial,subject,recording,model,height", "a,s01,s01/s01_t1.npz,icub,1.7", "generate a human model"),
    ("trial,subject,recording,height", "a,s01,s01/s01_t1.npz,170", "give metres"),
    ("trial,subject,recording,gain", "a,s01,s01/s01_t1.npz,fast", "gain: could not convert"),
])
def test_a_bad_manifest_exits_2_with_one_line_before_any_work(study, tmp_path, capsys, header, row, message):
    """Manifest errors are found when it is read, before a cluster starts: exit 2, one line."""
    manifest = study.parent / "bad.csv"
    manifest.write_text(f"{header}\n{row}\n")
    assert main(["cohort", str(manifest), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("torchik cohort: ") and message in err, err
    assert not (tmp_path / "out").exists()


def test_trials_with_the_same_id_are_refused(study, capsys, tmp_path):
    """Two trials with one id would share a results folder: refused, naming the row."""
    manifest = study.parent / "twice.toml"
    manifest.write_text('[[trials]]\ntrial = "a"\nsubject = "s"\nrecording = "s01/s01_t1.npz"\n' * 2)
    assert main(["cohort", str(manifest), "--out", str(tmp_path)]) == 2
    assert "trials[1] (a): trial id 'a' is used twice" in capsys.readouterr().err



def test_a_short_trials_row_holds_the_whole_trial_from_its_first_frames_posture(tmp_path):
    """A 1.2 s trial, shorter than its 2 s transient: tracked from rest in its first frame's
    posture, its row's statistics are the whole trial's (statistics_from_s 0) with no transient
    from the zero posture in them (its MNTE of 0.2 at frame 0 was the row's max)."""
    from torchik.io import save_recording
    from torchik.pipelines.cohort.manifest import TrialSpec
    from torchik.pipelines.cohort.trial import prepare, track_together, trial_row
    from torchik.pipelines.evaluation import tracking_errors
    from torchik.synthetic.scenarios import scenario

    path = save_recording(scenario("walking", load_model("human48"), TRACKED_LINKS["human48"], duration=1.2),
                          tmp_path / "short.npz")
    p = prepare(TrialSpec(trial="short", subject="s", recording=str(path), model="human48"))
    trajectory, _ = track_together([p])
    trajectory.diagnostics.update(tracking_errors(p.model, trajectory, p.sequence, p.links, p.spec.scheme))
    row = trial_row(p, trajectory)
    assert row["status"] == "ok" and row["mnte_max"] < 1e-3 and row["mnte_p99"] < 1e-3
    assert row["statistics_from_s"] == 0.0

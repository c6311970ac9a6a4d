"""cli/track on faulty inputs: a run that exits 0 holds no NaN. Gaps start new segments, absurd
samples are dropped, failed steps beyond --max-failed exit 1 writing nothing, and numeric options
and devices are checked before any work (exit 2, one line)."""

import dataclasses
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from torchik.io.recording import save_recording
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.synthetic.scenarios import scenario


@pytest.fixture(scope="module")
def walk():
    return scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=3.0, rate=100.0)


def tracked(cli, tmp_path, recording, *options):
    """Track `recording` (saved in tmp_path); (exit code, stderr, report or None, trajectory or None)."""
    source, out, report = tmp_path / "in.npz", tmp_path / "out.npz", tmp_path / "report.json"
    save_recording(recording, source)
    code, _, err = cli("track", "--input", source, "--out", out, "--report", report, "--quiet", *options)
    return (code, err, json.loads(report.read_text()) if report.exists() else None,
            dict(np.load(out)) if code == 0 else None)


def assert_finite(trajectory: dict) -> None:
    for name in ("base_position", "base_rotation", "joint_positions", "velocity"):
        assert np.isfinite(trajectory[name]).all(), name


def test_a_ten_second_gap_starts_a_new_segment_and_the_outputs_are_finite(cli, tmp_path, walk):
    gapped = dataclasses.replace(walk, time=np.where(walk.time > 1.5, walk.time + 10.0, walk.time))
    code, err, report, trajectory = tracked(cli, tmp_path, gapped)
    assert code == 0, err
    assert_finite(trajectory)
    assert report["segments"] == [[0.0, 1.5], [pytest.approx(11.51), pytest.approx(13.0)]]
    assert report["qp_fallbacks"] == 0 and report["failed_steps"] == 0


def test_a_recording_with_nothing_measured_is_refused_in_one_line(cli, tmp_path, walk):
    blind = dataclasses.replace(walk, orientation=np.full_like(walk.orientation, np.nan),
                                angular_velocity=np.full_like(walk.angular_velocity, np.nan))
    code, err, report, trajectory = tracked(cli, tmp_path, blind)
    assert code == 2 and "nothing to track" in err and len(err.strip().splitlines()) == 1, err
    assert report is None and not (tmp_path / "out.npz").exists()


@pytest.mark.parametrize("field, index", [("angular_velocity", (slice(100, 110), 3)), ("base_position", slice(100, 110))])
def test_absurd_finite_samples_are_dropped_as_missing_and_counted(cli, tmp_path, walk, field, index):
    values = getattr(walk, field).copy()
    values[index] = 1e300
    code, err, report, trajectory = tracked(cli, tmp_path, dataclasses.replace(walk, **{field: values}))
    assert code == 0, err
    assert_finite(trajectory)
    assert report["implausible_samples"] == 10 and report["failed_steps"] == 0
    assert np.abs(trajectory["base_position"]).max() < 10.0  # not followed to 1e296 m


def test_the_per_step_metrics_are_over_the_targets_present_and_nan_only_where_none_is(cli, tmp_path, walk):
    """Ten absurd samples of one link's angular velocity, dropped: the estimate's per-step MNTE and
    RMSE at those steps are the other 22 targets' (finite, at the run's level). Three frames with no
    orientation target at all are the only NaN ones, and the report counts them."""
    w, R = walk.angular_velocity.copy(), walk.orientation.copy()
    w[100:110, 3] = 1e300
    R[200:203] = np.nan  # every link missing (the base position is still there)
    code, err, report, trajectory = tracked(cli, tmp_path, dataclasses.replace(walk, angular_velocity=w, orientation=R))
    assert code == 0, err
    assert_finite(trajectory)
    for name in ("mnte", "rmse"):
        assert np.isnan(trajectory[name]).ravel().nonzero()[0].tolist() == [200, 201, 202], name
    assert trajectory["mnte"][100:110].max() < 1e-6 and trajectory["rmse"][100:110].max() < 1e-2
    assert report["steps_without_targets"] == 3 and report["implausible_samples"] == 10


def test_steps_failed_beyond_max_failed_exit_1_and_leave_existing_outputs(cli, tmp_path, walk):
    values = walk.angular_velocity.copy()
    values[100:110, 3] = 1e300  # let through by the bound below: the tracker's invariant catches it
    (tmp_path / "out.npz").write_bytes(b"before")
    code, err, _, _ = tracked(cli, tmp_path, dataclasses.replace(walk, angular_velocity=values),
                              "--max-angular-velocity", "1e308", "--force")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert (tmp_path / "out.npz").read_bytes() == b"before" and not (tmp_path / "report.json").exists()


@pytest.mark.parametrize("options", [
    ("--gain", "-5"), ("--gain", "nan"), ("--gain", "300"), ("--position-gain", "0"), ("--orientation-gain", "inf"),
    ("--rate", "nan"), ("--duration", "nan"), ("--duration", "inf"), ("--rate", "-100"), ("--device", "mps"),
    ("--device", "tpu"), ("--max-gap", "nan"), ("--max-gap", "0.5"), ("--max-failed", "2"), ("--max-angular-velocity", "0"),
])
def test_bad_numeric_options_and_devices_exit_2_with_one_line_before_any_work(cli, tmp_path, options):
    code, out, err = cli("track", "--duration", "0.2", "--quiet", "--report", tmp_path / "r.json", *options)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert options[0].lstrip("-") in err  # the option as the user knows it, not the library's setting name
    assert not (tmp_path / "r.json").exists()


def test_a_run_on_clean_data_reports_one_segment_and_no_failure(cli, tmp_path, walk):
    code, err, report, trajectory = tracked(cli, tmp_path, walk)
    assert code == 0, err
    assert report["segments"] == [[0.0, 3.0]] and report["failed_steps"] == 0 and report["implausible_samples"] == 0


@pytest.mark.parametrize("make", ["fifo", "symlink", "device", "input"])
def test_outputs_that_are_special_files_symlinks_or_the_input_are_refused_untouched(cli, tmp_path, walk, make):
    source = tmp_path / "in.npz"
    save_recording(walk, source)
    if make == "fifo":
        output = tmp_path / "pipe"
        os.mkfifo(output)
    elif make == "symlink":
        output = tmp_path / "link.npz"
        output.symlink_to(source)
    elif make == "device":
        output = Path("/dev/null")
    else:
        output = source
    before = source.read_bytes()
    code, _, err = cli("track", "--input", source, "--out", output, "--force", "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert source.read_bytes() == before
    assert output.is_symlink() if make == "symlink" else output.exists()
    if make == "fifo":
        assert stat.S_ISFIFO(output.lstat().st_mode)


def test_a_report_on_standard_output_is_the_json_alone(cli, tmp_path, walk):
    source = tmp_path / "in.npz"
    save_recording(walk, source)
    code, out, err = cli("track", "--input", source, "--report", "-")
    assert code == 0, err
    assert json.loads(out)["frames"] == len(walk.time)


def test_sigterm_keeps_the_frames_done_exits_143_and_leaves_no_part_file(tmp_path):
    out = tmp_path / "out.npz"
    command = [sys.executable, "-m", "torchik", "track", "--scenario", "walking", "--duration", "600", "--out", out]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(0.5)
    deadline = time.monotonic() + 60
    while "tracking" not in _peek(process) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)  # until the scenario is built and the tracking has begun
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 143, err
    assert "terminated" in err.strip().splitlines()[-1]
    frames = np.load(out)["time"]
    assert 0 < len(frames) < 60000 and np.isfinite(np.load(out)["base_rotation"]).all()
    assert not list(tmp_path.glob(".*.part"))


def _peek(process) -> str:
    """What the process wrote to stderr so far, without waiting (the progress bar appears after a second)."""
    import select

    ready, _, _ = select.select([process.stderr], [], [], 0)
    return os.read(process.stderr.fileno(), 65536).decode(errors="replace") if ready else ""


@pytest.mark.parametrize("args", [
    ("retarget", "--rate", "nan"), ("retarget", "--gain", "-1"), ("retarget", "--max-rate", "inf"),
    ("experiment", "--duration", "inf"), ("experiment", "--rate", "0"), ("experiment", "--tolerance", "nan"),
    ("diagnose", "--gain", "nan"), ("models", "--height", "-1.7"), ("bench", "--seconds", "nan"),
])
def test_every_commands_numeric_options_are_finite_and_positive_or_exit_2(cli, args):
    code, _, err = cli(*args)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "expected a positive, finite number" in err, err

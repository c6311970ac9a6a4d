"""cli: `torchik models` lists the models; bad input exits 2 with one line saying why."""

import subprocess
import sys


def run(*args):
    return subprocess.run([sys.executable, "-m", "torchik.cli", *args], capture_output=True, text=True, timeout=120)


def test_models_lists_the_three_models():
    result = run("models")
    assert result.returncode == 0, result.stderr
    assert "Human66: 66 DoF" in result.stdout and "Human48: 48 DoF" in result.stdout
    assert "iCub: 32 DoF" in result.stdout and "18 coupled linear limits" in result.stdout


def test_help_has_examples():
    result = run("models", "--help")
    assert result.returncode == 0 and "examples:" in result.stdout


def test_write_generates_urdfs_for_a_subject(tmp_path):
    result = run("models", "--write", str(tmp_path), "--height", "1.9", "--segment", "RightHand=0.2")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "human66.urdf").is_file() and (tmp_path / "human48.urdf").is_file()


def test_bad_input_exits_2_with_one_line():
    result = run("models", "--height", "175")
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "give metres" in result.stderr
    assert "Traceback" not in result.stderr
    assert run("models", "--links", "robot").returncode == 2  # argparse's own check


def test_convert_and_info_on_an_mvnx_file(tmp_path):
    from test_mvnx import mvnx_text

    source = tmp_path / "spin.mvnx"
    source.write_text(mvnx_text(30))
    out = tmp_path / "spin.npz"
    result = run("convert", str(source), str(out))
    assert result.returncode == 0, result.stderr
    assert run("convert", str(source), str(out)).returncode == 2  # exists: needs --force
    assert run("convert", str(source), str(out), "--force").returncode == 0
    info = run("info", str(out))
    assert info.returncode == 0 and "30 frames, 100.00 Hz" in info.stdout and "Pelvis, Head" in info.stdout
    bad = run("info", str(tmp_path / "walk.xyz"))
    assert bad.returncode == 2 and "unsupported format '.xyz'" in bad.stderr and "Traceback" not in bad.stderr


def test_track_a_scenario_end_to_end_with_report_and_trajectory(tmp_path):
    import json

    import numpy as np

    report, out = tmp_path / "walk.json", tmp_path / "walk.npz"
    result = run("track", "--scenario", "walking", "--model", "human48", "--duration", "3", "--report", str(report), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "MNTE after 2 s" in result.stdout
    data = json.loads(report.read_text())
    assert data["frames"] == 301 and data["mnte"]["p99"] < 1e-6 and data["qp_fallbacks"] == 0
    assert data["joint_error_rad"]["max"] < 1e-3
    trajectory = np.load(out)
    assert trajectory["joint_positions"].shape == (301, 48) and len(trajectory["joint_names"]) == 48
    again = run("track", "--scenario", "walking", "--model", "human48", "--duration", "3", "--report", str(report))
    assert again.returncode == 2 and "exists; add --force" in again.stderr


def test_track_a_recording_file_and_refuse_bad_input(tmp_path):
    from torchik.io import save_recording
    from torchik.models import TRACKED_LINKS, load_model
    from torchik.scenarios import scenario

    path = save_recording(scenario("tpose", load_model("icub"), TRACKED_LINKS["icub"], duration=1.0), tmp_path / "t.npz")
    result = run("track", "--input", str(path), "--model", "icub", "--quiet")
    assert result.returncode == 0 and result.stdout == ""
    wrong = run("track", "--input", str(path), "--model", "human66")
    assert wrong.returncode == 2 and "the recording has no" in wrong.stderr and "Traceback" not in wrong.stderr
    assert run("track", "--scenario", "dancing").returncode == 2
    assert run("track", "--model", "robot").returncode == 2


def test_track_through_a_map_with_calibration():
    from pathlib import Path

    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
    if not (shared / "HC002D02.c3d").is_file():
        import pytest

        pytest.skip("../shared/data absent")
    result = run("track", "--input", str(shared / "HC002D25.c3d"), "--map", "plugin_gait_to_human",
                 "--calibration", str(shared / "HC002D02.c3d"), "--model", "human48")
    assert result.returncode == 0, result.stderr
    assert "through map 'plug-in gait to human'" in result.stdout
    missing = run("track", "--input", str(shared / "HC002D25.c3d"), "--map", "xsens_to_human", "--model", "human48")
    assert missing.returncode == 2 and "lacks" in missing.stderr

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

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

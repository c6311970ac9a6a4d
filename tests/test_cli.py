"""cli: every sub-command's --help has examples; the README's main command works end to end; bad
input exits 2 with one line saying what is wrong; an interrupted run leaves valid, shorter outputs."""

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_file, skip_without_shared

from torchik.cli import build_parser

REPO = Path(__file__).resolve().parents[1]


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "torchik", *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd)


def test_models_lists_the_three_models():
    result = run("models")
    assert result.returncode == 0, result.stderr
    assert "Human66: 66 DoF" in result.stdout and "Human48: 48 DoF" in result.stdout
    assert "iCub: 32 DoF" in result.stdout and "18 coupled linear limits" in result.stdout


def test_every_sub_command_has_help_with_examples(cli):
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert {"track", "models", "info", "convert", "bench"} <= set(sub.choices)
    for command in [None, *sub.choices]:  # whatever sub-commands the parser has, as they land
        code, out, _ = cli(*([command] if command else []), "--help")
        assert code == 0 and out.startswith(f"usage: torchik {command or ''}".rstrip()), command
        assert "examples:" in out and "\n  torchik " in out.split("examples:")[1], command


def test_write_generates_urdfs_for_a_subject_and_keeps_existing_ones(tmp_path, cli):
    result = run("models", "--write", str(tmp_path), "--height", "1.9", "--segment", "RightHand=0.2")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "human66.urdf").is_file() and (tmp_path / "human48.urdf").is_file()
    written = (tmp_path / "human66.urdf").read_text()
    code, _, err = cli("models", "--write", tmp_path)
    assert code == 2 and "human48.urdf exist; add --force" in err and (tmp_path / "human66.urdf").read_text() == written
    assert cli("models", "--write", tmp_path, "--force")[0] == 0
    assert (tmp_path / "human66.urdf").read_text() != written  # subject 1 is shorter than 1.9 m


def test_the_command_exits_without_teardown_after_its_exit_handlers_and_output():
    """`torchik` ends by os._exit (torch's teardown costs half a second): exit handlers still run,
    what was printed arrives, the exit code is main's, and a thread still working is waited for."""
    script = ("import atexit, sys, threading, time\n"
              "atexit.register(lambda: print('handler ran', flush=True))\n"
              "if sys.argv[1] == 'thread':\n"
              "    threading.Thread(target=lambda: (time.sleep(0.5), print('thread done', flush=True))).start()\n"
              "sys.argv = ['torchik', *sys.argv[2:]]\n"
              "from torchik.cli import command\n"
              "command()\n")
    for thread in ("none", "thread"):
        result = subprocess.run([sys.executable, "-c", script, thread, "models"], capture_output=True, text=True,
                                timeout=120)
        assert result.returncode == 0, result.stderr
        assert "Human48: 48 DoF" in result.stdout and result.stdout.rstrip().endswith("handler ran")
        assert ("thread done" in result.stdout) == (thread == "thread")
    result = subprocess.run([sys.executable, "-c", script, "none", "models", "--height", "175"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2 and "give metres" in result.stderr and "handler ran" in result.stdout


def test_bad_input_exits_2_with_one_line():
    result = run("models", "--height", "175")
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "give metres" in result.stderr
    assert "Traceback" not in result.stderr
    assert run("models", "--links", "robot").returncode == 2  # argparse's own check


def test_convert_and_info_on_an_mvnx_file(tmp_path, cli):
    from test_mvnx import mvnx_text

    source = tmp_path / "spin.mvnx"
    source.write_text(mvnx_text(30))
    out = tmp_path / "spin.npz"
    code, _, err = cli("convert", source, out)
    assert code == 0, err
    assert cli("convert", source, out)[0] == 2  # exists: needs --force
    assert cli("convert", source, out, "--force")[0] == 0
    code, stdout, _ = cli("info", out)
    assert code == 0 and "30 frames, 100.00 Hz" in stdout and "Pelvis, Head" in stdout
    code, _, err = cli("info", tmp_path / "walk.xyz")
    assert code == 2 and "unsupported format '.xyz'" in err


def test_track_a_scenario_end_to_end_with_report_and_trajectory(tmp_path, cli):
    report, out = tmp_path / "walk.json", tmp_path / "walk.npz"
    code, stdout, err = cli("track", "--scenario", "walking", "--model", "human48", "--duration", "3",
                            "--report", report, "--out", out)
    assert code == 0, err
    assert "MNTE after 2 s" in stdout
    data = json.loads(report.read_text())
    assert data["statistics_from_s"] == 2.0
    assert data["frames"] == 301 and data["mnte"]["p99"] < 1e-6 and data["qp_fallbacks"] == 0
    assert data["joint_error_rad"]["max"] < 1e-3
    trajectory = np.load(out)
    assert trajectory["joint_positions"].shape == (301, 48) and len(trajectory["joint_names"]) == 48
    code, _, err = cli("track", "--scenario", "walking", "--model", "human48", "--duration", "3", "--report", report)
    assert code == 2 and "exists; add --force" in err


def test_track_with_contacts_com_and_posture_reports_each_tasks_error(tmp_path, cli):
    """--contacts auto finds the feet's stance in a first run and holds them there: each foot's slide
    per phase before and after in the report (after no more than before), the centre of mass' offset
    and the posture's distance beside, and the rerun recording written with them."""
    report = tmp_path / "walk.json"
    code, out, err = cli("track", "--scenario", "walking", "--model", "human48", "--duration", "4", "--contacts", "auto",
                         "--com", "0.05", "--posture", "1e-3", "--report", str(report), "--rrd", str(tmp_path / "w.rrd"),
                         "--quiet")
    assert code == 0, err
    tasks = json.loads(report.read_text())["tasks"]
    assert {"contact RightFoot", "contact LeftFoot", "centre of mass over the feet", "posture"} == set(tasks)
    for foot in ("RightFoot", "LeftFoot"):
        before, after = tasks[f"contact {foot}"]["slide_before"], tasks[f"contact {foot}"]["slide_after"]
        assert before["phases"] == after["phases"]
        if after["phases"]:
            assert after["max_mm"] <= before["max_mm"]
    assert tasks["centre of mass over the feet"]["median_offset_m"] < 0.5 and tasks["posture"]["median_rms_rad"] < 1.0
    assert (tmp_path / "w.rrd").stat().st_size > 0


def test_track_compile_replays_the_step_and_reports_what_the_eager_step_reports(tmp_path, cli, monkeypatch):
    import torchik.method.captured as captured

    monkeypatch.setattr(captured, "capture", lambda fn, inputs: fn)  # its logic; test_captured compiles
    reports = {}
    for flags in ((), ("--compile",)):
        path = tmp_path / f"walk{len(flags)}.json"
        code, _, err = cli("track", "--scenario", "walking", "--model", "human48", "--duration", "1", "--report", path,
                           "--quiet", *flags)
        assert code == 0, err
        reports[flags] = json.loads(path.read_text())
    eager, replayed = reports[()], reports[("--compile",)]
    assert replayed["mnte"] == pytest.approx(eager["mnte"], rel=1e-6, abs=1e-15) and replayed["frames"] == eager["frames"]
    assert replayed["compiled_steps"] == replayed["frames"] - 2 and "compiled_steps" not in eager


def test_track_a_recording_file_and_refuse_bad_input(tmp_path, cli):
    from torchik.io import save_recording
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.synthetic.scenarios import scenario

    path = save_recording(scenario("tpose", load_model("icub"), TRACKED_LINKS["icub"], duration=1.0), tmp_path / "t.npz")
    assert cli("track", "--input", path, "--model", "icub", "--quiet") == (0, "", "")
    code, _, err = cli("track", "--input", path, "--model", "human66")  # iCub's links: no map makes them human
    assert code == 2 and "no built-in map fits" in err and "the closest" in err


@pytest.mark.parametrize("session", ["written", pytest.param("shared", marks=skip_without_shared)])
def test_track_through_a_map_with_calibration(cli, session, request):
    """A Plug-in Gait walk and its static trial: the session the tests write (conftest's pig_session)
    or the real HC002 one of ../shared/data."""
    if session == "written":
        static, walk = request.getfixturevalue("pig_session").static, request.getfixturevalue("pig_session").walk
    else:
        static, walk = shared_file("c3d/HC002D02.c3d"), shared_file("c3d/HC002D25.c3d")
    code, stdout, err = cli("track", "--input", walk, "--map", "plugin_gait_to_human", "--calibration", static,
                            "--model", "human48")
    assert code == 0, err
    assert "through map 'plug-in gait to human'" in stdout
    code, _, err = cli("track", "--input", walk, "--map", "xsens_to_human", "--model", "human48")
    assert code == 2 and "lacks" in err


def test_track_a_lower_body_trial_leaving_the_trunk_head_and_arms_to_the_model(tmp_path, cli):
    """A Plug-in Gait trial with only the pelvis and legs is tracked (exit 0), and the report says
    which links had no segment."""
    from test_maps import LOWER_BODY, lower_body_plug_in_gait

    from torchik.io import save_recording

    path = save_recording(lower_body_plug_in_gait(), tmp_path / "lower.npz")
    code, stdout, err = cli("track", "--input", path, "--model", "human48", "--report", tmp_path / "r.json")
    assert code == 0, err
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["links"] == len(LOWER_BODY) and "through map 'plug-in gait to human'" in report["source"]
    assert report["left_to_model"] == ["T8", "Head", "RightShoulder", "RightUpperArm", "RightForeArm", "RightHand",
                                       "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand"]
    assert "left to the model (no segment in the recording): T8, Head, RightShoulder" in stdout
    assert report["mnte"]["max"] < 1e-3  # the legs followed


def test_a_short_trial_is_tracked_from_its_first_frames_posture_and_its_report_says_over_which_time(tmp_path, cli):
    """A 1.2 s trial (a clinical pass over the force plates): the estimate follows from frame 0, not
    after a transient from the zero posture; the statistics are the whole trial's, and the report
    and its printout say so instead of naming a window after 2 s that the trial does not have."""
    from torchik.io import save_recording
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.synthetic.scenarios import scenario

    walk = scenario("walking", load_model("human48"), TRACKED_LINKS["human48"], duration=1.2)
    path = save_recording(walk, tmp_path / "short.npz")
    code, stdout, err = cli("track", "--input", path, "--model", "human48", "--report", tmp_path / "r.json",
                            "--out", tmp_path / "e.npz")
    assert code == 0, err
    mnte = np.load(tmp_path / "e.npz")["mnte"]
    assert mnte[0] < 1e-3 and mnte.max() < 1e-3  # from the zero posture: 0.2 at frame 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["statistics_from_s"] == 0.0 and report["settled_s"] > 0 and report["mnte"]["p99"] < 1e-3
    assert "MNTE over the whole 1.20 s (shorter than the 2 s transient" in stdout and "after 2 s" not in stdout


def readme_main_command() -> str:
    """The README's main command: the `$ torchik track ...` line of its first example."""
    commands = re.findall(r"^\$ (torchik track .*)$", (REPO / "README.md").read_text(), flags=re.MULTILINE)
    assert commands, "README.md shows no `$ torchik track ...` command"
    return commands[0]


def test_the_readme_main_command_writes_a_report_and_a_recording_that_agree(tmp_path):
    from test_rrd import column, read_rrd

    command = readme_main_command()
    assert "--rrd walk.rrd" in command and "--report walk.json" in command and "--model human66" in command
    readme, makefile = (REPO / "README.md").read_text(), (REPO / "Makefile").read_text()
    assert "rerun walk.rrd" in readme and command.split(" ", 1)[1] in makefile  # `make demo` runs it
    result = run(*command.split()[1:], "--duration", "1", cwd=tmp_path)  # the same, on a short scenario
    assert result.returncode == 0, result.stderr
    assert "open it with: rerun walk.rrd" in result.stdout
    report = json.loads((tmp_path / "walk.json").read_text())
    assert report["frames"] == 101 and report["model"] == "Human66" and not report["interrupted"]
    frame = read_rrd(tmp_path / "walk.rrd", "/subject/0/errors/mnte")
    assert len(frame) == 101
    # 1 s is within the 2 s transient: the report's statistics are over every frame, as logged
    assert column(frame, "/subject/0/errors/mnte").max() == report["mnte"]["max"]


@pytest.fixture(scope="module")
def human_recording(tmp_path_factory):
    """A 0.5 s recording whose segments are Human66's links."""
    from torchik.io import save_recording
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.synthetic.scenarios import scenario

    path = tmp_path_factory.mktemp("recording") / "walk.npz"
    return save_recording(scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=0.5), path)


@pytest.mark.parametrize("args, says", [
    (("track", "--input", "missing.npz"), "missing.npz: no such file"),
    (("track", "--model", "robot"), "invalid choice: 'robot' (choose from 'human66', 'human48', 'icub')"),
    (("track", "--scenario", "dancing"), "unknown scenario 'dancing'; valid: tpose, walking, running"),
    (("track", "--input", "RECORDING", "--map", "cmu_to_human"), "needs segment 'Hips', its base link 'Pelvis', that "
                                                                 "the recording lacks: nothing to track without it; "
                                                                 "it has ['Pelvis'"),
    (("track", "--input", "RECORDING", "--map", "no_such_map"), "built-in maps: bandai_to_human"),
    (("track", "--rrd", "walk.txt"), "must end in .rrd"),
    (("track", "--rrd", "no/such/folder/walk.rrd"), "no folder no/such/folder to write into"),
    (("track", "--report", "EXISTING"), "exists; add --force to overwrite it"),
    (("track", "--device", "tpu"), "expected cpu, cuda or cuda:N"),
    (("track", "--gain", "fast"), "argument --gain: invalid float value: 'fast'"),
    (("info", "missing.bvh"), "missing.bvh: no such file"),
    (("unknown",), "invalid choice: 'unknown'"),
])
def test_bad_input_exits_2_with_one_line_saying_what_is_wrong(args, says, cli, human_recording, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "EXISTING").write_text("kept")
    args = [str(human_recording) if a == "RECORDING" else a for a in args]
    code, out, err = cli(*args)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("torchik") and says in err, err
    assert (tmp_path / "EXISTING").read_text() == "kept"


def test_an_interrupted_track_leaves_valid_shorter_outputs(tmp_path, cli, monkeypatch):
    from test_rrd import read_rrd

    from torchik.method.tracker import DynamicalIK
    from torchik.pipelines.track import SETTLE

    step, calls = DynamicalIK.step, []
    settling = round(SETTLE * 100)  # the steps on the first frame at the scenario's 100 Hz, before the run's

    def interrupted_after_7(self, *args, **kwargs):  # Ctrl-C during the run's 8th step
        calls.append(1)
        if len(calls) > settling + 7:
            raise KeyboardInterrupt
        return step(self, *args, **kwargs)

    monkeypatch.setattr(DynamicalIK, "step", interrupted_after_7)
    rrd, report, out = tmp_path / "walk.rrd", tmp_path / "walk.json", tmp_path / "walk.npz"
    code, _, err = cli("track", "--duration", "1", "--rrd", rrd, "--report", report, "--out", out, "--quiet")
    assert code == 130 and "interrupted; the outputs hold the 7 frames tracked" in err
    assert len(read_rrd(rrd, "/subject/0/errors/mnte")) == 7
    data = json.loads(report.read_text())
    assert data["frames"] == 7 and data["interrupted"] is True
    assert np.load(out)["joint_positions"].shape == (7, 66)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.json", "walk.npz", "walk.rrd"]  # no leftovers


def test_ctrl_c_during_tracking_leaves_valid_shorter_outputs(tmp_path):
    import signal

    from test_rrd import read_rrd

    command = [sys.executable, "-m", "torchik", "track", "--duration", "30", "--rrd", "walk.rrd", "--report", "walk.json"]
    # a terminal's Ctrl-C: SIGINT with its default action (a background job of a script would ignore it)
    process = subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = ""
    while "tracking:" not in seen and process.poll() is None:  # the progress bar: tracking has run a second
        seen += process.stderr.read(1)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, seen + err
    report = json.loads((tmp_path / "walk.json").read_text())
    assert report["interrupted"] is True and 0 < report["frames"] < 3001
    assert len(read_rrd(tmp_path / "walk.rrd", "/subject/0/errors/mnte")) == report["frames"]

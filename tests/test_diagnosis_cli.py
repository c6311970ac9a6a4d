"""diagnosis outside the synthetic batch: `torchik diagnose` writes its report, calibration, URDF and
rerun recording, and `torchik track` reuses them; the loop says what it cannot identify; and on
measured data (../shared/data, skipped when absent) it runs to the end and lowers the error.

One recording of a few seconds per test (Human48 or Human66, 50 Hz), each diagnosed in seconds.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import rerun
from conftest import shared_file

from torchik.cli import main
from torchik.io import angular_velocity_from_orientations, read, save_recording
from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis.effect import replace
from torchik.pipelines.diagnosis.joints import MissingDof
from torchik.pipelines.diagnosis.loop import diagnose
from torchik.pipelines.diagnosis.placement import Misalignment
from torchik.pipelines.diagnosis.synthetic import recording_of, with_missing_dof
from torchik.synthetic.scenarios import scenario

pytestmark = pytest.mark.usefixtures("one_thread")
LINKS = TRACKED_LINKS["human48"]


@pytest.fixture
def cli(monkeypatch, capsys):
    """`torchik ARGS` in this process: (exit code, stdout, stderr)."""
    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)

    def call(*args):
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out, err

    return call


def test_diagnose_writes_what_track_reuses(tmp_path, cli):
    """A recording with a knee axis Human48 lacks and a misaligned forearm sensor: the command names
    both, writes the report, the calibration, the augmented URDF and the residuals' recording, and
    tracking with the calibration and the URDF brings the error down to the noise's."""
    effect = MissingDof("missing_dof", "jLeftKnee", dict(axis=[1.0, 0.0, 0.0], parent="LeftUpperLeg",
                                                         child="LeftLowerLeg", first_joint="jLeftKnee_roty"))
    # 6 deg either way: within what a knee's ab/adduction moves (joints.HINGE_RANGE)
    truth, motion = with_missing_dof(human_urdf(48), effect, 0.1, 0.9, 0.3, duration=4.0, rate=50.0, seed=1)
    clean = recording_of(truth, motion, LINKS, 1, 0.005, 0.02)
    misaligned = Misalignment("misalignment", "RightForeArm", dict(rotation_vector=[0.1, -0.12, 0.0]))
    path = save_recording(misaligned.inject(clean), tmp_path / "walk.npz")
    report = tmp_path / "diag"
    code, out, err = cli("diagnose", path, "--model", "human48", "--report", report)
    assert code == 0, err
    assert "missing axis at jLeftKnee" in out and "misalignment of the RightForeArm sensor" in out
    assert {p.name for p in report.iterdir()} >= {"report.md", "calibration.json", "model.urdf", "residuals.rrd",
                                                 "errors.png", "residual.png", "diagnosis.json"}
    text = (report / "report.md").read_text()
    assert "## Effects found" in text and "jLeftKnee_added" not in text and "errors.png" in text
    calibration = json.loads((report / "calibration.json").read_text())
    assert [(e["kind"], e["target"]) for e in calibration["effects"]] == [("misalignment", "RightForeArm")]
    assert 'name="jLeftKnee_added"' in (report / "model.urdf").read_text()
    paths = set(rerun.chunk.RrdReader(str(report / "residuals.rrd")).store().schema().entity_paths())
    assert {"/residual/orientation_deg/RightForeArm/before", "/residual/orientation_deg/RightForeArm/after"} <= paths

    code, _, err = cli("diagnose", path, "--model", "human48", "--report", report, "--quiet")
    assert code == 2 and "--force" in err  # never writes over a report unasked
    mnte = {}
    for name, extra in (("plain", ()), ("calibrated", ("--sensor-calibration", report / "calibration.json",
                                                         "--urdf", report / "model.urdf"))):
        code, _, err = cli("track", "--input", path, "--model", "human48", "--report", tmp_path / f"{name}.json",
                           "--quiet", *extra)
        assert code == 0, err
        mnte[name] = json.loads((tmp_path / f"{name}.json").read_text())["mnte"]["median"]
    floor = 1 - math.cos(0.005 * math.sqrt(3))  # the noise's own MNTE: 1 - cos of a rotation of 0.005 rad per axis
    # down to the noise's (the knee's 6 deg leave 10 times the floor; its own tenth would be below the noise)
    assert mnte["calibrated"] < 2 * floor and mnte["calibrated"] < mnte["plain"] / 5, mnte


def test_what_the_data_cannot_identify_is_said():
    """Human66's ball joints follow any sensor-to-segment rotation: a misalignment leaves no residual
    and is reported as not identifiable on every link; an angular velocity computed from the
    orientations is no gyro: the gyro effects are reported as not identifiable either."""
    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    walk = scenario("walking", model, links, 3.0, 50.0, seed=2, orientation_noise=0.005, gyro_noise=0.02)
    walk = Misalignment("misalignment", "LeftForeArm", dict(rotation_vector=[0.1, 0.1, 0.05])).inject(walk)
    derived = replace(walk, angular_velocity=angular_velocity_from_orientations(walk.orientation, walk.time))
    found = diagnose(model, human_urdf(66), [walk, derived], links, max_effects=1, refine=0,
                     kinds=("misalignment", "gyro_bias"))
    for d in found:
        assert not any(e.kind == "misalignment" for e in d.effects)
        unobservable = {(e.kind, e.target) for e in d.unobservable}
        assert {("misalignment", link) for link in links} <= unobservable
        assert all("not identifiable" in e.notes for e in d.unobservable)
    assert not any(kind == "gyro_bias" for kind, _ in {(e.kind, e.target) for e in found[0].unobservable})
    assert {("gyro_bias", link) for link in links} <= {(e.kind, e.target) for e in found[1].unobservable}


@pytest.mark.parametrize("name", ["human48", "human66"])
def test_measured_mvnx_runs_to_the_end_and_lowers_the_error(name):
    """The Xsens recording (real gyros, 60 Hz): the loop runs to its end with finite errors, the
    overall MNTE after is at most the MNTE before (the loop only checks each effect's own error),
    and Human66 (ball joints) reports every misalignment as not identifiable."""
    recording = read(str(shared_file("mvnx/test_mocap.mvnx")))
    model, links = load_model(name), TRACKED_LINKS[name]
    d, = diagnose(model, human_urdf(int(name[-2:])), [recording], links, max_effects=3)
    assert d.after.overall["mnte"] <= d.before.overall["mnte"]
    assert np.isfinite(d.after.mnte).all()
    if name == "human66":
        assert {("misalignment", link) for link in links} <= {(e.kind, e.target) for e in d.unobservable}

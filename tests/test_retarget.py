"""retarget: a human walk becomes iCub joint trajectories that never leave a limit and follow the
mapped human link orientations as closely as the best instantaneous fit; resampling is exact for
uniform motion; the command writes what a position controller needs."""

import numpy as np
import pytest
import torch
from conftest import shared_file, skip_without_shared

from torchik.cli import main
from torchik.io import Recording, save_recording
from torchik.io.targets import recording_targets
from torchik.method import so3
from torchik.method.baselines import WholeBodyIK
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import State
from torchik.pipelines.retarget import human_to_icub, resample, retarget
from torchik.synthetic.scenarios import scenario

# iCub is not a person: its links can follow the mapped human ones only so far. On the walk below the
# best fit within the limits (whole-body IK, every frame) leaves an MNTE of about 9e-3 (some 8 degrees
# per link); the retargeted motion must stay within 10% of that fit at every frame after the first
# second, and so below this bound.
MNTE_BOUND = 0.015


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def walk():
    return scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=2.0, rate=100.0)


@pytest.fixture(scope="module")
def retargeted(walk):
    return retarget(walk, rate=100.0, progress=False)


def test_the_retargeted_walk_never_leaves_a_joint_or_coupled_limit(retargeted):
    result, report = retargeted
    icub = load_model("icub")
    s = torch.from_numpy(result.joint_positions)
    assert s.shape == (201, icub.n_dof) and result.joint_names == icub.joint_names
    assert float((s - icub.upper).max()) <= 1e-6 and float((icub.lower - s).max()) <= 1e-6
    A, b = icub.linear_limits.A, icub.linear_limits.b
    assert float((s @ A.T - b).max()) <= 1e-6  # the coupled shoulder and elbow limits, every frame
    assert report["qp_fallbacks"] == 0


def test_the_icub_links_follow_the_mapped_human_ones_as_well_as_the_best_fit(walk, retargeted):
    result, _ = retargeted
    icub = load_model("icub")
    mapped = human_to_icub(walk, icub)
    after = result.time >= 1.0
    assert float(np.max(result.mnte[after])) < MNTE_BOUND
    # the best instantaneous fit within the same limits, from the retargeted pose, at every tenth frame
    sequence = recording_targets(mapped, mapped.links)
    ik = WholeBodyIK(icub, mapped.links)
    for k in np.flatnonzero(after)[::10]:
        pose = State(*(torch.from_numpy(x[k:k + 1]) for x in (result.base_position, result.base_rotation,
                                                               result.joint_positions)),
                     torch.zeros(1, 6 + icub.n_dof, dtype=torch.float64))
        best = float(ik.solve(sequence[int(k)], pose).mnte)
        assert result.mnte[k] <= 1.1 * best, (k, result.mnte[k], best)


def test_angles_and_rates_agree_at_the_controller_rate(retargeted):
    result, report = retargeted
    dt = np.diff(result.time)
    assert np.allclose(dt, 0.01) and report["rate_hz"] >= 50
    # each step moved the joints by dt times its rate: what a position controller streams is consistent
    assert np.allclose(np.diff(result.joint_positions, axis=0), dt[:, None] * result.joint_velocities[1:], atol=1e-12)


def test_resampling_a_uniform_rotation_is_exact():
    t = np.arange(0.0, 1.0 + 1e-9, 1 / 30)  # 30 Hz, as a BVH file
    omega = np.array([0.4, -0.3, 1.1])
    R = so3.exp(torch.from_numpy(t[:, None] * omega)).numpy()[:, None]  # [T,1,3,3]
    recording = Recording(time=t, links=("Pelvis",), orientation=R, angular_velocity=np.tile(omega, (len(t), 1, 1)),
                          base_link="Pelvis", base_position=t[:, None] * np.array([1.0, 0.0, 0.0]) + [0, 0, 1],
                          base_linear_velocity=np.tile([1.0, 0.0, 0.0], (len(t), 1)))
    fine = resample(recording, 100.0)
    assert np.allclose(np.diff(fine.time), 0.01) and fine.time[-1] <= t[-1] + 1e-12
    exact = so3.exp(torch.from_numpy(fine.time[:, None] * omega)).numpy()[:, None]
    assert np.allclose(fine.orientation, exact, atol=1e-12)
    assert np.allclose(fine.base_position[:, 0], fine.time, atol=1e-12)


def test_the_command_writes_the_trajectories_and_keeps_an_existing_file(tmp_path, walk, capsys):
    source = save_recording(walk, tmp_path / "walk.npz")
    out = tmp_path / "icub.npz"
    assert main(["retarget", str(source), "--to", "icub", "--out", str(out), "--quiet"]) == 0
    data = np.load(out)
    assert list(data["joint_names"]) == list(load_model("icub").joint_names)
    T = len(data["time"])
    assert data["joint_positions"].shape == data["joint_velocities"].shape == (T, 32) and float(data["rate_hz"]) >= 50
    assert main(["retarget", str(source), "--to", "icub", "--out", str(out), "--quiet"]) == 2  # exists: --force
    assert "--force" in capsys.readouterr().err


@pytest.mark.parametrize("extra, message", [(["--rate", "30"], "50 Hz or more"), (["--calibration", "x.npz"], "--map")])
def test_bad_input_is_refused_with_exit_code_2(tmp_path, walk, capsys, extra, message):
    source = save_recording(walk, tmp_path / "walk.npz")
    assert main(["retarget", str(source), "--to", "icub", "--out", str(tmp_path / "icub.npz"), "--quiet", *extra]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "icub.npz").exists()


@pytest.mark.parametrize("source", ["written", pytest.param("shared", marks=skip_without_shared)])
def test_an_xsens_recording_retargets_within_the_limits(tmp_path, source, request):
    """The MVN export the tests write (conftest's mvn_export) and the real one of ../shared/data."""
    path = request.getfixturevalue("mvn_export").path if source == "written" else shared_file("mvnx/test_mocap.mvnx")
    out = tmp_path / "icub.npz"
    assert main(["retarget", str(path), "--to", "icub", "--out", str(out), "--quiet"]) == 0
    data = np.load(out)
    icub = load_model("icub")
    s = torch.from_numpy(data["joint_positions"])
    assert float(torch.maximum(s - icub.upper, icub.lower - s).max()) <= 1e-6
    assert float((s @ icub.linear_limits.A.T - icub.linear_limits.b).max()) <= 1e-6

"""Shared fixtures, and the one way a test reaches ../shared (the published reference models, the real
recordings in ../shared/data): `shared_file`, which skips the test, naming the path, when it is absent
(a user's clone has no ../shared). Paths are resolved from the repository, never the working directory."""

import os
from pathlib import Path

import pytest
import torch

from torchik.method import so3

REPO = Path(__file__).resolve().parents[1]

if os.environ.get("PYTEST_XDIST_WORKER"):  # `make test` runs one worker per core: more torch threads would only contend
    torch.set_num_threads(1)
SHARED = REPO.parent / "shared"  # beside the checkout, where the project's machines keep it
DATA = SHARED / "data"
REFERENCE = SHARED / "reference-models"


# a test (or a parameter) that reads ../shared/data: skipped, saying so, on a clone without it
skip_without_shared = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} absent: ../shared is not beside this checkout")


def shared_file(relative: str | Path, root: Path = DATA) -> Path:
    """A file of ../shared/data (`relative` to it, e.g. "c3d/HC002D02.c3d"; or to `root`), as an absolute
    path; the calling test is skipped, with the path named, when it is absent."""
    path = root / relative
    if not path.is_file():
        pytest.skip(f"{path} absent: ../shared is not beside this checkout")
    return path


def reference_urdf(name: str) -> Path:
    """A published URDF of ../shared/reference-models (skipped when absent)."""
    return shared_file(name, REFERENCE)


def random_configurations(model, batch: int, seed: int, joint_scale: float = 1.0):
    """Random base poses and joint angles: p_B [B,3], R_B [B,3,3], s [B,n] (float64)."""
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(batch, 3, generator=g, dtype=torch.float64)
    R = so3.random_rotation((batch,), g)
    s = joint_scale * torch.randn(batch, model.n_dof, generator=g, dtype=torch.float64)
    return p, R, s


@pytest.fixture(scope="module")
def one_thread():
    """Torch on one thread for a module's tests: one subject's problems are too small for threads
    to pay, and on a shared machine idle threads only spin and wait for each other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def cli(monkeypatch, capsys):
    """`torchik ARGS` in this process: (exit code, stdout, stderr). Faster than a subprocess; the
    allocator tuning of the command line is left out (it would stay with pytest's process)."""
    from torchik.cli import main

    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)

    def call(*args):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse: --help and usage errors
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err

    return call


def kept_subject(model, urdf: str, recording, kept, links):
    """A subject of the diagnosis loop that kept `kept` (in that order) on `recording`: the recording
    corrected by them, tracked and analysed, each effect a step (errors before and after both the
    current ones)."""
    from torchik.pipelines.diagnosis.loop import Step, errors
    from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

    current = recording
    for effect in kept:
        current = effect.correct(current)
    s = Subject(current, urdf, model, source=(recording, urdf))
    analyse_subjects([s], links, 20.0, False, 300)
    s.derived = s.current[0].derived[0]
    s.steps = [Step(effect, errors(*s.current), errors(*s.current)) for effect in kept]
    return s


def human48_walk(seconds: float, seed: int, orientation_noise: float, gyro_noise: float = 0.02):
    """(Human48, its URDF, a built-in walk of `seconds` at 50 Hz with that sensor noise on its
    tracked links): the recording most diagnosis tests inject their effects into."""
    from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
    from torchik.synthetic.scenarios import scenario

    model = load_model("human48")
    return model, human_urdf(48), scenario("walking", model, TRACKED_LINKS["human48"], seconds, 50.0, seed=seed,
                                           orientation_noise=orientation_noise, gyro_noise=gyro_noise)


@pytest.fixture(scope="session")
def pig_session(tmp_path_factory):
    """A Plug-in Gait session the tests write (tests/written.py), as a Vicon one is: a 1.45 m, 32.1 kg
    subject's static trial (51 frames at 100 Hz, standing in the N-pose facing +x) and a 2 s walk at
    100 Hz (human48's walking scenario), with the model and the recordings they were written from."""
    pytest.importorskip("ezc3d")
    from types import SimpleNamespace

    from written import plug_in_gait_c3d, standing, walk

    from torchik.method.models import load_model
    from torchik.method.models.human import HumanSubject

    folder = tmp_path_factory.mktemp("plug_in_gait")
    subject = HumanSubject(height=1.45, mass=32.1)
    model = load_model("human48", subject=subject)
    still, walking = standing(model, "npose", frames=51, rate=100.0), walk(model, seconds=2.0, rate=100.0)
    return SimpleNamespace(model=model, subject=subject, still=still, walking=walking,
                           static=plug_in_gait_c3d(folder / "HC000S01.c3d", model, still, subject),
                           walk=plug_in_gait_c3d(folder / "HC000W01.c3d", model, walking, subject))


@pytest.fixture(scope="session")
def mvn_export(tmp_path_factory):
    """An Xsens MVN export the tests write (tests/written.py): human66's walking scenario, 1.5 s at 60 Hz,
    as MVNX with segments, sensors, joints and calibration frames; with the model and the recording."""
    from types import SimpleNamespace

    from written import walk, xsens_mvnx

    from torchik.method.models import load_model

    model = load_model("human66")
    walking = walk(model, seconds=1.5, rate=60.0)
    return SimpleNamespace(model=model, walking=walking,
                           path=xsens_mvnx(tmp_path_factory.mktemp("mvn") / "walk.mvnx", model, walking))

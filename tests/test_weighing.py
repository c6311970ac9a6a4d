"""io.weighing: a static trial's plates weigh the subject standing still on them, and that mass, not
the typed PROCESSING:Bodymass, builds the subject (io/subjects.py) and drives `torchik dynamics`;
where a foot stands off the plates, or the file has none, Bodymass does and the output says why.

The trials are Plug-in Gait static trials the tests write (tests/written.py: a 1.45 m subject whose
Bodymass says 32.1 kg, standing still in the N-pose) with two plates added (tests/test_force_plates.py),
one under each foot, carrying together 31.0 kg's weight with a 2 Hz sway of known amplitude: the file
states 32.1 kg, 3.5 % more than the plates weigh, as HC002's static trial does (32.1 against 31.07)."""

import numpy as np
import pytest
from conftest import shared_file
from test_force_plates import ANALOG_RATE, DOWN, Plate, add_plates, constant

import torchik as tk
from torchik.io import read
from torchik.io.subjects import subject_from_recording
from torchik.method.models.human import HumanSubject

ezc3d = pytest.importorskip("ezc3d")

FRAMES, RATE, GRAVITY = 51, 100.0, 9.81
STATED = HumanSubject(height=1.45, mass=32.1)  # what PROCESSING says
WEIGHED, SWAY = 31.0, 20.0  # kg the plates carry; N amplitude of the sway of their summed vertical force


def static_trial(folder, off: float = 0.0):
    """A written static trial on two plates (module docstring); the left plate moved `off` m to the left
    (0: under the left foot)."""
    from written import plug_in_gait_c3d, standing

    model = tk.load_model("human48", STATED)
    still = standing(model, "npose", frames=FRAMES, rate=RATE)
    path = plug_in_gait_c3d(folder / "S01.c3d", model, still, STATED)
    S = int(FRAMES * ANALOG_RATE / RATE)
    t = np.arange(S) / ANALOG_RATE
    sway = SWAY * np.sin(2 * np.pi * 2.0 * t)
    plates, signals = [], []
    for side, shift in (("Right", 0.0), ("Left", off)):
        foot = still.position[0, still.links.index(f"{side}Foot")] + np.array([0.0, shift, 0.0])
        plate = Plate(DOWN, (1000.0 * (foot[0] + 0.05), 1000.0 * foot[1], 0.0), half=(150.0, 60.0))
        force = np.zeros((S, 3))
        force[:, 2] = WEIGHED * GRAVITY / 2 + sway / 2
        plates.append(plate)
        signals.append(plate.channels(force, constant(1000.0 * np.array([foot[0] + 0.03, foot[1], 0.0]), S),
                                      constant(0.0, S)))
    c3d = ezc3d.c3d(str(path))
    add_plates(c3d, plates, signals)
    c3d.write(str(path))
    return path


@pytest.fixture(scope="module")
def on_plates(tmp_path_factory):
    return static_trial(tmp_path_factory.mktemp("weighed"))


def test_the_plates_weigh_a_subject_standing_still_on_them_and_that_mass_builds_it(on_plates):
    """The mass is the plates' mean vertical force over g, its sd the sway's (A / sqrt 2 / g), over every
    frame; the subject takes it and says what Bodymass states; asked for Bodymass, it takes that."""
    scale = read(on_plates).meta["skeleton"]["weighed"]
    assert scale["why_not"] is None and scale["frames"] == FRAMES
    assert scale["mass_kg"] == pytest.approx(WEIGHED, abs=0.02)
    assert scale["sd_kg"] == pytest.approx(SWAY / np.sqrt(2) / GRAVITY, rel=0.1)
    built = subject_from_recording(read(on_plates))
    assert built.subject.mass == pytest.approx(WEIGHED, abs=0.02)
    assert built.mass_from.startswith(f"the static trial's plates: {FRAMES} still frames with every foot on a plate")
    assert "PROCESSING:Bodymass states 32.1 kg, 3.5 % more" in built.mass_from
    stated = subject_from_recording(read(on_plates), weighed=False)
    assert stated.subject.mass == pytest.approx(32.1) and stated.mass_from == "the file's PROCESSING:Bodymass"


def test_a_foot_off_the_plates_leaves_the_stated_mass_and_says_why(tmp_path):
    """The left plate 0.2 m to the left of the left foot: the plates carry a weight, but not the
    subject's whole one as far as they can tell; Bodymass builds the subject and the reason is given."""
    built = subject_from_recording(read(static_trial(tmp_path, off=0.2)))
    assert built.subject.mass == pytest.approx(32.1)
    assert built.mass_from.startswith("the file's PROCESSING:Bodymass; the plates do not weigh the subject: no frame "
                                      "has every foot wholly on a plate")


def test_a_walk_is_not_a_weighing(pig_session):
    """A file without plates, and a walk (the pelvis moves): no mass from the plates, and why."""
    assert read(pig_session.static).meta["skeleton"]["weighed"]["why_not"] == "the file has no force plates"
    walk = shared_file("c3d/HC002D06.c3d")
    assert read(walk).meta["skeleton"]["weighed"]["why_not"].startswith("the subject moves")


def test_dynamics_takes_the_plates_mass_and_reports_both(on_plates, cli, tmp_path):
    """`torchik dynamics` on the static trial: the printed subject and report.md give the plates' mass and
    Bodymass; --mass-from bodymass takes the stated one, --mass overrides both."""
    common = ("--input", on_plates, "--map", "plugin_gait_to_human", "--calibration", on_plates, "--model", "human48",
              "--no-fit")
    code, stdout, err = cli("dynamics", *common, "--report", tmp_path / "plates")
    assert code == 0, err
    assert "mass 31.00 kg (the static trial's plates: 51 still frames" in stdout
    assert "PROCESSING:Bodymass states 32.1 kg, 3.5 % more" in stdout and "(31.0 kg)" in stdout
    report = (tmp_path / "plates" / "report.md").read_text()
    assert "31.00 kg" in report and "PROCESSING:Bodymass states 32.1 kg, 3.5 % more" in report
    code, stdout, err = cli("dynamics", *common, "--report", tmp_path / "stated", "--mass-from", "bodymass")
    assert code == 0, err
    assert "mass 32.1 kg (the file's PROCESSING:Bodymass)" in stdout and "(32.1 kg)" in stdout
    code, stdout, err = cli("dynamics", *common, "--report", tmp_path / "given", "--mass", "30.5")
    assert code == 0, err
    assert "mass 30.5 kg (given)" in stdout and "(30.5 kg)" in stdout

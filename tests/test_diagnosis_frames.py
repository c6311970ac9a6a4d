"""The flipped-frame family (torchik/pipelines/diagnosis/frames.py).

Recordings: a Human48 walk (5 s at 50 Hz, the scenarios' sensor noise), clean; the same with one
sensor's frame turned by 180 deg about one of its axes (its orientation stream multiplied by
diag(+-1)), and with the forearms' streams exchanged, both made here, independently of the
families' own `apply`.

Properties:
- a flip's and a swap's corrections undo their injections, move only their links, and a calibration
  file carries a flip;
- on each flipped recording (one link's frame; a forearm's and hand's together) the loop adds that
  flip, on those links and that axis, and the MNTE after is within 2x the clean recording's;
- on the recording with the forearms' streams exchanged the loop adds that swap, and the MNTE after
  is within 2x the clean recording's;
- a kept flip removes most of the residual on its links and those one joint away; one that removes
  less than MIN_REMOVED is refused (Retracked.implausible: it brought a cause of another size closer);
- the clean recording gets no flip nor swap and has no link with a residual large enough to propose one (no
  re-tracking spent on it).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import human48_walk

from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis.calibration import apply_calibration
from torchik.pipelines.diagnosis.effect import replace
from torchik.pipelines.diagnosis.frames import KIND, KINDS, MIN_REMOVED, SWAP, FlippedFrame, SwappedSegments, large_residual
from torchik.pipelines.diagnosis.loop import diagnose

LINKS = TRACKED_LINKS["human48"]
FLIPS = ((("LeftHand",), "x", (1.0, -1.0, -1.0)), (("RightLowerLeg",), "z", (-1.0, -1.0, 1.0)),
         (("RightForeArm", "RightHand"), "y", (-1.0, 1.0, -1.0)))  # links, axis, diag(F)
SWAPPED = ("LeftForeArm", "RightForeArm")


def _flipped(walk, links, diagonal) -> object:
    R = walk.orientation.copy()
    for link in links:
        R[:, LINKS.index(link)] = R[:, LINKS.index(link)] @ np.diag(diagonal)
    return replace(walk, orientation=R)


def _swapped(walk, pair) -> object:
    i, j = (LINKS.index(n) for n in pair)
    R, w = walk.orientation.copy(), walk.angular_velocity.copy()
    R[:, [i, j]], w[:, [i, j]] = R[:, [j, i]], w[:, [j, i]]
    return replace(walk, orientation=R, angular_velocity=w)


@pytest.fixture(scope="module")
def walk(one_thread):
    return human48_walk(5.0, seed=5, orientation_noise=0.005)


@pytest.fixture(scope="module")
def runs(walk):
    """The diagnoses of the flipped walks (FLIPS' order), the swapped, then the clean one, tracked as one batch."""
    model, urdf, clean = walk
    recordings = [_flipped(clean, links, diagonal) for links, _, diagonal in FLIPS] + [_swapped(clean, SWAPPED), clean]
    return diagnose(model, urdf, recordings, LINKS, max_effects=3), recordings


def test_a_correction_undoes_the_injection(walk):
    clean = walk[2]
    effect = FlippedFrame(KIND, "LeftForeArm", dict(axis="y", links=["LeftForeArm"]))
    moved = effect.inject(clean)
    i = LINKS.index("LeftForeArm")
    others = [n for n in range(len(LINKS)) if n != i]
    assert not np.allclose(moved.orientation[:, i], clean.orientation[:, i])
    np.testing.assert_array_equal(moved.orientation[:, others], clean.orientation[:, others])
    np.testing.assert_allclose(effect.correct(moved).orientation, clean.orientation, atol=1e-15)
    np.testing.assert_array_equal(moved.angular_velocity, clean.angular_velocity)  # world frame: a constant F leaves it
    swap = SwappedSegments(SWAP, SWAPPED[0], dict(links=list(SWAPPED)))
    moved = swap.inject(clean)
    np.testing.assert_array_equal(moved.orientation, _swapped(clean, SWAPPED).orientation)
    np.testing.assert_array_equal(swap.correct(moved).angular_velocity, clean.angular_velocity)
    np.testing.assert_array_equal(swap.correct(moved).orientation, clean.orientation)


def test_the_loop_finds_the_swap(runs):
    diagnoses, _ = runs
    d, clean = diagnoses[-2], diagnoses[-1]
    assert [e.params["links"] for e in d.effects if e.kind in KINDS] == [list(SWAPPED)]
    assert [e.kind for e in d.effects if e.kind in KINDS] == [SWAP]
    assert d.after.overall["mnte"] <= 2.0 * clean.after.overall["mnte"]


@pytest.mark.parametrize("case", range(len(FLIPS)))
def test_the_loop_finds_the_flip_and_the_error_returns_to_the_clean_level(runs, case):
    diagnoses, _ = runs
    d, clean = diagnoses[case], diagnoses[-1]
    links, axis, _ = FLIPS[case]
    flips = [(tuple(e.params["links"]), e.params["axis"]) for e in d.effects if e.kind == KIND]
    assert flips == [(links, axis)]
    assert d.after.overall["mnte"] <= 2.0 * clean.after.overall["mnte"]


def test_the_calibration_file_undoes_the_flip(runs, walk):
    diagnoses, recordings = runs
    calibration = json.loads(json.dumps(diagnoses[0].calibration()))
    i = LINKS.index(FLIPS[0][0][0])
    corrected = apply_calibration(recordings[0], calibration)
    np.testing.assert_allclose(corrected.orientation[:, i], walk[2].orientation[:, i], atol=1e-12)


def test_a_clean_recording_gets_no_flip_and_proposes_none(runs):
    clean = runs[0][-1]
    assert not [e for e in clean.effects + clean.rejected if e.kind in KINDS]
    assert not large_residual(*clean.first)


def test_a_flip_that_removes_little_of_its_links_residual_is_refused(runs):
    """A half turn has no size to fit: undone where it is the cause, it takes most of its links' residual
    with it (the kept flips), and one that removes less brought a cause of another size closer."""
    kept = [e for d in runs[0][:len(FLIPS)] for e in d.effects if e.kind == KIND]
    assert kept and all(e.params["removed"] >= MIN_REMOVED and not e.implausible() for e in kept)
    partial = FlippedFrame(KIND, "LeftHand", dict(axis="x", links=["LeftHand"], removed=MIN_REMOVED / 2))
    assert f"{100 * MIN_REMOVED / 2:.0f} %" in partial.implausible()

"""The diagnosis on recordings of simulated sensors, which share none of its equations (issue 35).

experiments/sensor_physics.py makes them on pinocchio's kinematics (Human48, Human66 for a missing
axis): inertial sensors through their strap, gyro, accelerometer, magnetometer and a complementary
filter, or marker clusters fitted by Kabsch; it imports nothing from the diagnosis. One recording of
each kind the diagnosis must tell apart, 8 s at 100 Hz, on seeds neither the diagnosis' tuning (0-199)
nor the reported study (1000-1899) used.

Property: every injected effect is named on its link, as the kind its physics makes (a drift whose
gyro shares it, or whose gyro does not), and nothing else is kept; a clean suit keeps nothing.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.diagnosis.loop import diagnose

pinocchio = pytest.importorskip("pinocchio")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import sensor_physics  # noqa: E402

LINKS = TRACKED_LINKS["human48"]
SEED = 7000
CASES = (("clean", None), ("strap", 1), ("gyro_bias", 2), ("vertical_bias", 1), ("magnetic_drift", 2),
         ("missing_axis", 1), ("optical_clean", None), ("cluster_offset", 1))


@pytest.fixture(scope="module")
def diagnosed(one_thread):
    """[(injected, Diagnosis)] per case, diagnosed as one batch."""
    made = [sensor_physics.generate(SEED + k, family, count, LINKS, duration=8.0, rate=100.0, reference=None)
            for k, (family, count) in enumerate(CASES)]
    found = diagnose(load_model("human48"), human_urdf(48), [rec for rec, *_ in made], LINKS, max_effects=6)
    return {family: (injected, d) for (family, _), (_, injected, _), d in zip(CASES, made, found)}


def _names(effect, kind: str, target: str) -> bool:
    """Whether `effect` names `kind` at `target`: itself, or as its equal in the report ("explained nearly
    as well by"): a drift its gyro shares on the Neck or on the Head, whose headings no joint between
    them turns apart, is seen only as their difference, and the report says the data cannot tell which."""
    return effect.kind == kind and (effect.target == target or f"explained nearly as well by {kind} at {target} "
                                    in effect.notes)


def _invisible(effect, kind: str, target: str) -> bool:
    """Whether `effect` names `kind` at `target` among the negligible ones because, tracked with and
    without it, nothing a report shows changes by a degree (contribution.py): a strap turned about
    directions the joints follow leaves a fraction of a degree (the study's "not identifiable")."""
    return effect.kind == kind and effect.target == target and "nothing a report shows changes" in effect.notes


@pytest.mark.parametrize("family", [family for family, _ in CASES])
def test_each_simulated_effect_is_named_on_its_link_and_nothing_else(diagnosed, family):
    """Named among the effects, or, where the joints follow it, listed as changing nothing."""
    injected, d = diagnosed[family]
    for inj in injected:
        for target in inj.targets:
            assert any(_names(e, kind, target) for e in d.effects for kind in inj.kinds()) or any(
                _invisible(e, kind, target) for e in d.negligible for kind in inj.kinds()), (family, target, d.effects)
    spurious = [e for e in d.effects if not any(_names(e, kind, target) for inj in injected for kind in inj.kinds()
                                                for target in inj.targets)]
    assert not spurious, (family, spurious)


def test_a_drift_is_named_as_what_its_gyro_does(diagnosed):
    """A bias about the vertical through a filter without a heading reference: the gyro drifts with
    the heading; a magnetic field turning under a 9-axis filter: the heading drifts, the gyro not."""
    for family, shares in (("vertical_bias", True), ("magnetic_drift", False)):
        drifts = [e for e in diagnosed[family][1].effects if e.kind == "heading_drift"]
        assert drifts and all(bool(e.params["gyro_shares"]) == shares for e in drifts), (family, drifts)


def test_marker_clusters_are_seen_as_derived_rates_and_inertial_sensors_as_gyros(diagnosed):
    """streams.derived_rates on the data themselves: the clusters' angular velocity is their
    orientations' derivative (np.gradient), the suit's is its gyros'."""
    for family, derived in (("optical_clean", True), ("clean", False)):
        analysis, b = diagnosed[family][1].first
        assert bool(analysis.derived[b].all()) == derived and bool(analysis.derived[b].any()) == derived


def test_the_generator_imports_nothing_from_the_diagnosis():
    tree = ast.parse(Path(sensor_physics.__file__).read_text())
    names = [a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names]
    names += [node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)]
    assert not [n for n in names if n.startswith("torchik.pipelines")], names

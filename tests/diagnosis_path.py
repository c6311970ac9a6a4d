"""The diagnosis loop's path built by hand, for the tests of its checks (limit_turn, axis_drift,
neighbour): a subject tracked as the loop's first round tracks it, and candidates added as the loop
adds them."""

from __future__ import annotations

from torchik.method.kinematics import KinematicModel
from torchik.method.models import TRACKED_LINKS
from torchik.pipelines.diagnosis import crossing
from torchik.pipelines.diagnosis.analysis import DEFAULT_GAIN
from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

LINKS = TRACKED_LINKS["human48"]


def tracked_subject(recording, urdf: str) -> Subject:
    """A Human48 subject of `recording`, tracked and analysed as the loop's first round leaves it."""
    s = Subject(recording, urdf, KinematicModel.from_urdf(urdf, name="Human48"), source=(recording, urdf))
    analyse_subjects([s], LINKS, DEFAULT_GAIN, False)
    s.first = s.analysis
    s.derived = s.current[0].derived[s.current[1]]
    return s


def added(s: Subject, kind: str, target: str):
    """The candidate of `kind` on `target` fitted, refitted and added to s, s tracked again."""
    found = [c for c in s.candidates((kind,), target=target) if c.fit is not None]
    assert found, f"the data give a {kind} at {target}"
    effect = s.refit(found[0]) or found[0]
    crossing.add_tracked(s, effect, LINKS, DEFAULT_GAIN, False, 300)
    return effect

"""The candidate effects of every family, fitted on one subject's analysis and scored on held-out time."""

from __future__ import annotations

import math
from typing import Sequence

import torch

from . import drift, gyro, joints, placement, position, posture
from .analysis import Analysis
from .effect import Effect

KINDS = ("gyro_bias", "gyro_scale", "stream_delay", "misalignment", "sensor_delay", "heading_drift", "static_pose",
         "missing_dof", "joint_limit", "position_offset", "flipped_frame",
         "swapped_segments")  # the last two: scored by re-tracking in the loop (frames.py)


def candidates(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, urdf: str,
               kinds: Sequence[str] = KINDS, derived: torch.Tensor | None = None, target: str | None = None,
               like: Effect | None = None) -> list[Effect]:
    """Every candidate effect of subject b, fitted on `train` and scored on `test`, best first; last,
    those the data cannot identify (no fit; their notes say why). derived [L]: links without a gyro of
    their own (default: analysis.derived); target: only the candidates on that link or joint (a refit;
    each is fitted on its own data, so they are the same as among all); like: an effect whose form a
    refit keeps (a heading drift's kind, shared with its gyro or not)."""
    wanted = set(kinds)
    out: list[Effect] = []
    if wanted & {"gyro_bias", "gyro_scale", "stream_delay"}:
        out += gyro.fit(analysis, b, train, test, derived, target=target)
    if wanted & set(placement.KINDS):
        out += placement.fit(analysis, b, train, test, target=target, kinds=wanted)
    if "heading_drift" in wanted:
        out += drift.fit(analysis, b, train, test, derived, target=target, like=like)
    if "static_pose" in wanted:
        out += posture.fit(analysis, b, train, test, urdf, target=target)
    if wanted & {"missing_dof", "joint_limit"}:
        out += joints.fit(analysis, b, train, test, urdf, target=target)
    if "position_offset" in wanted:
        out += position.fit(analysis, b, train, test)
    out = [c for c in out if c.kind in wanted and (target is None or c.target == target)
           and (c.fit is None or math.isfinite(c.score))]
    _weigh_turns(out)
    return sorted(out, key=lambda c: -c.score)


def _weigh_turns(out: list[Effect]) -> None:
    """A gyro bias whose integral a turn about the vertical explains as well (GyroBias.implausible)
    is that link's heading drift only if its orientations turn too: the drift candidate of the same
    link leaves its score on them (less its own gyro's part, which says what the bias' score says)
    beside the bias, and the drift is preferred where that is above zero. A bias along the sensor
    axis of a link that stays upright (a foot, a hand) also looks like a vertical turn to the gyro
    alone, but the orientations do not follow it. (The bias' own score, a likelihood ratio over the
    whole time, and the drift's, held out, are not on one scale: comparing them kept 8 s of a 1.5
    deg/s drift on an upper arm as a bias.)"""
    drifts = {c.target: c.score - (0.0 if c.params.get("gyro_shares") else c.params.get("own_gyro_score", 0.0))
              for c in out if c.kind == "heading_drift" and c.fit is not None}  # a shared drift's is the orientations' alone
    for c in out:
        if c.kind == "gyro_bias" and "vertical_turn_score" in c.params and c.target in drifts:
            c.params["drift_score"] = drifts[c.target]

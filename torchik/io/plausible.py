"""Samples no person could produce, dropped before tracking as missing ones are.

A finite but absurd value (a sensor's overflow, 1e300 from a bad conversion) passes every check
for NaN, and the tracker would follow it: a body turning at 1e300 rad/s, a base 1e296 m away.
Each bound is far beyond what a human body reaches (the fastest segment, a pitcher's forearm,
turns at about 160 rad/s; the fastest sprinters run at about 12 m/s)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .recording import Recording


@dataclass(frozen=True)
class Plausibility:
    """max_angular_velocity: rad/s of any link; max_linear_velocity: m/s of the base, measured or
    between two samples' positions (plus `position_noise` m, a marker's or a filter's jitter)."""

    max_angular_velocity: float = 300.0
    max_linear_velocity: float = 50.0
    position_noise: float = 0.05


def drop_implausible(recording: Recording, bounds: Plausibility) -> tuple[Recording, int]:
    """`recording` with the samples beyond `bounds` made missing (NaN), and how many were: a link's
    orientation and angular velocity at a frame, or the base's position and linear velocity."""
    w, v = recording.angular_velocity, recording.base_linear_velocity
    with np.errstate(over="ignore", invalid="ignore"):  # NaN (missing) compares False; an overflow to inf is beyond
        spinning = np.linalg.norm(w / bounds.max_angular_velocity, axis=-1) > 1.0  # [T,n]
        speeding = np.linalg.norm(v / bounds.max_linear_velocity, axis=-1) > 1.0  # [T]
    jumping = _jumps(recording.time, recording.base_position, bounds)
    base = speeding | jumping
    count = int(spinning.sum() + base.sum())
    if not count:
        return recording, 0
    orientation, w = recording.orientation.copy(), w.copy()
    orientation[spinning], w[spinning] = np.nan, np.nan
    position, v = recording.base_position.copy(), v.copy()
    position[base], v[base] = np.nan, np.nan
    return dataclasses.replace(recording, orientation=orientation, angular_velocity=w, base_position=position,
                               base_linear_velocity=v), count


def _jumps(time: np.ndarray, position: np.ndarray, bounds: Plausibility) -> np.ndarray:
    """[T] bool: base positions farther from the last accepted one than the speed bound allows."""
    known = np.isfinite(position).all(-1)
    k = np.flatnonzero(known)
    with np.errstate(over="ignore", invalid="ignore"):
        step = np.linalg.norm(np.diff(position[k], axis=0), axis=-1)
        allowed = bounds.max_linear_velocity * np.diff(time[k]) + bounds.position_noise
        if not (step > allowed).any():
            return np.zeros(len(time), dtype=bool)  # the usual case, without the loop below
        # a jump away and the jump back: compare each with the last position accepted, not the previous
        jumping = np.zeros(len(time), dtype=bool)
        last = k[0] if len(k) else 0
        for t in k[1:]:
            if np.linalg.norm(position[t] - position[last]) > bounds.max_linear_velocity * (time[t] - time[last]) + \
                    bounds.position_noise:
                jumping[t] = True
            else:
                last = t
    return jumping

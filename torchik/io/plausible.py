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
    return ImplausibleFilter(bounds)(recording)


class ImplausibleFilter:
    """`drop_implausible` for a recording given a chunk at a time, in order: call it on each chunk.
    The base's jumps are measured from the last position accepted, which may be in an earlier chunk."""

    def __init__(self, bounds: Plausibility):
        self.bounds = bounds
        self._last: tuple[float, np.ndarray] | None = None  # time and base position last accepted

    def __call__(self, recording: Recording) -> tuple[Recording, int]:
        bounds = self.bounds
        w, v = recording.angular_velocity, recording.base_linear_velocity
        with np.errstate(over="ignore", invalid="ignore"):  # NaN (missing) compares False; an overflow to inf is beyond
            spinning = np.linalg.norm(w / bounds.max_angular_velocity, axis=-1) > 1.0  # [T,n]
            speeding = np.linalg.norm(v / bounds.max_linear_velocity, axis=-1) > 1.0  # [T]
        jumping, self._last = _jumps(recording.time, recording.base_position, bounds, self._last)
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


def _jumps(time: np.ndarray, position: np.ndarray, bounds: Plausibility,
           last: tuple[float, np.ndarray] | None) -> tuple[np.ndarray, tuple[float, np.ndarray] | None]:
    """[T] bool: base positions farther from the last accepted one (`last`, from an earlier chunk,
    or else the first known here) than the speed bound allows; and the last accepted one after them."""
    known = np.flatnonzero(np.isfinite(position).all(-1))
    jumping = np.zeros(len(time), dtype=bool)
    if not len(known):
        return jumping, last
    t = np.concatenate(([last[0]], time[known])) if last else time[known]
    p = np.concatenate((last[1][None], position[known])) if last else position[known]
    with np.errstate(over="ignore", invalid="ignore"):
        step = np.linalg.norm(np.diff(p, axis=0), axis=-1)
        allowed = bounds.max_linear_velocity * np.diff(t) + bounds.position_noise
        if not (step > allowed).any():
            return jumping, (float(t[-1]), p[-1])  # the usual case, without the loop below
        # a jump away and the jump back: compare each with the last position accepted, not the previous
        accepted = 0
        for k in range(1, len(t)):
            if np.linalg.norm(p[k] - p[accepted]) > bounds.max_linear_velocity * (t[k] - t[accepted]) + \
                    bounds.position_noise:
                jumping[known[k - (len(t) - len(known))]] = True
            else:
                accepted = k
    return jumping, (float(t[accepted]), p[accepted])

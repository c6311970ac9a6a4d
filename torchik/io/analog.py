"""Analog channels (force plates, EMG) sampled faster than the motion, brought to the motion's frames.

A C3D file stores `ratio = ANALOG:RATE / POINT:RATE` analog samples per point frame (an integer),
the first of them synchronous with the frame: sample `ratio * k` is frame k's instant. `to_frames`
low-passes each channel with a zero-phase filter (no lag) and takes the sample at each frame's
instant:

- "butterworth" (the default): a 4th-order Butterworth low-pass run forward and backward
  (scipy's `sosfiltfilt`: 8th order in magnitude, no phase) at `cutoff` Hz, by default
  `CUTOFF_FRACTION` (0.3) of the frame rate: 30 Hz at 100 Hz, 0.6 of the frames' Nyquist frequency.
  It passes half the amplitude at the cut-off and 1.7 % at the frames' Nyquist frequency, so
  what the frames cannot hold does not alias into them.
- "mean": the centred mean of the `2 (ratio // 2) + 1` samples around the frame's instant (11, or
  +-5 ms, at 1000 Hz over 100 Hz), shrunk at the ends of the file. This is what Vicon Nexus
  computes Plug-in Gait's kinetics from: the shared walks' ground reactions equal it to float32's
  rounding. It passes 57 % of the amplitude at the Nyquist frequency: a weaker anti-alias filter,
  kept to compare with Plug-in Gait.

A non-finite sample is never used: the Butterworth filter runs over each finite stretch on its own
(a stretch too short for its edge padding gives NaN), and a mean whose window holds one is NaN.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..errors import InputError

CUTOFF_FRACTION = 0.3  # the Butterworth's default cut-off, as a fraction of the frame rate
ORDER = 4
Method = Literal["butterworth", "mean"]


def samples_per_frame(analog_rate: float, frame_rate: float) -> int:
    """ANALOG:RATE / POINT:RATE, which C3D makes an integer; InputError when it is not."""
    ratio = analog_rate / frame_rate
    if ratio < 1 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        raise InputError(f"analog rate {analog_rate} Hz is not a whole multiple of the frame rate {frame_rate} Hz")
    return int(round(ratio))


def to_frames(samples: np.ndarray, analog_rate: float, frame_rate: float, frames: int,
              method: Method = "butterworth", cutoff: float | None = None) -> np.ndarray:
    """Analog `samples` [S,...] (S = frames * ratio, sample 0 at frame 0) low-passed by `method` and
    taken at the `frames` instants: [frames,...]. cutoff: the Butterworth's, Hz (default
    CUTOFF_FRACTION * frame_rate); it must lie below the frames' Nyquist frequency."""
    ratio = samples_per_frame(analog_rate, frame_rate)
    if samples.shape[0] < (frames - 1) * ratio + 1:
        raise InputError(f"{samples.shape[0]} analog samples cannot cover {frames} frames at {ratio} samples a frame")
    x = np.asarray(samples, dtype=np.float64).reshape(samples.shape[0], -1)
    if method == "butterworth":
        cutoff = CUTOFF_FRACTION * frame_rate if cutoff is None else float(cutoff)
        if not 0 < cutoff < frame_rate / 2:
            raise InputError(f"cut-off {cutoff} Hz must lie between 0 and the frames' Nyquist frequency, "
                             f"{frame_rate / 2} Hz")
        smooth = _butterworth(x, cutoff, analog_rate)
        taken = smooth[::ratio][:frames]
    elif method == "mean":
        taken = _centred_mean(x, ratio // 2, np.arange(frames) * ratio)
    else:
        raise InputError(f"unknown analog filter {method!r}; use 'butterworth' or 'mean'")
    return taken.reshape((frames, *samples.shape[1:]))


def _butterworth(x: np.ndarray, cutoff: float, rate: float) -> np.ndarray:
    """Zero-phase low-pass of each column of x [S,C], over each finite stretch on its own."""
    from scipy.signal import butter, sosfiltfilt

    sos = butter(ORDER, cutoff, fs=rate, output="sos")
    pad = 3 * (2 * len(sos) + 1)  # sosfiltfilt's default edge padding: a stretch must be longer
    out = np.full_like(x, np.nan)
    for c in range(x.shape[1]):  # a few channels per plate
        finite = np.isfinite(x[:, c])
        edges = np.flatnonzero(np.diff(np.concatenate(([0], finite.astype(np.int8), [0]))))
        for start, stop in zip(edges[::2], edges[1::2]):
            if stop - start > pad:
                out[start:stop, c] = sosfiltfilt(sos, x[start:stop, c])
    return out


def _centred_mean(x: np.ndarray, half: int, at: np.ndarray) -> np.ndarray:
    """The mean of x [S,C] over samples at-half .. at+half (those inside the file) for each index in at."""
    S = x.shape[0]
    finite = np.isfinite(x)
    total = np.concatenate((np.zeros((1, x.shape[1])), np.cumsum(np.where(finite, x, 0.0), axis=0)))
    bad = np.concatenate((np.zeros((1, x.shape[1])), np.cumsum(~finite, axis=0)))
    lo, hi = np.clip(at - half, 0, S), np.clip(at + half + 1, 0, S)
    mean = (total[hi] - total[lo]) / (hi - lo)[:, None]
    return np.where(bad[hi] - bad[lo] > 0, np.nan, mean)

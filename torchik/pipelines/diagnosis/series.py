"""Time series of the residual analysis: the Simpson mean and the central differences that compare
a gyro with its orientations, a zero-phase low-pass, and the autocorrelation time the scores count
independent samples with. Every function works along dim 0 (time) of a tensor [T,...]."""

from __future__ import annotations

import numpy as np
import torch


def simpson(x: torch.Tensor) -> torch.Tensor:
    """(x_{k-1} + 4 x_k + x_{k+1}) / 6 along dim 0, the ends kept: the mean of x over [t-dt, t+dt]
    that a central difference of its integral sees. x: [T,...] -> [T,...]."""
    if x.shape[0] < 3:
        return x.clone()
    out = x.clone()
    out[1:-1] = (x[:-2] + 4.0 * x[1:-1] + x[2:]) / 6.0
    return out


def central_rate(w: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
    """The rate a central difference of orientations, log(R_{k+1} R_{k-1}^T) / 2h, measures, from the
    world-frame rates w [T,...,3] at the same times -> [T,...,3]: their Simpson mean over [t-h, t+h]
    less the second Magnus term (h^2 / 3) w x dw/dt. The axis of a limb's rotation moves (coning),
    and without that term the two differ by O(h^2), not O(h^4): at 50 Hz a walking arm's consistent
    streams disagree by a steady 0.3 deg/s, which would pass for a gyro bias or a heading drift."""
    half = 0.5 * _span(time, w.dim())
    return simpson(w) - half.square() / 3.0 * torch.linalg.cross(w, central_difference(w, time), dim=-1)


def central_difference(x: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
    """dx/dt by central differences (one-sided at the ends). x: [T,...]; time [T] -> [T,...]."""
    ahead, behind = torch.cat((x[1:], x[-1:])), torch.cat((x[:1], x[:-1]))
    return (ahead - behind) / _span(time, x.dim())


def _span(time: torch.Tensor, dims: int) -> torch.Tensor:
    """t_{k+1} - t_{k-1} (one step at the ends) [T], shaped [T,1,...] to divide a [T,...] of `dims` dims."""
    span = torch.cat((time[1:], time[-1:])) - torch.cat((time[:1], time[:-1]))
    return span.view(-1, *([1] * (dims - 1)))


def lowpass(x: torch.Tensor, time: torch.Tensor, cutoff: float) -> torch.Tensor:
    """Zero-phase low-pass of x [T,...] along time: the spectrum kept below 0.7 cutoff, tapered by a
    raised cosine to zero at cutoff (Hz). The ends are mirrored first, so a constant stays a
    constant. Linear and time-invariant: fitting lowpass(e) = lowpass(X) theta is fitting e = X theta
    without the high-frequency noise of differentiated orientations."""
    T = x.shape[0]
    if T < 8:
        return x.clone()
    rate = 1.0 / float(torch.diff(time).median())
    x = x.movedim(0, -1)  # time last: the transforms run on contiguous series
    padded = torch.cat((x.flip(-1), x, x.flip(-1)), dim=-1)
    f = torch.fft.rfftfreq(3 * T, d=1.0 / rate).to(x.dtype)
    gain = torch.clamp((cutoff - f) / (0.3 * cutoff), 0.0, 1.0)
    gain = 0.5 - 0.5 * torch.cos(torch.pi * gain)
    spectrum = torch.fft.rfft(padded, dim=-1) * gain
    return torch.fft.irfft(spectrum, n=3 * T, dim=-1)[..., T:2 * T].movedim(-1, 0)


def autocorrelation_time(x: torch.Tensor, axis: int = 0) -> float:
    """Integrated autocorrelation time of a series (Sokal's window: sum lags until 5 tau), >= 1.
    x: [T,...] (the other dims averaged)."""
    T = x.shape[axis]
    if T < 4:
        return 1.0
    # in numpy: the scores call this on every candidate's short series, where torch's per-call cost dominates
    series = x.movedim(axis, 0).reshape(T, -1).double().numpy()
    series = series - series.mean(0)
    f = np.fft.rfft(series, n=2 * T, axis=0)
    acf = np.fft.irfft((f.real ** 2 + f.imag ** 2).sum(-1), n=2 * T)[:T]  # summed over the other dims
    if acf[0] <= 0:
        return 1.0
    taus = 1.0 + 2.0 * np.cumsum(acf[1:] / acf[0])  # tau summed up to lag k = 1, 2, ...
    stop = np.flatnonzero(np.arange(1, T) >= 5.0 * taus)
    tau = float(taus[stop[0]] if len(stop) else taus[-1])
    return float(min(max(tau, 1.0), T / 4.0))

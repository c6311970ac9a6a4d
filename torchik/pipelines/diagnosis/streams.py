"""What a recording's streams can tell, read from the data whatever a file or a converted `.npz` says.

- Is an angular velocity a gyro's, or a derivative of the orientations (C3D and BVH readers compute
  one; a user converting an IMU file often does too)? A derivative is a linear combination of the
  orientations' rates between neighbouring samples, whatever the scheme (a forward, backward or
  central difference, np.gradient on quaternions, a Savitzky-Golay filter): it carries the
  orientations' own noise, differentiated. A gyro measures the motion on its own and carries its own
  noise instead. So, above the band where the motion lives, the stream is explained by a short filter
  of the half-sample rates (`derivative_share` near 1) or it is not (a gyro: near 0; Xsens' MVNX gyros
  0.06 to 0.6, every derived stream of the shared data above 0.96). On a derived stream no gyro
  effect can be fitted: its "disagreement with its own orientations" is the differentiation's own error.
  A recording without noise in either stream cannot be told; it is taken as derived, and what a gyro
  would add to such a stream (a bias, a scale error) it would not show in that band either.
  A reader that computed the rates itself says so (`meta["angular_velocity"] = "derived"`), which is
  taken as it is.
- Do the segments share one clock? Optical markers are sampled together by one camera system: no
  segment can be late on the others unless the file declares separate streams
  (`meta["clock"] = "per_sensor"`); the C3D and BVH readers write `meta["clock"] = "shared"`.

The same test tells whether a base velocity is its positions' derivative (`derivative_share` on
position differences).
"""

from __future__ import annotations

import torch

from ...io.recording import Recording
from ...method import so3

DERIVED = 0.999  # share of the stream's high band a filter of the orientations' rates explains: a derivative
TAPS = 4  # half-sample rates on either side of a sample the filter combines (8 in all)


def half_step_rates(R: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
    """The world-frame rates between neighbouring orientations, log(R_{k+1} R_k^T) / (t_{k+1} - t_k):
    R [T,...,3,3], time [T] -> [T-1,...,3] (NaN where either orientation is)."""
    dt = torch.diff(time).view(-1, *([1] * (R.dim() - 2)))
    return so3.log(R[1:] @ R[:-1].transpose(-1, -2)) / dt


def derivative_share(rates: torch.Tensor, stream: torch.Tensor, time: torch.Tensor, coning: bool = True
                     ) -> torch.Tensor:
    """[...] the share of `stream`'s high band that a derivative of the series explains: rates
    [T-1,...,3], the half-sample rates of a series (half_step_rates, or position differences over dt),
    stream [T,...,3] a rate measured at the samples. Per series (the dims between time and the last),
    one filter of 2 TAPS taps shared by the three axes (and, with `coning`, of the cross products of
    neighbouring rates: a scheme on SO(3), a central logarithm or a quaternion derivative, differs
    from a linear one by them to second order) is fitted by least squares to the stream's high band
    (`high`; both sides high-passed alike), over the samples where all its inputs are finite. 1 for a
    derivative of the same series by any such scheme (above 0.999 on the shared data's tracked links,
    as read or through np.gradient of their quaternions), near 0 for an independent sensor's rate
    (Xsens' MVNX gyros 0.04 to 0.27; a simulated suit's raw gyros beside their own filters'
    orientations, which follow them above the filters' bandwidth, up to 0.99); NaN where the high band
    holds nothing."""
    T = stream.shape[0]
    if T < 2 * TAPS + 8:
        return torch.full(stream.shape[1:-1], float("nan"), dtype=stream.dtype)
    at = torch.arange(TAPS, T - TAPS)
    columns = [rates[at + j] for j in range(-TAPS, TAPS)]
    if coning and rates.shape[-1] == 3:
        columns += [torch.linalg.cross(rates[at + j], rates[at + j + 1], dim=-1) for j in range(-TAPS, TAPS - 1)]
    X = torch.stack(columns, dim=-1)  # [K,...,3,taps]
    y = stream[at]
    X, y = high(X), high(y)
    finite = torch.isfinite(X).flatten(-2).all(-1) & torch.isfinite(y).all(-1)  # [K-4,...]
    X, y = torch.where(finite[..., None, None], X, 0.0), torch.where(finite[..., None], y, 0.0)
    A = X.movedim(0, -3).flatten(-3, -2)  # [...,K 3,taps]: each series' samples and axes, stacked
    b = y.movedim(0, -2).flatten(-2, -1)  # [...,K 3]
    normal = A.transpose(-1, -2) @ A
    ridge = 1e-12 * normal.diagonal(dim1=-2, dim2=-1).mean(-1).clamp(min=1e-300)
    taps = torch.linalg.solve(normal + ridge[..., None, None] * torch.eye(A.shape[-1], dtype=A.dtype),
                              A.transpose(-1, -2) @ b[..., None])
    left = (b - (A @ taps)[..., 0]).square().sum(-1)
    power = b.square().sum(-1)
    return torch.where(power > 0, 1.0 - left / power.clamp(min=1e-300), torch.nan)


def high(x: torch.Tensor) -> torch.Tensor:
    """The second difference of x [K,...] along time, twice: [K-4,...]. A high-pass of gain
    16 sin^4(pi f / f_s), 1 % of its largest at a tenth of the Nyquist frequency and half of it at 0.6:
    what is left of a stream is the band where a walk has little and a sensor's noise most. Linear and
    time-invariant, so a filter of the rates that explains the stream explains it here too; and a few
    multiplications, where the low-pass' FFTs took a diagnosis seconds."""
    for _ in range(2):
        x = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return x


def derived_rates(R: torch.Tensor, w: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
    """[...] whether each angular velocity w [T,...,3] is the derivative of its orientations R
    [T,...,3,3] (module docstring): a share of DERIVED or more of its high band, or a high band with
    nothing in it."""
    return torch.nan_to_num(derivative_share(half_step_rates(R, time), w, time), nan=1.0) >= DERIVED


def derived_velocity(p: torch.Tensor, v: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
    """[...] whether each velocity v [T,...,3] is the derivative of its positions p [T,...,3]."""
    rates = torch.diff(p, dim=0) / torch.diff(time).view(-1, *([1] * (p.dim() - 1)))
    return torch.nan_to_num(derivative_share(rates, v, time, coning=False), nan=1.0) >= DERIVED


def declared_derived(recording: Recording) -> bool:
    """Whether the reader says it computed the angular velocity from the orientations
    (meta["angular_velocity"] == "derived": the C3D and BVH readers)."""
    return recording.meta.get("angular_velocity") == "derived"


def shared_clock(recording: Recording) -> bool:
    """Whether one clock samples every segment of the recording (module docstring): meta["clock"]
    "shared" (optical markers; the C3D and BVH readers say so), unless the file declares "per_sensor"."""
    return recording.meta.get("clock") == "shared"

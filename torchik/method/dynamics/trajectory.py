"""Inverse dynamics of a sampled trajectory (a tracked `Trajectory`, a `Motion`): its accelerations
from its velocities, low-passed, then differentiated.

A tracked velocity carries the noise of the measurements, and differentiating it amplifies that
noise in proportion to frequency. The velocity is therefore low-passed first, at `cutoff` (6 Hz by
default, Winter's choice for gait, which keeps the first ten harmonics of a 0.6 Hz stride), with zero
phase: the gain is G(f) = 1 / (1 + (f / cutoff)^4), a second-order Butterworth's run forward and
backward (fourth order, zero lag; one half at the cut-off), applied in the frequency domain to the
signal extended at both ends by its odd reflection (as filtfilt pads), so that the ends do not wrap.
The acceleration is the central difference of the low-passed velocity (one-sided at the ends), and
the velocity handed to the dynamics is the low-passed one, the configuration the trajectory's own.
Measured external wrenches want the same cut-off (`low_pass(wrenches, rate, cutoff)`): forces
filtered less than the motion they explain make spikes of their own at impacts.
"""

from __future__ import annotations

import math
from typing import Protocol, Sequence

import torch

from ...errors import InputError
from ..kinematics.model import KinematicModel
from .inverse import GRAVITY, InverseDynamics, inverse_dynamics

CUTOFF = 6.0  # Hz
REACH_SHARE = 0.1  # `reach`: the share of the filter's weight allowed beyond it
ROWS = 8192  # configurations per call of `inverse_dynamics`: memory stays a chunk's, however long the trajectory


class Sampled(Protocol):
    """What `trajectory_dynamics` reads: a `Trajectory` or a `Motion`."""

    time: torch.Tensor  # [T]
    base_position: torch.Tensor  # [T,B,3]
    base_rotation: torch.Tensor  # [T,B,3,3]
    joint_positions: torch.Tensor  # [T,B,n]
    velocity: torch.Tensor  # [T,B,6+n]


def trajectory_dynamics(model: KinematicModel, trajectory: Sampled, wrenches: torch.Tensor | None = None,
                        wrench_links: Sequence[str] | None = None, cutoff: float = CUTOFF,
                        gravity: Sequence[float] | torch.Tensor = GRAVITY) -> InverseDynamics:
    """The generalized forces along a trajectory sampled at a constant rate (T >= 3 samples), its
    accelerations the derivative of its velocity low-passed at `cutoff` Hz (the module's docstring).

    wrenches [T,B,L,6] (force; moment about the link's origin, world axes) on wrench_links (default
    every link), as `inverse_dynamics` takes them. Returns InverseDynamics with fields [T,B,...]."""
    time = trajectory.time
    T, B = trajectory.velocity.shape[:2]
    if T < 3:
        raise InputError(f"a trajectory of {T} samples: differentiating needs at least 3")
    step = time.diff().double()
    if not bool((step > 0).all()) or float((step - step.mean()).abs().max()) > 1e-6 * float(step.mean()):
        raise InputError("the trajectory's time is not evenly spaced: resample it to a constant rate first")
    rate = 1.0 / float(step.mean())
    if not 0.0 < cutoff < rate / 2:
        raise InputError(f"cutoff {cutoff} Hz: expected above 0 and below half the rate ({rate / 2:g} Hz)")
    velocity = low_pass(trajectory.velocity, rate, cutoff)
    acceleration = torch.gradient(velocity, spacing=1.0 / rate, dim=0)[0]
    # a model of one subject takes many samples per call; one of B subjects, a sample (its B rows) per call
    chunk = max(1, ROWS // B) if model.n_subjects == 1 else 1
    parts = []
    for start in range(0, T, chunk):
        cut = slice(start, start + chunk)
        p, R, s, v, a = (x[cut].flatten(0, 1) for x in (trajectory.base_position, trajectory.base_rotation,
                                                          trajectory.joint_positions, velocity, acceleration))
        w = None if wrenches is None else wrenches[cut].flatten(0, 1)
        parts.append(inverse_dynamics(model, p, R, s, v, a, w, wrench_links, gravity))
    forces = torch.cat([part.forces for part in parts]).reshape(T, B, -1)
    torques = forces[..., 6:]
    return InverseDynamics(forces, forces[..., :6], torques, torques * velocity[..., 6:])


def low_pass(x: torch.Tensor, rate: float, cutoff: float = CUTOFF) -> torch.Tensor:
    """x [T,...] sampled at `rate` Hz, low-passed at `cutoff` Hz with zero phase: gain
    1 / (1 + (f / cutoff)^4) in the frequency domain, the ends padded by odd reflection."""
    T = x.shape[0]
    pad = min(T - 1, int(3 * rate / cutoff))  # three periods of the cut-off: the filter's memory is shorter
    head = 2 * x[:1] - x[1:pad + 1].flip(0)
    tail = 2 * x[-1:] - x[-pad - 1:-1].flip(0)
    extended = torch.cat((head, x, tail))
    f = torch.fft.rfftfreq(extended.shape[0], d=1.0 / rate, dtype=x.dtype, device=x.device)
    gain = (1.0 / (1.0 + (f / cutoff) ** 4)).reshape(-1, *([1] * (x.dim() - 1)))
    smooth = torch.fft.irfft(torch.fft.rfft(extended, dim=0) * gain, n=extended.shape[0], dim=0)
    return smooth[pad:pad + T]


def reach(rate: float, cutoff: float = CUTOFF, share: float = REACH_SHARE) -> int:
    """The samples either side of a sample that hold all but `share` of `low_pass`'s weight at `rate`
    and `cutoff` (Hz; the absolute values of its impulse response): a low-passed sample depends on
    those, so one within `reach` of a sample a signal lacks is not the filtered signal's. 6 at
    6 Hz and 100 Hz (90 % of the weight within 60 ms)."""
    half = int(math.ceil(8 * rate / cutoff))  # the response has decayed far below `share` by then
    impulse = torch.zeros(2 * half + 1, dtype=torch.float64)
    impulse[half] = 1.0
    weight = low_pass(impulse, rate, cutoff).abs()
    beyond = torch.stack([weight[:half - k].sum() + weight[half + k + 1:].sum() for k in range(half + 1)])
    return int((beyond <= share * weight.sum()).nonzero()[0, 0])

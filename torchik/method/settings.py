"""The tracker's settings, the one place their defaults are written."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..errors import InputError
from .limits import LimitSettings

SCHEMES = {"midpoint": 2.0, "paper": 2.0}  # discretisation -> linear stability bound on K dt


@dataclass(frozen=True)
class TrackerSettings:
    """How `DynamicalIK` tracks.

    position_gain, orientation_gain: K per block (1/s), a scalar or one per target; dt: the nominal
    time step (s); scheme: 'midpoint' (second order) or 'paper' (the paper's literal law);
    rotation_integrator: 'baumgarte' (rho: baumgarte_gain, 1/s) or 'exp'; damping: lambda of
    ||nu||^2; limits: the joint limits' velocity bounds; backend: the QP solver, 'auto' (batched
    for a batch or on CUDA, else PIQP), 'piqp' or 'batched'; max_gap: a time step longer than this
    many nominal steps is a gap, after which the tracker restarts from the targets (a new segment);
    compile: replay the usual step compiled (`captured.py`): for one subject and for batches, the
    faster step on long runs, after a first capture of seconds (a minute or two the first time on a
    machine).
    """

    position_gain: float = 20.0
    orientation_gain: float = 20.0
    dt: float = 0.01
    scheme: str = "midpoint"
    rotation_integrator: str = "baumgarte"
    baumgarte_gain: float = 100.0
    damping: float = 1e-9
    limits: LimitSettings = field(default_factory=LimitSettings)
    backend: str = "auto"
    max_gap: float = 5.0
    compile: bool = False


def check_settings(settings: TrackerSettings) -> None:
    """InputError naming the first setting a tracker cannot run with."""
    from .integrate import ROTATION_INTEGRATORS  # the registries live beside what they register
    from .qp import BACKENDS

    if settings.scheme not in SCHEMES:
        raise InputError(f"unknown scheme {settings.scheme!r}; valid: {', '.join(SCHEMES)}")
    if settings.rotation_integrator not in ROTATION_INTEGRATORS:
        raise InputError(f"unknown rotation integrator {settings.rotation_integrator!r}; "
                         f"valid: {', '.join(ROTATION_INTEGRATORS)}")
    if not 0 < settings.dt < math.inf:
        raise InputError(f"dt must be positive and finite, got {settings.dt}")
    if not 1 < settings.max_gap:  # NaN too; inf: no gap ever restarts
        raise InputError(f"max_gap must be above 1 nominal step, got {settings.max_gap}")
    if isinstance(settings.backend, str) and settings.backend != "auto" and settings.backend not in BACKENDS:
        raise InputError(f"unknown QP backend {settings.backend!r}; valid: auto, {', '.join(BACKENDS)}")

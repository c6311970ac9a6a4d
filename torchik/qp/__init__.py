"""The step's quadratic program and the solvers behind one interface.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h

`PiqpBackend` solves it subject by subject with PIQP through qpsolvers. Another backend (a
batched solver in torch) fills the same `QPBackend.solve`.
"""

from .base import QPBackend, QPProblem, QPSolution, clipped_fallback, unconstrained_if_feasible
from .piqp_backend import PiqpBackend

BACKENDS = {"piqp": PiqpBackend}


def make_backend(name: str, **options) -> QPBackend:
    """A backend by name ('piqp')."""
    from ..errors import InputError

    if name not in BACKENDS:
        raise InputError(f"unknown QP backend {name!r}; valid: {', '.join(BACKENDS)}")
    return BACKENDS[name](**options)


__all__ = ["QPBackend", "QPProblem", "QPSolution", "PiqpBackend", "clipped_fallback", "unconstrained_if_feasible", "make_backend", "BACKENDS"]

"""The step's quadratic program and the solvers behind one interface.

    minimise 1/2 x^T H x + g^T x   subject to   lb <= x <= ub,   G x <= h

`PiqpBackend` solves it subject by subject with PIQP through qpsolvers; `BatchedBackend` solves
the whole batch at once in torch (CPU or GPU) by a primal-dual active-set method, using the
step's tree structure (`TreeHessian`) when the problem carries it.
"""

from .base import QPBackend, QPProblem, QPSolution, Unconstrained, clipped_fallback, unconstrained
from .batched import BatchedBackend
from .dense import DenseHessian
from .piqp_backend import PiqpBackend
from .tree import JointTree, TreeHessian

BACKENDS = {"piqp": PiqpBackend, "batched": BatchedBackend}


def make_backend(name: str, **options) -> QPBackend:
    """A backend by name ('piqp' or 'batched')."""
    from ...errors import InputError

    if name not in BACKENDS:
        raise InputError(f"unknown QP backend {name!r}; valid: {', '.join(BACKENDS)}")
    return BACKENDS[name](**options)


__all__ = ["QPBackend", "QPProblem", "QPSolution", "PiqpBackend", "BatchedBackend", "DenseHessian", "JointTree",
           "TreeHessian", "Unconstrained", "clipped_fallback", "unconstrained", "make_backend",
           "BACKENDS"]

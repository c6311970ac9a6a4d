"""Dynamics on the kinematic tree: the generalized forces that produce a motion (`inverse.py`), the
same captured and replayed compiled (`compiled.py`), and for a tracked trajectory, its accelerations
from a filtered derivative (`trajectory.py`)."""

from .compiled import CompiledInverseDynamics
from .inverse import GRAVITY, InverseDynamics, inverse_dynamics
from .trajectory import CUTOFF, low_pass, reach, trajectory_dynamics

__all__ = ["GRAVITY", "CUTOFF", "InverseDynamics", "inverse_dynamics", "trajectory_dynamics", "low_pass", "reach",
           "CompiledInverseDynamics"]

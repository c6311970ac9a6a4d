"""Floating-base forward kinematics and Jacobians of a URDF tree, batched in torch.

The URDF is parsed once (with pytorch-kinematics' URDF parser) and compiled into a frozen
`KinematicTree` (`urdf.py`): a *skeleton* of frames (the base link and the child frame of every
movable joint) ordered by depth, with the constant transform from each frame's parent to its
joint. Every other link (fixed to a skeleton frame) is that frame's pose times a constant offset.
A `KinematicModel` (`model.py`) holds the tree and the tensors derived from it (`tensors.py`); a
call then does tensor work only (`compose.py`): the joint rotations of all frames at once, one
composition per tree level, and all Jacobian columns from one batched product.

Conventions: configuration `q = (p_B [B,3], R_B [B,3,3], s [B,n])`; velocity
`nu = (p_dot_B, omega_B, s_dot)` with the base linear and angular velocity in the world frame
(iDynTree's MIXED representation). A link Jacobian maps `nu` to the world-frame linear velocity
of the link origin and the world-frame angular velocity of the link: `[B,L,6,6+n]`, rows
(linear; angular).
"""

from .model import KinematicModel, LinearLimits
from .selection import LinkKinematics, LinkSelection
from .urdf import KinematicTree, compile_tree, load_tree, read_urdf

__all__ = ["KinematicModel", "LinearLimits", "LinkKinematics", "LinkSelection", "KinematicTree", "compile_tree",
           "load_tree", "read_urdf"]

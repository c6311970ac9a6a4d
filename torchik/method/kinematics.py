"""Floating-base forward kinematics and Jacobians of a URDF tree, batched in torch.

The URDF is parsed once (with pytorch-kinematics' URDF parser) and compiled into tensors:
a *skeleton* of frames (the base link and the child frame of every movable joint) ordered by
depth, with the constant transform from each frame's parent to its joint. Every other link
(fixed to a skeleton frame) is that frame's pose times a constant offset. A call then does
tensor work only: the joint rotations of all frames at once, one composition per tree level,
and all Jacobian columns from one batched product.

Conventions: configuration `q = (p_B [B,3], R_B [B,3,3], s [B,n])`; velocity
`nu = (p_dot_B, omega_B, s_dot)` with the base linear and angular velocity in the world frame
(iDynTree's MIXED representation). A link Jacobian maps `nu` to the world-frame linear velocity
of the link origin and the world-frame angular velocity of the link: `[B,L,6,6+n]`, rows
(linear; angular).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import contextlib
import copy
import io

import numpy as np
import torch

from ..errors import InputError, ModelError, UnknownLinkError
from . import so3

MOVABLE = ("revolute", "continuous")


@dataclass(frozen=True)
class LinearLimits:
    """General linear joint limits `A s <= b` (for instance iCub's coupled shoulder).

    A: [m, n], b: [m]; `names` labels each row.
    """

    A: torch.Tensor
    b: torch.Tensor
    names: tuple[str, ...] = ()

    def to(self, dtype=None, device=None) -> "LinearLimits":
        return LinearLimits(self.A.to(dtype=dtype, device=device), self.b.to(dtype=dtype, device=device), self.names)


@dataclass(frozen=True)
class LinkKinematics:
    """Poses and Jacobians of a selection of links for a batch of configurations.

    rotation: [B,L,3,3] link-to-world; position: [B,L,3] world, or None (`rotations`);
    jacobian: [B,L_j,6,6+n] mixed representation, rows (linear; angular), or None if not asked;
    joint_axes: [B,n,3] every joint's axis in the world frame, or None if not asked.
    """

    rotation: torch.Tensor
    position: torch.Tensor | None
    jacobian: torch.Tensor | None
    joint_axes: torch.Tensor | None = None


@dataclass(frozen=True)
class LinkSelection:
    """A list of links compiled for repeated calls (indices, constant offsets, ancestor mask)."""

    names: tuple[str, ...]
    anchor: torch.Tensor  # [L] skeleton frame each link is fixed to
    offset_rotation: torch.Tensor  # [L,3,3,S] link frame in its anchor frame (batch last)
    offset_position: torch.Tensor  # [L,3,S]
    ancestor_mask: torch.Tensor  # [L,n] 1 where joint j moves link L
    pair_link: torch.Tensor  # [P] the (link, joint) pairs where the mask is 1 ...
    pair_joint: torch.Tensor  # [P]
    pair_flat_index: torch.Tensor  # [6P] ... and where their columns go in a flattened [L,6,6+n]
    offsets_are_identity: bool


@dataclass
class _Geometry:
    """Per-subject constants of the tree, batch-last: trailing dimension S (1, or one per batch row).

    Batch-last ("structure of arrays") so that each tree level is a contiguous slab and each
    3x3 product is vectorised along the batch, which is what makes large batches fast on CPU.
    """

    offset_rotation: torch.Tensor  # [F,3,3,S] joint frame (at zero angle) in the parent frame
    offset_position: torch.Tensor  # [F,3,S]
    rotation_sin_term: torch.Tensor  # [F,3,3,S] offset_rotation @ hat(axis)
    rotation_cos_term: torch.Tensor  # [F,3,3,S] offset_rotation @ hat(axis)^2
    link_rotation: torch.Tensor  # [N,3,3,S] every URDF link in its anchor frame
    link_position: torch.Tensor  # [N,3,S]

    def to(self, dtype=None, device=None) -> "_Geometry":
        return _Geometry(*(t.to(dtype=dtype, device=device) for t in vars(self).values()))


# Below this batch size, per-operation overhead dominates: use one matmul per product and
# compose frames by pointer jumping (fewer, larger operations). Above it, the work dominates:
# vectorise along the batch and compose level by level (least work).
SMALL_BATCH = 32


def _matmul_soa(A: torch.Tensor, B: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """3x3 products in batch-last layout: A [...,3,3,b], B [...,3,3,b] -> [...,3,3,b]."""
    if A.shape[-1] <= SMALL_BATCH:
        C = torch.matmul(A.movedim(-1, -3), B.movedim(-1, -3)).movedim(-3, -1)
        return C if out is None else out.copy_(C)
    out = torch.mul(A[..., :, 0:1, :], B[..., 0:1, :, :], out=out)
    out.addcmul_(A[..., :, 1:2, :], B[..., 1:2, :, :])
    out.addcmul_(A[..., :, 2:3, :], B[..., 2:3, :, :])
    return out


def _matvec_soa(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Matrix-vector products in batch-last layout: A [...,3,3,b], v [...,3,b] -> [...,3,b]."""
    if A.shape[-1] <= SMALL_BATCH:
        return torch.matmul(A.movedim(-1, -3), v.movedim(-1, -2).unsqueeze(-1)).squeeze(-1).movedim(-2, -1)
    return (A * v.unsqueeze(-3)).sum(-2)


def _read_urdf(source: str | Path):
    """Parse a URDF file (or XML text) with pytorch-kinematics' parser; errors name the file."""
    from pytorch_kinematics.urdf_parser_py.urdf import URDF

    if isinstance(source, Path) or (isinstance(source, str) and not source.lstrip().startswith("<")):
        path = Path(source)
        if not path.is_file():
            raise ModelError(f"URDF file not found: {path}")
        text, where = path.read_text(), str(path)
    else:
        text, where = str(source), "<URDF text>"
    # The parser prints a line for every tag it does not know (sensors, gazebo); keep them quiet.
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        try:
            robot = URDF.from_xml_string(text)
        except Exception as exc:  # the parser raises bare XML and assertion errors
            raise ModelError(f"{where}: not a valid URDF ({type(exc).__name__}: {exc})") from exc
    if not robot.links:
        raise ModelError(f"{where}: the URDF has no links")
    return robot, where


def _origin(origin) -> tuple[np.ndarray, np.ndarray]:
    """URDF <origin> as (R [3,3], p [3]) in float64."""
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = np.array(origin.xyz if origin.xyz is not None else [0, 0, 0], dtype=np.float64)
    rpy = np.array(origin.rpy if origin.rpy is not None else [0, 0, 0], dtype=np.float64)
    return so3.rpy_to_matrix(torch.from_numpy(rpy)).numpy(), xyz


def _hat(a: np.ndarray) -> np.ndarray:
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


class KinematicModel:
    """A floating-base kinematic tree compiled from a URDF to tensors.

    Build it once (`KinematicModel.from_urdf(path)`), then call `forward` for batches of
    configurations. Joints are ordered as in the URDF (movable ones only); `joint_names`
    gives the order of `s`. Joint limits: `lower`, `upper` [n] (infinite for continuous joints),
    `linear_limits` (A s <= b) when the model has coupled limits.
    """

    def __init__(self, robot, where: str, name: str | None = None, dtype=torch.float64, device="cpu"):
        self.name = name or robot.name
        self.source = where
        links = [link.name for link in robot.links]
        joints = list(robot.joints)
        by_child = {}
        children: dict[str, list] = {name_: [] for name_ in links}
        for j in joints:
            if j.parent not in children or j.child not in children:
                raise ModelError(f"{where}: joint {j.name!r} connects unknown links {j.parent!r} -> {j.child!r}")
            if j.type not in MOVABLE + ("fixed",):
                raise ModelError(
                    f"{where}: joint {j.name!r} has type {j.type!r}; torchik supports revolute, continuous and fixed joints"
                )
            if j.child in by_child:
                raise ModelError(f"{where}: link {j.child!r} has two parent joints; a URDF must be a tree")
            by_child[j.child] = j
            children[j.parent].append(j)
        roots = [name_ for name_ in links if name_ not in by_child]
        if len(roots) != 1:
            raise ModelError(f"{where}: expected one root link, found {roots}")
        self.base_link = roots[0]

        # Breadth-first walk: every link gets its anchor (skeleton frame) and offset from it.
        frame_of_link = {self.base_link: 0}
        link_offset = {self.base_link: (np.eye(3), np.zeros(3))}
        frame_parent, frame_depth, frame_joint_name = [-1], [0], [None]
        frame_offset = [(np.eye(3), np.zeros(3))]
        frame_axis = [np.zeros(3)]
        order = deque([self.base_link])
        visited = []
        while order:
            parent = order.popleft()
            visited.append(parent)
            Ra, pa = link_offset[parent]  # parent link in its anchor frame
            for j in children[parent]:
                Rj, pj = _origin(j.origin)
                R_in_anchor, p_in_anchor = Ra @ Rj, pa + Ra @ pj
                if j.type == "fixed":
                    frame_of_link[j.child] = frame_of_link[parent]
                    link_offset[j.child] = (R_in_anchor, p_in_anchor)
                else:
                    axis = np.array(j.axis if j.axis is not None else [1.0, 0.0, 0.0], dtype=np.float64)
                    if np.linalg.norm(axis) < 1e-12:
                        raise ModelError(f"{where}: joint {j.name!r} has a zero axis")
                    frame_of_link[j.child] = len(frame_parent)
                    link_offset[j.child] = (np.eye(3), np.zeros(3))
                    frame_parent.append(frame_of_link[parent])
                    frame_depth.append(frame_depth[frame_of_link[parent]] + 1)
                    frame_joint_name.append(j.name)
                    frame_offset.append((R_in_anchor, p_in_anchor))
                    frame_axis.append(axis / np.linalg.norm(axis))
                order.append(j.child)
        if len(visited) != len(links):
            raise ModelError(f"{where}: links not connected to the root: {sorted(set(links) - set(visited))}")

        # Joint order: as the movable joints appear in the URDF (what other tools show users).
        self.joint_names = tuple(j.name for j in joints if j.type in MOVABLE)
        joint_index = {name_: i for i, name_ in enumerate(self.joint_names)}
        self.n_dof = len(self.joint_names)
        limits = {j.name: j.limit for j in joints}
        types = {j.name: j.type for j in joints}
        lower, upper = [], []
        for name_ in self.joint_names:
            lim = limits[name_]
            if types[name_] == "continuous" or lim is None or lim.lower is None or lim.upper is None:
                lower.append(-np.inf)
                upper.append(np.inf)
            else:
                lower.append(float(lim.lower))
                upper.append(float(lim.upper))
        self.link_names = tuple(links)
        self._link_index = {name_: i for i, name_ in enumerate(links)}

        # Skeleton frames sorted by depth so that each tree level is one contiguous slice.
        n_frames = len(frame_parent)
        order_by_depth = sorted(range(n_frames), key=lambda f: (frame_depth[f], f))
        new_index = {old: new for new, old in enumerate(order_by_depth)}
        self._n_frames = n_frames
        parent = [new_index[frame_parent[f]] if f else -1 for f in order_by_depth]
        depth = [frame_depth[f] for f in order_by_depth]
        self._frame_joint = [joint_index[frame_joint_name[f]] if f else -1 for f in order_by_depth]
        levels = []
        for d in range(1, max(depth) + 1):
            members = [i for i in range(n_frames) if depth[i] == d]
            levels.append((members[0], members[-1] + 1, [parent[i] for i in members]))
        self._levels_py = levels
        self._frame_parent_py = parent
        # frame of each joint (its child frame), to read the joint axis and origin in the world
        joint_frame = [0] * self.n_dof
        for f, j in enumerate(self._frame_joint):
            if j >= 0:
                joint_frame[j] = f
        self._joint_frame_py = joint_frame

        offsets = [frame_offset[f] for f in order_by_depth]
        axes = np.stack([frame_axis[f] for f in order_by_depth])
        R_off = np.stack([o[0] for o in offsets])
        p_off = np.stack([o[1] for o in offsets])
        K = np.stack([_hat(a) for a in axes])

        def soa(a: np.ndarray) -> torch.Tensor:  # [F,...] -> [F,...,1], batch last
            return torch.from_numpy(np.ascontiguousarray(a))[..., None]

        geometry = _Geometry(
            offset_rotation=soa(R_off),
            offset_position=soa(p_off),
            rotation_sin_term=soa(R_off @ K),
            rotation_cos_term=soa(R_off @ K @ K),
            link_rotation=soa(np.stack([link_offset[n_][0] for n_ in links])),
            link_position=soa(np.stack([link_offset[n_][1] for n_ in links])),
        )
        self._link_anchor_py = [new_index[frame_of_link[n_]] for n_ in links]
        self._axes_np = axes
        self._ancestor_np = self._ancestors()
        # Pointer jumping (for small batches): after round r every frame holds its pose relative
        # to its 2^r-th ancestor; frame F is the world, its own parent.
        jumps, up = [], np.array([p if p >= 0 else n_frames for p in parent] + [n_frames])
        while not np.all(up == n_frames):
            jumps.append(up.copy())
            up = up[up]
        self._jumps_py = jumps
        self._set_tensors(geometry, torch.tensor(lower), torch.tensor(upper), dtype, device)
        self.linear_limits: LinearLimits | None = None

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_urdf(cls, source: str | Path, name: str | None = None, dtype=torch.float64, device="cpu") -> "KinematicModel":
        """Compile a URDF file (or its XML text). Raises ModelError naming the file and problem."""
        robot, where = _read_urdf(source)
        return cls(robot, where, name=name, dtype=dtype, device=device)

    def _ancestors(self) -> np.ndarray:
        """[F, n] 1 where joint j lies on the path from the base to skeleton frame f."""
        mask = np.zeros((self._n_frames, self.n_dof))
        for f in range(self._n_frames):  # build time only
            g = f
            while g > 0:
                mask[f, self._frame_joint[g]] = 1.0
                g = self._frame_parent_py[g]
        return mask

    def _set_tensors(self, geometry: _Geometry, lower, upper, dtype, device) -> None:
        self.dtype, self.device = dtype, torch.device(device)
        self._geometry = geometry.to(dtype=dtype, device=self.device)
        self.lower = lower.to(dtype=dtype, device=self.device)
        self.upper = upper.to(dtype=dtype, device=self.device)
        long = dict(dtype=torch.long, device=self.device)
        self._levels = [(a, b, torch.tensor(p, **long)) for a, b, p in self._levels_py]
        self._jumps = [torch.tensor(j, **long) for j in self._jumps_py]
        template = torch.zeros(self._n_frames + 1, 4, 4, dtype=dtype, device=self.device)
        template[:, 3, 3] = 1.0
        template[-1] = torch.eye(4, dtype=dtype, device=self.device)
        self._homogeneous_template = template
        self._frame_joint_t = torch.tensor([max(j, 0) for j in self._frame_joint], **long)
        self._frame_is_joint = torch.tensor([[float(j >= 0)] for j in self._frame_joint], dtype=dtype, device=self.device)
        self._joint_frame = torch.tensor(self._joint_frame_py, **long)
        axes = torch.from_numpy(self._axes_np).to(dtype=dtype, device=self.device)
        self._joint_axes = axes[self._joint_frame][:, :, None]  # [n,3,1] in each joint frame
        self._link_anchor = torch.tensor(self._link_anchor_py, **long)
        self._ancestor = torch.from_numpy(self._ancestor_np).to(dtype=dtype, device=self.device)
        self._selections: dict[tuple[str, ...], LinkSelection] = {}
        self._set_small_batch_rotations()

    def _set_small_batch_rotations(self) -> None:
        """Batch-first constants of the rotation-only kinematics for small batches ([S,F-1,3,3], frames
        1..F-1; frame 0, the base, is the base rotation itself, and the world, frame F, the identity):
        R_local = (R_off + C) + sin S - cos C, with S = R_off hat(axis) and C = R_off hat(axis)^2."""
        g = self._geometry
        first = lambda t: t.permute(3, 0, 1, 2)[:, 1:].contiguous()  # noqa: E731  [F,3,3,S] -> [S,F-1,3,3]
        self._small_offset = first(g.offset_rotation + g.rotation_cos_term)
        self._small_sin = first(g.rotation_sin_term)
        self._small_cos = first(g.rotation_cos_term)
        self._small_angle_index = self._frame_joint_t[1:]
        self._world = torch.eye(3, dtype=self.dtype, device=self.device)[None, None]  # [1,1,3,3]
        self._joint_axes_row = self._joint_axes.transpose(1, 2)  # [n,1,3]

    def to(self, dtype=None, device=None) -> "KinematicModel":
        """A copy with tensors in another dtype and/or on another device."""
        other = copy.copy(self)
        other._set_tensors(self._geometry, self.lower, self.upper, dtype or self.dtype, device or self.device)
        if self.linear_limits is not None:
            other.linear_limits = self.linear_limits.to(dtype or self.dtype, device or self.device)
        return other

    @property
    def n_subjects(self) -> int:
        """How many subjects' geometries the model holds (1, or one per batch row)."""
        return self._geometry.offset_position.shape[-1]

    def same_topology(self, other: "KinematicModel") -> bool:
        """True when both models have the same joints, links, tree and axes (dimensions may differ)."""
        return (other.joint_names == self.joint_names and other.link_names == self.link_names
                and other._frame_parent_py == self._frame_parent_py and np.allclose(other._axes_np, self._axes_np))

    @staticmethod
    def stack(models: Sequence["KinematicModel"]) -> "KinematicModel":
        """One model whose batch rows are different subjects of the same topology.

        The result's `forward` expects B == len(models), row i using models[i]'s dimensions.
        Limits are taken from the first model (they must agree).
        """
        first = models[0]
        for m in models[1:]:
            if not first.same_topology(m):
                raise ModelError(f"cannot stack {m.source} with {first.source}: different topology")
            if not (torch.equal(m.lower, first.lower) and torch.equal(m.upper, first.upper)):
                raise ModelError(f"cannot stack {m.source} with {first.source}: different joint limits")
        out = copy.copy(first)
        geoms = [m._geometry.to(dtype=first.dtype, device=first.device) for m in models]
        stacked = _Geometry(*(torch.cat([vars(g)[k] for g in geoms], dim=-1) for k in vars(geoms[0])))
        out._set_tensors(stacked, first.lower, first.upper, first.dtype, first.device)
        out.linear_limits = first.linear_limits
        out.name = f"{first.name} x{len(models)}"
        return out

    # ------------------------------------------------------------------ queries
    def select(self, links: Sequence[str]) -> LinkSelection:
        """Compile a list of link names for `forward` (cached). Unknown names raise UnknownLinkError."""
        key = tuple(links)
        if key in self._selections:
            return self._selections[key]
        unknown = [n for n in key if n not in self._link_index]
        if unknown:
            raise UnknownLinkError(
                f"model {self.name!r} has no link(s) {unknown}; valid links: {', '.join(self.link_names)}"
            )
        if not key:
            raise InputError("select at least one link")
        idx = torch.tensor([self._link_index[n] for n in key], dtype=torch.long, device=self.device)
        anchor = self._link_anchor[idx]
        R = self._geometry.link_rotation[idx]
        p = self._geometry.link_position[idx]
        eye = torch.eye(3, dtype=self.dtype, device=self.device)[..., None]
        mask = self._ancestor[anchor]  # [L,n]
        link_of_pair, joint_of_pair = mask.nonzero(as_tuple=True)
        width = 6 + self.n_dof
        # flat position of (link l, row r, column 6 + j) in a [L,6,6+n] Jacobian
        rows = torch.arange(6, device=self.device)
        flat = (link_of_pair[:, None] * 6 + rows) * width + 6 + joint_of_pair[:, None]
        selection = LinkSelection(
            names=key,
            anchor=anchor,
            offset_rotation=R,
            offset_position=p,
            ancestor_mask=mask,
            pair_link=link_of_pair,
            pair_joint=joint_of_pair,
            pair_flat_index=flat.reshape(-1),
            offsets_are_identity=bool((R - eye).abs().max() == 0 and p.abs().max() == 0),
        )
        self._selections[key] = selection
        return selection

    def _check(self, name: str, t: torch.Tensor, shape: tuple) -> None:
        if not isinstance(t, torch.Tensor):
            raise InputError(f"{name}: expected a torch.Tensor of shape {list(shape)}, got {type(t).__name__}")
        if tuple(t.shape) != shape:
            raise InputError(f"{name}: expected shape {list(shape)}, got {list(t.shape)}")
        if t.dtype != self.dtype or t.device != self.device:
            raise InputError(
                f"{name}: expected dtype {self.dtype} on {self.device} (the model's; use model.to(...)), "
                f"got {t.dtype} on {t.device}"
            )

    def forward(
        self,
        base_position: torch.Tensor,
        base_rotation: torch.Tensor,
        joint_positions: torch.Tensor,
        links: Sequence[str] | LinkSelection,
        jacobian: bool = True,
        out: LinkKinematics | None = None,
        jacobian_links: Sequence[str] | LinkSelection | None = None,
        joint_axes: bool = False,
    ) -> LinkKinematics:
        """World poses and mixed-representation Jacobians of the chosen links.

        base_position: [B,3]; base_rotation: [B,3,3] base-to-world; joint_positions: [B,n]
        (order `joint_names`); links: names or a `select(...)` result.
        Returns LinkKinematics with rotation [B,L,3,3], position [B,L,3], jacobian [B,L,6,6+n].

        jacobian_links: Jacobians of other links than the poses (default: the same);
        joint_axes: also return the joints' world axes [B,n,3] (what the orientation part of a
        tracking task needs, see torchik.task).
        out: buffers from `empty_output(B, links, ...)` to write into instead of allocating (what a
        tracker does every step: a fresh 80 MB Jacobian costs more in page faults than in
        arithmetic). The Jacobian's structural zeros are written when the buffer is made and not
        again, so write nothing into it yourself.
        """
        B = base_position.shape[0] if isinstance(base_position, torch.Tensor) and base_position.dim() else -1
        self._check("base_position", base_position, (B, 3))
        self._check("base_rotation", base_rotation, (B, 3, 3))
        self._check("joint_positions", joint_positions, (B, self.n_dof))
        if self.n_subjects not in (1, B):
            raise InputError(f"this model holds {self.n_subjects} subjects; the batch has {B} rows")
        sel = self._selection(links)
        jsel = sel if jacobian_links is None else self._selection(jacobian_links)
        if out is None:
            out = self.empty_output(B, sel, jacobian, jsel)
        elif out.position.shape != (B, len(sel.names), 3) or (
                jacobian and (out.jacobian is None or out.jacobian.shape[1] != len(jsel.names))):
            raise InputError(f"out: expected buffers from empty_output({B}, links, ...) for {len(sel.names)} links")

        R, p = self._frame_poses(base_position, base_rotation, joint_positions)  # [F,3,3,B], [F,3,B]
        p_link = self._link_poses(R, p, sel, out)
        axis = None
        if jacobian or joint_axes:
            axis = self._world_axes(R)
        if jacobian:
            p_jacobian = p_link if jsel is sel else self._link_poses(R, p, jsel, None)
            self._jacobian(base_position, axis, p, p_jacobian, jsel, out.jacobian)
        if joint_axes:
            return LinkKinematics(out.rotation, out.position, out.jacobian, axis.permute(2, 0, 1))
        return out

    __call__ = forward

    def rotations(self, base_rotation: torch.Tensor, joint_positions: torch.Tensor,
                  links: Sequence[str] | LinkSelection, joint_axes: bool = False) -> LinkKinematics:
        """World rotations of the chosen links and, optionally, every joint's world axis: all that
        orientation targets need (no positions, no Jacobians), so less work than `forward`.

        base_rotation: [B,3,3] base-to-world; joint_positions: [B,n]; links: names or a
        `select(...)` result. Returns LinkKinematics with rotation [B,L,3,3], joint_axes [B,n,3]
        (None unless asked), position and jacobian None.
        """
        B = base_rotation.shape[0] if isinstance(base_rotation, torch.Tensor) and base_rotation.dim() else -1
        self._check("base_rotation", base_rotation, (B, 3, 3))
        self._check("joint_positions", joint_positions, (B, self.n_dof))
        if self.n_subjects not in (1, B):
            raise InputError(f"this model holds {self.n_subjects} subjects; the batch has {B} rows")
        sel = self._selection(links)
        if B > SMALL_BATCH or not self._jumps:
            R, _ = self._frame_poses(None, base_rotation, joint_positions)  # [F,3,3,B]
            R_link = R.index_select(0, sel.anchor)
            if not sel.offsets_are_identity:
                R_link = _matmul_soa(R_link, sel.offset_rotation.expand_as(R_link))
            axes = self._world_axes(R).permute(2, 0, 1).contiguous() if joint_axes else None
            return LinkKinematics(R_link.permute(3, 0, 1, 2).contiguous(), None, None, axes)
        R = self._frame_rotations_small(base_rotation, joint_positions)  # [B,F+1,3,3]
        R_link = R.index_select(1, sel.anchor)
        if not sel.offsets_are_identity:
            R_link = R_link @ sel.offset_rotation.permute(3, 0, 1, 2)
        # the world axis of joint j: its frame's rotation times the axis in that frame
        axes = (R.index_select(1, self._joint_frame) * self._joint_axes_row).sum(-1) if joint_axes else None
        return LinkKinematics(R_link, None, None, axes)

    def _world_axes(self, R: torch.Tensor) -> torch.Tensor:
        """Every joint's world axis from the frame rotations R [F,3,3,B] (batch last): [n,3,B]."""
        return _matvec_soa(R.index_select(0, self._joint_frame), self._joint_axes)

    def _frame_rotations_small(self, R_B: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """World rotations of every skeleton frame, then the world's identity: [B,F+1,3,3].

        Pointer jumping on batch-first 3x3 rotations: a few large operations, which is what costs
        least when the batch is small and each operation's overhead dominates."""
        angle = s.index_select(1, self._small_angle_index)[:, :, None, None]  # [B,F-1,1,1]
        R_local = torch.addcmul(torch.addcmul(self._small_offset, torch.sin(angle), self._small_sin),
                                torch.cos(angle), self._small_cos, value=-1.0)
        # the base frame's offset is the identity; the world is its own parent in the jumps
        R = torch.cat((R_B.unsqueeze(1), R_local, self._world.expand(R_B.shape[0], 1, 3, 3)), 1)
        for up in self._jumps:
            R = torch.matmul(R.index_select(1, up), R)
        return R

    def _selection(self, links: Sequence[str] | LinkSelection) -> LinkSelection:
        return links if isinstance(links, LinkSelection) else self.select(links)

    @staticmethod
    def _link_poses(R, p, sel: LinkSelection, out: LinkKinematics | None) -> torch.Tensor:
        """Link poses from the skeleton frames; written into `out` when given. Returns p [L,3,B]."""
        R_link, p_link = R.index_select(0, sel.anchor), p.index_select(0, sel.anchor)
        if not sel.offsets_are_identity:
            p_link = p_link + _matvec_soa(R_link, sel.offset_position)
            R_link = _matmul_soa(R_link, sel.offset_rotation.expand_as(R_link))
        if out is not None:
            out.rotation.copy_(R_link.permute(3, 0, 1, 2))
            out.position.copy_(p_link.permute(2, 0, 1))
        return p_link

    def empty_output(self, batch: int, links: Sequence[str] | LinkSelection, jacobian: bool = True,
                     jacobian_links: Sequence[str] | LinkSelection | None = None) -> LinkKinematics:
        """Buffers for `forward(..., out=...)`: rotation [B,L,3,3], position [B,L,3], jacobian [B,L_j,6,6+n]."""
        sel = self._selection(links)
        jsel = sel if jacobian_links is None else self._selection(jacobian_links)
        kw = dict(dtype=self.dtype, device=self.device)
        J = None
        if jacobian:
            J = torch.zeros(batch, len(jsel.names), 6, 6 + self.n_dof, **kw)
            eye = torch.eye(3, **kw)
            J[:, :, 0:3, 0:3] = eye
            J[:, :, 3:6, 3:6] = eye
        L = len(sel.names)
        return LinkKinematics(torch.empty(batch, L, 3, 3, **kw), torch.empty(batch, L, 3, **kw), J)

    def _frame_poses(self, p_B, R_B, s) -> tuple[torch.Tensor, torch.Tensor | None]:
        """World rotation [F,3,3,B] and position [F,3,B] of every skeleton frame (batch last);
        rotations only (position None) when p_B is None."""
        g = self._geometry
        B = s.shape[0]
        rotations_only = p_B is None
        if self.n_dof:
            angle = s.T.index_select(0, self._frame_joint_t) * self._frame_is_joint  # [F,B]; the base has no joint
        else:  # a single rigid body
            angle = s.new_zeros(self._n_frames, B)
        sin = torch.sin(angle)[:, None, None, :]
        one_minus_cos = (1.0 - torch.cos(angle))[:, None, None, :]
        # R_parent->frame = R_off exp(hat(axis) angle) = R_off + sin R_off K + (1 - cos) R_off K^2
        R_local = (g.offset_rotation + sin * g.rotation_sin_term).addcmul_(one_minus_cos, g.rotation_cos_term)
        p_local = g.offset_position.expand(-1, -1, B)
        R_base = R_B.permute(1, 2, 0)  # [3,3,B]
        if B <= SMALL_BATCH and self._jumps and not rotations_only:
            return self._compose_by_jumping(R_local, p_local, R_base, p_B.T)
        # the base frame's offset is the identity and it has no joint, so its pose is the base pose
        R = torch.empty_like(R_local)
        p = None if rotations_only else torch.empty_like(p_local)
        R[0] = R_base
        if p is not None:
            p[0] = p_B.T
        for start, stop, parents in self._levels:  # one step per tree level, not per link
            R_parent = R.index_select(0, parents)
            _matmul_soa(R_parent, R_local[start:stop], out=R[start:stop])
            if p is not None:
                torch.add(p.index_select(0, parents), _matvec_soa(R_parent, p_local[start:stop]), out=p[start:stop])
        return R, p

    def _compose_by_jumping(self, R_local, p_local, R_base, p_base):
        """Pointer jumping for small batches: log2(depth) rounds, each one gather and one product of
        homogeneous transforms [B,F+1,4,4] over all frames (frame F is the world, its own parent).
        Returns the same batch-last views as the level-by-level composition."""
        F, B = R_local.shape[0], R_local.shape[-1]
        T = self._homogeneous_template.expand(B, -1, -1, -1).clone()
        T[:, :F, :3, :3] = R_local.permute(3, 0, 1, 2)
        T[:, :F, :3, 3] = p_local.permute(2, 0, 1)
        T[:, 0, :3, :3] = R_base.permute(2, 0, 1)  # the base frame's offset is the identity
        T[:, 0, :3, 3] = p_base.T
        for up in self._jumps:
            T = torch.matmul(T.index_select(1, up), T)
        # contiguous batch-last copies: the gathers that follow are several times faster on them
        return (T[:, :F, :3, :3].permute(1, 2, 3, 0).contiguous(), T[:, :F, :3, 3].permute(1, 2, 0).contiguous())

    def _jacobian(self, p_B, axis, p, p_link, sel: LinkSelection, J: torch.Tensor) -> None:
        """Fill J [B,L,6,6+n]: base columns (I, -hat(p_L - p_B); 0, I), joint columns (a x (p_L - o); a).
        axis: [n,3,B] world joint axes; p: [F,3,B] frame positions; p_link: [L,3,B]."""
        B = J.shape[0]
        origin = p.index_select(0, self._joint_frame) - p_B.T  # [n,3,B] joint origins relative to the base
        d = p_link - p_B.T  # [L,3,B]
        J[:, :, 0:3, 3:6] = so3.hat(-d.permute(2, 0, 1))
        # the columns of every (link, ancestor joint) pair: (a x r; a), r = p_L - o, batch last
        columns = torch.empty(sel.pair_joint.shape[0], 6, B, dtype=J.dtype, device=J.device)
        torch.index_select(axis, 0, sel.pair_joint, out=columns[:, 3:6])
        r = d.index_select(0, sel.pair_link) - origin.index_select(0, sel.pair_joint)
        a = columns[:, 3:6]
        if B <= SMALL_BATCH:
            torch.linalg.cross(a, r, dim=1, out=columns[:, 0:3])
        else:  # torch's cross along a middle dimension is slow for large batches
            for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # the three components of a x r
                torch.mul(a[:, j], r[:, k], out=columns[:, i]).addcmul_(a[:, k], r[:, j], value=-1.0)
        if B <= SMALL_BATCH:
            J.view(B, -1).index_copy_(1, sel.pair_flat_index, columns.view(-1, B).T)
        else:  # large batches: write through the transposed view, without transposing the columns
            J.view(B, -1).T.index_copy_(0, sel.pair_flat_index, columns.view(-1, B))

    @property
    def joint_parents(self) -> list[int]:
        """Each joint's nearest ancestor joint (-1 where only the base lies above it): the joints'
        own tree, which the structured QP solve eliminates leaves first."""
        above = self._ancestor_np[self._joint_frame_py]  # [n,n] ancestor-or-self joints of each joint
        depth = above.sum(1)
        parents = []
        for j in range(self.n_dof):  # build time only
            candidates = [k for k in np.flatnonzero(above[j]) if k != j]
            parents.append(int(max(candidates, key=lambda k: depth[k])) if candidates else -1)
        return parents

    def zero_configuration(self, batch: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The zero configuration: base at the origin, identity rotation, s = 0. Shapes [B,3], [B,3,3], [B,n]."""
        kw = dict(dtype=self.dtype, device=self.device)
        return (torch.zeros(batch, 3, **kw), torch.eye(3, **kw).expand(batch, 3, 3).clone(),
                torch.zeros(batch, self.n_dof, **kw))

    def summary(self) -> str:
        """One line: name, DoF, links, how many joints have effective limits, coupled constraints."""
        effective = int(((self.upper - self.lower) < 19.9).sum())  # +-10 rad means "no limit" in URDFs
        coupled = 0 if self.linear_limits is None else self.linear_limits.A.shape[0]
        return (f"{self.name}: {self.n_dof} DoF, {len(self.link_names)} links, base {self.base_link}, "
                f"{effective} joints with effective limits, {coupled} coupled linear limits")

    def __repr__(self) -> str:
        return f"KinematicModel({self.summary()})"

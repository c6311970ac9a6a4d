"""`KinematicModel`: a compiled tree (`KinematicTree`) with its tensors in one dtype on one device,
and the queries on it: link poses and Jacobians (`forward`), link rotations and joint axes
(`rotations`), link selections, output buffers, stacking subjects, and the joint limits
(`lower`, `upper`, and `LinearLimits` for coupled ones).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import torch

from ...errors import InputError, ModelError, UnknownLinkError
from ..capture import tracing
from .compose import SMALL_BATCH, fill_jacobian, frame_poses, frame_rotations_small, link_poses, matmul_soa, world_axes
from .selection import LinkKinematics, LinkSelection, compile_selection
from .tensors import Geometry, tensors, tree_geometry
from .urdf import KinematicTree, load_tree


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


class KinematicModel:
    """A floating-base kinematic tree compiled from a URDF to tensors.

    Build it once (`KinematicModel.from_urdf(path)`, or `KinematicModel(tree)` from a compiled
    `KinematicTree`), then call `forward` for batches of configurations. Joints are ordered as in
    the URDF (movable ones only); `joint_names` gives the order of `s`. Joint limits: `lower`,
    `upper` [n] (infinite for continuous joints), `linear_limits` (A s <= b) when the model has
    coupled limits.
    """

    def __init__(self, tree: KinematicTree, name: str | None = None, dtype=torch.float64, device="cpu"):
        self.tree = tree
        self.name = name or tree.name
        self._derive(tree_geometry(tree), dtype, device)
        # the limits are the model's, not the tree's: a user may widen them, and copies keep that
        self.lower = torch.tensor(tree.lower).to(dtype=self.dtype, device=self.device)  # [n]
        self.upper = torch.tensor(tree.upper).to(dtype=self.dtype, device=self.device)
        self.linear_limits: LinearLimits | None = None

    @classmethod
    def from_urdf(cls, source: str | Path, name: str | None = None, dtype=torch.float64, device="cpu") -> "KinematicModel":
        """Compile a URDF file (or its XML text). Raises ModelError naming the file and problem."""
        return cls(load_tree(source), name=name, dtype=dtype, device=device)

    def _derive(self, geometry: Geometry, dtype, device) -> None:
        """(Re)make the tensors from the tree and the subjects' dimensions; forget compiled selections."""
        self._tensors = tensors(self.tree, geometry, dtype, device)
        self._selections: dict[tuple[str, ...], LinkSelection] = {}

    # ------------------------------------------------------------------ the tree's names and sizes
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.tree.joint_names

    @property
    def link_names(self) -> tuple[str, ...]:
        return self.tree.link_names

    @property
    def n_dof(self) -> int:
        return self.tree.n_dof

    @property
    def base_link(self) -> str:
        return self.tree.base_link

    @property
    def source(self) -> str:
        """The URDF's path, or '<URDF text>'."""
        return self.tree.source

    @property
    def dtype(self) -> torch.dtype:
        return self._tensors.dtype

    @property
    def device(self) -> torch.device:
        return self._tensors.device

    @property
    def n_subjects(self) -> int:
        """How many subjects' geometries the model holds (1, or one per batch row)."""
        return self._tensors.geometry.offset_position.shape[-1]

    @property
    def joint_parents(self) -> list[int]:
        """Each joint's nearest ancestor joint (-1 where only the base lies above it): the joints'
        own tree, which the structured QP solve eliminates leaves first."""
        return list(self.tree.joint_parents)

    # ------------------------------------------------------------------ copies
    def to(self, dtype=None, device=None) -> "KinematicModel":
        """A copy with tensors in another dtype and/or on another device."""
        other = copy.copy(self)
        other._derive(self._tensors.geometry, dtype or self.dtype, device or self.device)
        other.lower = self.lower.to(dtype=other.dtype, device=other.device)
        other.upper = self.upper.to(dtype=other.dtype, device=other.device)
        if self.linear_limits is not None:
            other.linear_limits = self.linear_limits.to(dtype or self.dtype, device or self.device)
        return other

    def with_inertial(self, mass: torch.Tensor | None = None, com: torch.Tensor | None = None,
                      inertia: torch.Tensor | None = None) -> "KinematicModel":
        """A copy whose links have other masses [N] (kg), centres of mass [N,3] (m, each in its link's
        frame) and inertias about them [N,3,3] (kg m^2, link axes), `model.link_names` order; those
        not given are kept. The model holds one subject."""
        if self.n_subjects != 1:
            raise ModelError(f"model {self.name!r} holds {self.n_subjects} subjects: give each its own inertial")
        g = self._tensors.geometry
        N = len(self.link_names)
        for name, x, shape in (("mass", mass, (N,)), ("com", com, (N, 3)), ("inertia", inertia, (N, 3, 3))):
            if x is not None and tuple(x.shape) != shape:
                raise InputError(f"with_inertial: {name} must be {list(shape)}, got {list(x.shape)}")
        as_geometry = lambda x, old: old if x is None else x.to(old)[..., None]  # noqa: E731
        geometry = replace(g, link_mass=as_geometry(mass, g.link_mass), link_com=as_geometry(com, g.link_com),
                           link_inertia=as_geometry(inertia, g.link_inertia))
        out = copy.copy(self)
        out._derive(geometry, self.dtype, self.device)
        return out

    def same_topology(self, other: "KinematicModel") -> bool:
        """True when both models have the same joints, links, tree and axes (dimensions may differ)."""
        return self.tree.same_topology(other.tree)

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
        stacked = Geometry.cat([m._tensors.geometry.to(dtype=first.dtype, device=first.device) for m in models])
        out._derive(stacked, first.dtype, first.device)
        out.linear_limits = first.linear_limits
        out.name = f"{first.name} x{len(models)}"
        return out

    # ------------------------------------------------------------------ queries
    def select(self, links: Sequence[str]) -> LinkSelection:
        """Compile a list of link names for `forward` (cached). Unknown names raise UnknownLinkError."""
        key = tuple(links)
        if key in self._selections:
            return self._selections[key]
        index = self.tree.link_index
        unknown = [n for n in key if n not in index]
        if unknown:
            raise UnknownLinkError(
                f"model {self.name!r} has no link(s) {unknown}; valid links: {', '.join(self.link_names)}"
            )
        if not key:
            raise InputError("select at least one link")
        selection = compile_selection(self._tensors, key, [index[n] for n in key])
        self._selections[key] = selection
        return selection

    def check_input(self, name: str, t: torch.Tensor, shape: tuple) -> None:
        """Raise InputError naming `name` unless `t` is a tensor of `shape` in the model's dtype and device."""
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
        self.check_input("base_position", base_position, (B, 3))
        self.check_input("base_rotation", base_rotation, (B, 3, 3))
        self.check_input("joint_positions", joint_positions, (B, self.n_dof))
        if self.n_subjects not in (1, B):
            raise InputError(f"this model holds {self.n_subjects} subjects; the batch has {B} rows")
        sel = self._selection(links)
        jsel = sel if jacobian_links is None else self._selection(jacobian_links)
        if out is None:
            out = self.empty_output(B, sel, jacobian, jsel)
        elif out.position is None or out.position.shape != (B, len(sel.names), 3) or (
                jacobian and (out.jacobian is None or out.jacobian.shape[1] != len(jsel.names))):
            raise InputError(f"out: expected buffers from empty_output({B}, links, ...) for {len(sel.names)} links")

        t = self._tensors
        R, p = frame_poses(t, base_position, base_rotation, joint_positions)  # [F,3,3,B], [F,3,B]
        p_link = link_poses(R, p, sel, out)
        if not (jacobian or joint_axes):
            return out
        axis = world_axes(t, R)
        if jacobian:
            assert out.jacobian is not None  # empty_output made it, or the check above found it
            p_jacobian = p_link if jsel is sel else link_poses(R, p, jsel, None)
            fill_jacobian(t, base_position, axis, p, p_jacobian, jsel, out.jacobian)
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
        self.check_input("base_rotation", base_rotation, (B, 3, 3))
        self.check_input("joint_positions", joint_positions, (B, self.n_dof))
        if self.n_subjects not in (1, B):
            raise InputError(f"this model holds {self.n_subjects} subjects; the batch has {B} rows")
        sel = self._selection(links)
        t = self._tensors
        if B > SMALL_BATCH or not t.jumps:
            R, _ = frame_poses(t, None, base_rotation, joint_positions)  # [F,3,3,B]
            R_link = R.index_select(0, sel.anchor)
            if not sel.offsets_are_identity:
                R_link = matmul_soa(R_link, sel.offset_rotation.expand_as(R_link))
            axes = world_axes(t, R).permute(2, 0, 1) if joint_axes else None
            # captured, the axes stay batch-last in memory (a [B,n,3] view): the tree's factor reads
            # them batch-last, and a batch-first copy is a scattered store per number
            if axes is not None and not tracing():
                axes = axes.contiguous()
            return LinkKinematics(R_link.permute(3, 0, 1, 2).contiguous(), None, None, axes)
        R = frame_rotations_small(t, base_rotation, joint_positions)  # [B,F+1,3,3]
        R_link = R.index_select(1, sel.anchor)
        if not sel.offsets_are_identity:
            R_link = R_link @ sel.offset_rotation.permute(3, 0, 1, 2)
        # the world axis of joint j: its frame's rotation times the axis in that frame
        axes = (R.index_select(1, t.joint_frame) * t.joint_axes_row).sum(-1) if joint_axes else None
        return LinkKinematics(R_link, None, None, axes)

    def _selection(self, links: Sequence[str] | LinkSelection) -> LinkSelection:
        return links if isinstance(links, LinkSelection) else self.select(links)

    def empty_output(self, batch: int, links: Sequence[str] | LinkSelection, jacobian: bool = True,
                     jacobian_links: Sequence[str] | LinkSelection | None = None) -> LinkKinematics:
        """Buffers for `forward(..., out=...)`: rotation [B,L,3,3], position [B,L,3], jacobian [B,L_j,6,6+n]."""
        sel = self._selection(links)
        jsel = sel if jacobian_links is None else self._selection(jacobian_links)
        kw: dict[str, Any] = dict(dtype=self.dtype, device=self.device)
        J = None
        if jacobian:
            J = torch.zeros(batch, len(jsel.names), 6, 6 + self.n_dof, **kw)
            eye = torch.eye(3, **kw)
            J[:, :, 0:3, 0:3] = eye
            J[:, :, 3:6, 3:6] = eye
        L = len(sel.names)
        return LinkKinematics(torch.empty(batch, L, 3, 3, **kw), torch.empty(batch, L, 3, **kw), J)

    def zero_configuration(self, batch: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The zero configuration: base at the origin, identity rotation, s = 0. Shapes [B,3], [B,3,3], [B,n]."""
        kw: dict[str, Any] = dict(dtype=self.dtype, device=self.device)
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

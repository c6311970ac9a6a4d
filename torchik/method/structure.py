"""What a tracker compiles once for its model and targets (`StepStructure`), and what `reset`
fixes for a batch size (`BatchSetup`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from ..errors import InputError
from .constraints import Limit
from .kinematics import KinematicModel, LinkKinematics, LinkSelection
from .limits import Bounds, base_velocity_bounds
from .qp import BatchedBackend, JointTree, QPBackend
from .settings import TrackerSettings
from .target_equations import TargetStructure
from .tasks import Task


@dataclass(frozen=True)
class StepStructure:
    """What a tracker compiles once for its model and target links.

    selection: every target link; orientation_selection: the orientation targets' links (None
    without any); position_index [n_p], orientation_index [n_o]: the targets in `selection`;
    targets: which coordinates move which of the paper's targets (target_equations.py); tree: the
    joints' tree for the structured QP solve (None when a position target is off the base link, or
    the model has no joint, or there are other tasks: `tasks`); rotations_only: the
    step needs link rotations and joint axes only (the paper's targets: orientations, and the base
    position); position_gain [n_p,1], orientation_gain [n_o,1]: K per target; base_selection: the
    base link alone (a kinematics call that only needs the joint axes); tasks, limits: those beyond
    the paper's targets and the model's limits (tasks.py, constraints.py), which make the step dense
    (no tree).
    """

    selection: LinkSelection
    orientation_selection: LinkSelection | None
    position_index: torch.Tensor
    orientation_index: torch.Tensor
    targets: TargetStructure
    tree: JointTree | None
    rotations_only: bool
    position_gain: torch.Tensor
    orientation_gain: torch.Tensor
    base_selection: LinkSelection
    tasks: tuple[Task, ...] = ()
    limits: tuple[Limit, ...] = ()

    @classmethod
    def build(cls, model: KinematicModel, orientation_links: tuple[str, ...], position_links: tuple[str, ...],
              settings: TrackerSettings, tasks: tuple[Task, ...] = (), limits: tuple[Limit, ...] = ()) -> "StepStructure":
        links = tuple(dict.fromkeys(position_links + orientation_links))
        selection = model.select(links)  # raises UnknownLinkError for a bad name
        targets = TargetStructure.build(model, orientation_links, position_links)
        index = {name: i for i, name in enumerate(links)}
        long: dict[str, Any] = dict(dtype=torch.long, device=model.device)
        gains = []
        for name, given, n in (("position_gain", settings.position_gain, len(position_links)),
                               ("orientation_gain", settings.orientation_gain, len(orientation_links))):
            gain = torch.as_tensor(given, dtype=model.dtype, device=model.device)
            if gain.dim() > 1 or (gain.dim() == 1 and gain.shape[0] != n):
                raise InputError(f"{name}: give a scalar or one gain per target ({n}), got shape {list(gain.shape)}")
            gains.append(gain.expand(n).clone()[:, None])  # [n,1], against [B,n,3]
        # The structured solve needs every position target on the base link (the base's linear
        # velocity is then its own block of H) and a joint to eliminate; otherwise the batched
        # backend works densely.
        tree = JointTree.build(model, orientation_links) \
            if set(position_links) <= {model.base_link} and model.n_dof > 0 and not tasks else None
        return cls(selection, model.select(orientation_links) if orientation_links else None,
                   torch.tensor([index[n] for n in position_links], **long),
                   torch.tensor([index[n] for n in orientation_links], **long), targets, tree,
                   targets.position is None and len(orientation_links) > 0, gains[0], gains[1],
                   model.select((model.base_link,)), tuple(tasks), tuple(limits))


@dataclass(frozen=True)
class BatchSetup:
    """What `reset` fixes for a batch of `size` subjects: the targets' shapes, the base's velocity
    bounds, the coupled limits' rows G [B,m,6+n] (None without), whether both configurations of a
    step go in one kinematics call (`stacked`), whether the QP is solved on the tree's structure,
    and the kinematics' output buffers (None for rotations only)."""

    STACK_BELOW: ClassVar[int] = 16  # batches up to this size evaluate both configurations of a step in one call
    # from this batch size the batched backend solves with the tree structure, below densely: the
    # tree's leaves-first elimination costs a fixed time per level of the tree, a dense Cholesky of
    # B matrices less up to about 96 subjects, where the two cost the same for Human66 (the
    # timings: experiments/speed_history.md)
    TREE_FROM: ClassVar[int] = 96
    # captured (settings.compile), the tree's elimination costs no time per level and is the faster
    # solve from this size. At B = 1 the dense step is faster, and the tree's first capture on a
    # machine takes twice as long (the timings: experiments/speed_history.md)
    CAPTURED_TREE_FROM: ClassVar[int] = 32

    size: int
    target_shapes: tuple
    base_bounds: Bounds
    linear_rows: torch.Tensor | None
    stacked: bool
    structured: bool
    buffers: LinkKinematics | None

    @classmethod
    def build(cls, model: KinematicModel, structure: StepStructure, settings: TrackerSettings, backend: QPBackend,
              B: int) -> "BatchSetup":
        kw: dict[str, Any] = dict(dtype=model.dtype, device=model.device)
        A = None if model.linear_limits is None else model.linear_limits.A
        n_p, n_o = len(structure.position_index), len(structure.orientation_index)
        stacked = B <= cls.STACK_BELOW and model.n_subjects == 1
        rows = 2 * B if stacked and settings.scheme == "midpoint" else B
        return cls(
            size=B,
            target_shapes=((B, n_p, 3), (B, n_p, 3), (B, n_o, 3, 3), (B, n_o, 3)),
            base_bounds=base_velocity_bounds(B, settings.limits, **kw),
            # G of the coupled limits A s_dot <= h: the base's columns are zero
            linear_rows=None if A is None else torch.cat((A.new_zeros(A.shape[0], 6), A), dim=1).expand(B, -1, -1),
            stacked=stacked,
            structured=structure.tree is not None and (
                (settings.compile and B >= cls.CAPTURED_TREE_FROM) or
                (isinstance(backend, BatchedBackend) and B >= cls.TREE_FROM)),
            buffers=None if structure.rotations_only else
            model.empty_output(rows, structure.selection, structure.targets.position is not None,
                               structure.targets.position))

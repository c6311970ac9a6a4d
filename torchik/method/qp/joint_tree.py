"""The joints' tree of a model, compiled once for the step's Hessian (`tree.py`): the joints leaves
first, one tree level after another, and which rows of which levels each level's sums come from and
go to. Build-time Python only; what it returns is index tensors."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from ..kinematics import KinematicModel


def _one_child_per_parent(pairs: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """(child row, parent row) pairs split into rounds in which no parent row appears twice: a
    parent's first child in this level in the first round, its second in the second, ... Captured,
    each round's sum into the parents is a scatter whose adds TorchInductor makes atomic; two adds
    to one row in one scatter would land in either order from one run to the next, and so would the
    sum's rounding. Eagerly the rounds add in the same order as one sum over all pairs would."""
    rounds: list[list[tuple[int, int]]] = []
    seen: dict[int, int] = {}
    for child, parent in pairs:
        k = seen.get(parent, 0)
        seen[parent] = k + 1
        if k == len(rounds):
            rounds.append([])
        rounds[k].append((child, parent))
    return rounds


@dataclass(frozen=True)
class JointTree:
    """The joints' tree compiled for a model and its orientation targets.

    order: [n] the joints leaves first, one tree level (height) after another (node_order [n+1]: the
    base after them); position: [n] where each joint is in that order; levels: per level (start,
    stop): its joints are order[start:stop] (level L = len(levels), the base, stands for node n).
    Each level's work reads and writes only its own per-level tensors, never a whole [n,...]
    accumulator: written in place, such an accumulator is copied whole at every level once the step
    is captured and made functional (`captured.py`). Eagerly it costs about what the accumulator
    did, with the same solution to the bit (the timings: experiments/speed_history.md).
    up[h]: where level h's sum of its children's contributions comes from, as (child level, the
    child rows that feed level h or None for all, the level-h rows they add to, none twice in one
    entry, or None for the same rows); down[h]: (the levels holding level h's parents, each with
    its rows) and the permutation that puts their concatenation in level h's order (None where it
    is already).
    attach: [n_o, n+1] 1 where target t's angular velocity is that of joint j's frame (column n:
    the base); ancestors: [n+1, n] 1 where joint k lies on the path to j (column of the base: all
    zero), for H's dense form.
    """

    n: int
    order: torch.Tensor
    node_order: torch.Tensor
    position: torch.Tensor
    levels: tuple[tuple[int, int], ...]
    up: tuple[tuple[tuple[int, torch.Tensor | None, torch.Tensor | None], ...], ...]
    down: tuple[tuple[tuple[tuple[int, torch.Tensor | None], ...], torch.Tensor | None], ...]
    attach: torch.Tensor
    ancestors: torch.Tensor

    @classmethod
    def build(cls, model: KinematicModel, orientation_links) -> "JointTree":
        n = model.n_dof
        parents = [p if p >= 0 else n for p in model.joint_parents]
        height = [0] * n
        for j in sorted(range(n), key=lambda j: -_depth(parents, j, n)):  # build time only
            if parents[j] < n:
                height[parents[j]] = max(height[parents[j]], height[j] + 1)
        long: dict[str, Any] = dict(dtype=torch.long, device=model.device)
        order = sorted(range(n), key=lambda j: (height[j], j))
        levels, start = [], 0
        for h in range(max(height) + 1 if n else 0):
            size = sum(1 for j in order if height[j] == h)
            levels.append((start, start + size))
            start += size
        up, down = _links_between_levels(order, parents, levels, n, long)
        above = torch.zeros(n + 1, n, dtype=model.dtype, device=model.device)
        for j in range(n):
            k = j
            while k < n:
                above[j, k] = 1.0
                k = parents[k]
        mask = model.select(tuple(orientation_links)).ancestor_mask if len(orientation_links) else \
            torch.zeros(0, n, dtype=model.dtype, device=model.device)
        # a target's frame is that of the deepest joint moving it (its movers form one path)
        depth = above[:n].sum(1)
        if n:
            deepest = torch.where(mask > 0, depth, torch.zeros_like(depth)).argmax(1)
            node = torch.where(mask.sum(1) > 0, deepest, torch.full_like(deepest, n))
        else:  # a lone rigid body: every target is on the base
            node = torch.full((mask.shape[0],), n, dtype=torch.long, device=model.device)
        attach = torch.zeros(mask.shape[0], n + 1, dtype=model.dtype, device=model.device)
        attach[torch.arange(mask.shape[0]), node] = 1.0
        position = {j: i for i, j in enumerate(order)}
        return cls(n, torch.tensor(order, **long), torch.tensor(order + [n], **long),
                   torch.tensor([position[j] for j in range(n)], **long), tuple(levels), up, down, attach, above)


def _depth(parents, j, n) -> int:
    d = 0
    while j < n:
        j, d = parents[j], d + 1
    return d


def _links_between_levels(order: list[int], parents: list[int], levels: list[tuple[int, int]], n: int,
                           long: dict[str, Any]) -> tuple[tuple, tuple]:
    """`JointTree.up` and `.down` (build time only): for each level, which rows of which other levels
    its children and its parents are."""
    L = len(levels)
    where = {n: (L, 0)}  # node -> (level, row); the base is level L's only row
    for h, (start, stop) in enumerate(levels):
        for row, j in enumerate(order[start:stop]):
            where[j] = (h, row)
    size = [stop - start for start, stop in levels] + [1]
    rows_or_all = lambda rows, m: None if rows == list(range(m)) else torch.tensor(rows, **long)  # noqa: E731
    up: list[list] = [[] for _ in range(L + 1)]
    down = []
    for h, (start, stop) in enumerate(levels):
        groups: dict[int, list[tuple[int, int]]] = {}
        for row, j in enumerate(order[start:stop]):
            groups.setdefault(where[parents[j]][0], []).append((row, where[parents[j]][1]))
        for h_parent, pairs in groups.items():
            for round_ in _one_child_per_parent(pairs):
                child_rows, parent_rows = [r for r, _ in round_], [p for _, p in round_]
                same = child_rows == parent_rows == list(range(size[h_parent])) and size[h] == size[h_parent]
                up[h_parent].append((h, None if same else rows_or_all(child_rows, size[h]),
                                     None if same else torch.tensor(parent_rows, **long)))
        arrival = [r for pairs in groups.values() for r, _ in pairs]  # level h's rows as concatenated
        permutation = None if arrival == list(range(size[h])) else \
            torch.tensor(sorted(range(len(arrival)), key=arrival.__getitem__), **long)
        down.append((tuple((h_parent, rows_or_all([p for _, p in pairs], size[h_parent]))
                           for h_parent, pairs in groups.items()), permutation))
    return tuple(tuple(u) for u in up), tuple(down)

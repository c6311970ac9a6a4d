"""Limits: what the step's velocity must respect, each as rows G nu <= h or A nu = b.

A limit gives, from the state and dt, inequality rows (`rows`) and equality rows (`equalities`),
[B,m,6+n] and [B,m], or None. The model's joint limits (bounds on the joint rates, `limits.py`) and
its coupled limits (iCub's shoulder, rows A s_dot <= h) are the first two, declared by
`JointLimits` and `CoupledLimits` and built by the step as always; any other is added to them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import torch

from ..errors import InputError
from .limits import LinearRows
from .tasks import ContactTask, StepContext


@dataclass
class Limit:
    """A limit on the step's velocity; `name` labels it in reports."""

    name: str = field(default="limit", kw_only=True)

    def rows(self, context: StepContext) -> LinearRows | None:
        """G [B,m,6+n], h [B,m] of G nu <= h (None: none)."""
        return None

    def equalities(self, context: StepContext) -> LinearRows | None:
        """A [B,e,6+n], b [B,e] of A nu = b (None: none). A zero row (and b 0) constrains nothing."""
        return None

    def reset(self) -> None:
        """Forget what earlier steps left (the tracker's `reset` calls it)."""


@dataclass
class JointLimits(Limit):
    """The model's joint limits as bounds on the joint rates (limits.py): a declaration."""

    name: str = field(default="joint limits", kw_only=True)


@dataclass
class CoupledLimits(Limit):
    """The model's coupled limits A s <= b as rows (limits.py): a declaration."""

    name: str = field(default="coupled limits", kw_only=True)


MODEL_LIMITS = (JointLimits, CoupledLimits)


@dataclass
class ContactLimit(Limit):
    """A link held still while on the ground, exactly: its velocity rows J nu = -K (drift from
    where it touched down), as equalities, switched per sample as ContactTask (whose `on`, `link`,
    `angular` and gain it takes): rows of zeros where the contact is off."""

    contact: ContactTask = field(default_factory=ContactTask)
    name: str = field(default="contact", kw_only=True)

    def equalities(self, context: StepContext) -> LinearRows:
        r, J, _, active = self.contact.terms(context)
        assert active is not None  # a contact's rows are switched
        return LinearRows(J * active.unsqueeze(-1), self.contact.rate(context) * r * active)

    def reset(self) -> None:
        self.contact.reset()


def split_limits(limits: Sequence[Limit]) -> tuple[Limit, ...]:
    """The limits beyond the model's (whose joint and coupled limits always hold: declaring them
    changes nothing)."""
    for limit in limits:
        if not isinstance(limit, Limit):
            raise InputError(f"limits: {limit!r} is not a torchik.method.constraints.Limit")
    return tuple(x for x in limits if not isinstance(x, MODEL_LIMITS))


def stacked_rows(found: list[LinearRows]) -> LinearRows | None:
    """The rows of several limits one after the other (None when there are none)."""
    if not found:
        return None
    B = max(rows.G.shape[0] for rows in found)
    return LinearRows(torch.cat([rows.G.expand(B, -1, -1) for rows in found], 1),
                      torch.cat([rows.h.expand(B, -1) for rows in found], 1))

"""Figures as files: matplotlib without a display, or a clear error naming the extra that brings it."""

from __future__ import annotations

from ..errors import optional


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display)."""
    matplotlib = optional("matplotlib", "viz", "figures")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt

"""Figures as files: matplotlib without a display, or a clear error naming the extra that brings it."""

from __future__ import annotations

import math

from ..errors import optional


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display)."""
    matplotlib = optional("matplotlib", "viz", "figures")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure(figsize: tuple[float, float]):
    """A matplotlib Figure of `figsize` inches, drawn by Agg when saved, without pyplot: pyplot's
    import and figure manager cost a second a command where a report saves two figures."""
    optional("matplotlib", "viz", "figures")
    from matplotlib.figure import Figure

    return Figure(figsize=figsize)


def plain_log_labels(ax) -> None:
    """Label a log-scaled y axis with plain numbers (0.001, not 10^-3): matplotlib's mathtext, which
    the exponents need, costs more than the rest of a small figure."""
    from matplotlib.ticker import FuncFormatter

    def minor(value: float, _) -> str:  # 2 and 5 times a power of ten, on an axis spanning a decade or so
        low, high = ax.get_ylim()
        if low <= 0 or high / low > 30:
            return ""
        mantissa = value / 10.0 ** math.floor(math.log10(value)) if value > 0 else 0.0
        return f"{value:g}" if min(abs(mantissa - 2.0), abs(mantissa - 5.0)) < 1e-6 else ""

    ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    ax.yaxis.set_minor_formatter(FuncFormatter(minor))

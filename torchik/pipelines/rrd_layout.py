"""The layout a torchik rerun recording opens on (`blueprint`), for files and live viewers alike."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from ..errors import optional

if TYPE_CHECKING:
    import rerun.blueprint as rrb
else:
    rrb = optional("rerun.blueprint", "viz", "writing rerun recordings")


def blueprint(subjects: Sequence[int], aggregate: bool = False, live: bool = False) -> rrb.Blueprint:
    """The layout: the 3D view on the left; on the right MNTE and angular velocity RMSE (of the
    first logged subject, or mean and max over the batch), residuals and joint angles of the first
    logged subject, solver status and step time; live: the live counters too (/live)."""
    first = f"/subject/{subjects[0]}"
    summary = "/aggregate" if aggregate else first
    plots: list[rrb.Container | rrb.View] = [
        rrb.Horizontal(rrb.TimeSeriesView(name="MNTE", origin=f"{summary}/errors/mnte"),
                       rrb.TimeSeriesView(name="angular velocity RMSE (rad/s)", origin=f"{summary}/errors/rmse")),
        rrb.TimeSeriesView(name=f"residual norms, subject {subjects[0]}", origin=f"{first}/residual"),
        rrb.TimeSeriesView(name=f"joint angles (rad), subject {subjects[0]}", origin=f"{first}/joints"),
        rrb.TimeSeriesView(name="solver and step time", contents=[f"{summary}/solver/**", "/timing/**"]),
    ]
    if live:
        plots.append(rrb.TimeSeriesView(name="live counters", origin="/live"))
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(name="estimate and targets", origin="/"), rrb.Vertical(*plots),
                                        column_shares=[3, 2]))

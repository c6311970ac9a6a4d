"""The experiment's five figures: box plots of log10 MNTE, log10 RMSE and step time per model,
scenario and method; the convergence to a static T-pose for several gains; and an iCub joint's
constrained phase plane (its angle against its rate within the tanh velocity bounds)."""

from __future__ import annotations

from pathlib import Path

import torch

from ...method.limits import LimitSettings, velocity_bounds
from ..evaluation import after_transient
from ..plotting import pyplot
from .cases import cached_model
from .runs import METHODS, Run

_pyplot = pyplot


COLOURS = {"whole-body": "tab:blue", "pair-wise": "tab:orange", "dynamical (paper)": "tab:green",
           "dynamical (midpoint)": "tab:red"}


def _save(fig, path: Path, tight: bool = True) -> Path:
    """Write a figure as PNG and free it."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def box_plots(runs: list[Run], transient: float, out: Path) -> list[Path]:
    """box_mnte.png, box_rmse.png, box_time.png: one panel per model, scenarios along x, a box per method."""
    plt = _pyplot()
    models = list(dict.fromkeys(r.model for r in runs))
    scenarios = list(dict.fromkeys(r.scenario for r in runs))
    methods = [m for m in METHODS if any(r.method == m for r in runs)]
    by = {(r.model, r.scenario, r.method): r for r in runs}
    quantities = (("box_mnte.png", "log10 MNTE", lambda r: torch.log10(r.mnte.clamp(min=1e-30))),
                  ("box_rmse.png", "log10 angular-velocity RMSE (rad/s)", lambda r: torch.log10(r.rmse.clamp(min=1e-30))),
                  ("box_time.png", "step compute time (ms)", lambda r: r.step_time * 1e3))
    width = 0.8 / len(methods)
    written = []
    for filename, label, value in quantities:
        fig, axes = plt.subplots(1, len(models), figsize=(4.5 * len(models), 4), squeeze=False)
        for ax, model in zip(axes[0], models):
            for i, method in enumerate(methods):
                data, positions = [], []
                for j, name in enumerate(scenarios):
                    run = by.get((model, name, method))
                    if run is None:
                        continue
                    v = after_transient(value(run), run.time, transient)
                    data.append(v[torch.isfinite(v)].numpy())
                    positions.append(j + (i - (len(methods) - 1) / 2) * width)
                if data:
                    parts = ax.boxplot(data, positions=positions, widths=width * 0.9, patch_artist=True,
                                       showfliers=True, flierprops=dict(markersize=1.5, alpha=0.4))
                    for box in parts["boxes"]:
                        box.set_facecolor(COLOURS[method])
                        box.set_alpha(0.7)
            ax.set_xticks(range(len(scenarios)), scenarios)
            ax.set_title(cached_model(model).name)
            ax.set_ylabel(label)
            if filename == "box_time.png":
                ax.set_yscale("log")
            ax.grid(axis="y", alpha=0.3)
        handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[m], alpha=0.7) for m in methods]
        fig.legend(handles, methods, loc="lower center", ncol=len(methods), frameon=False)
        fig.tight_layout(rect=(0, 0.07, 1, 1))
        written.append(_save(fig, out / filename, tight=False))
    return written


def convergence_figure(curves: dict, rate: float, out: Path) -> Path:
    """convergence.png: one panel per scheme, MNTE against time for each gain of `convergence`
    (dashed beyond the stability bound K dt < 2)."""
    plt = _pyplot()
    schemes = list(dict.fromkeys(scheme for scheme, _ in curves))
    fig, axes = plt.subplots(1, len(schemes), figsize=(5.5 * len(schemes), 4), squeeze=False, sharey=True)
    for ax, scheme in zip(axes[0], schemes):
        for (s, gain), (time_, error) in curves.items():
            if s != scheme:
                continue
            beyond = gain / rate >= 2.0
            ax.semilogy(time_.numpy(), error.clamp(min=1e-30).numpy(), ls="--" if beyond else "-",
                        label=f"K = {gain:g} 1/s, K dt = {gain / rate:g}" + (" > 2: unstable" if beyond else ""))
        ax.set_title(f"Human66 to a static T-pose, {scheme} scheme, {rate:g} Hz")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("MNTE")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    return _save(fig, out / "convergence.png")


def phase_plane_figure(run: Run, joint: str, out: Path, transient: float = 2.0,
                       limits: LimitSettings = LimitSettings()) -> Path:
    """An iCub joint's angle against its rate along `run` after the transient, over the region the
    velocity bounds allow (the tracker's LimitSettings, at the run's time step):
    -min(b tanh(K_g (s - s_min)), (s - s_min)/dt) <= s_dot <= min(b tanh(K_g (s_max - s)), (s_max - s)/dt)."""
    plt = _pyplot()
    model = cached_model(run.model)
    j = model.joint_names.index(joint)
    lower, upper = float(model.lower[j]), float(model.upper[j])
    dt = float((run.time[1:] - run.time[:-1]).median())
    grid = torch.linspace(lower, upper, 400, dtype=model.dtype)
    s = torch.zeros(len(grid), model.n_dof, dtype=model.dtype) + (model.lower + model.upper) / 2
    s[:, j] = grid
    lb, ub = velocity_bounds(s, model.lower, model.upper, limits, torch.full((len(grid), 1), dt, dtype=model.dtype))
    # step k's rate was bounded at the angle the step started from: pair rate k with angle k - 1
    keep = run.time[1:] >= run.time[0] + transient
    if not bool(keep.any()):  # a recording shorter than the transient: all of it
        keep[:] = True
    angle = run.trajectory.joint_positions[:-1, 0, j][keep]
    rate = run.trajectory.velocity[1:, 0, 6 + j][keep]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    ax.fill_between(grid.numpy(), lb[:, 6 + j].numpy(), ub[:, 6 + j].numpy(), color="tab:gray", alpha=0.15,
                    label="allowed by the tanh velocity bounds")
    ax.plot(grid.numpy(), ub[:, 6 + j].numpy(), color="tab:gray", lw=1)
    ax.plot(grid.numpy(), lb[:, 6 + j].numpy(), color="tab:gray", lw=1)
    for x in (lower, upper):
        ax.axvline(x, color="black", lw=0.8, ls=":")
    ax.plot(angle.numpy(), rate.numpy(), color="tab:red", lw=0.8,
            label=f"{run.method}, {run.scenario}, after {transient:g} s (angle at the step's start)")
    reach = max(float(rate.abs().max()) * 1.5, 1.0)
    ax.set_ylim(-reach, reach)
    # the trajectory's neighbourhood and the limits near it
    low, high = float(angle.min()), float(angle.max())
    span = max(high - low, 0.2)
    ax.set_xlim(max(lower, low - span) - 0.05, min(upper, high + span) + 0.05)
    ax.set_xlabel(f"{joint} angle (rad)")
    ax.set_ylabel(f"{joint} rate (rad/s)")
    ax.set_title(f"iCub {joint}: limits [{lower:.3f}, {upper:.3f}] rad, b = {limits.max_rate:g} rad/s, "
                 f"K_g = {limits.gain:g}", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    return _save(fig, out / "phase_plane.png")

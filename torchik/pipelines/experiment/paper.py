"""The whole experiment: every method on every case, the convergence runs, then the table and
the figures written into one folder (OUTPUTS)."""

from __future__ import annotations

import time
from pathlib import Path

import torch

from ..evaluation import after_transient
from .cases import Case, Settings, cached_model, scenario_cases
from .figures import box_plots, convergence_figure, phase_plane_figure
from .runs import METHODS, convergence, timed_run
from .tables import markdown, statistics, write_csv

OUTPUTS = ("results.csv", "results.md", "box_mnte.png", "box_rmse.png", "box_time.png", "convergence.png",
           "phase_plane.png")


def run_paper(out: str | Path, settings: Settings = Settings(), cases: list[Case] | None = None,
              methods=METHODS, progress: bool = True, source: str = "built-in scenarios") -> tuple[list[dict], list[Path]]:
    """Run every method on every case (default: the built-in scenarios on every model), then the
    convergence runs, and write the table and figures into `out`. Returns the rows and the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(settings.threads)
    try:
        cases = scenario_cases(settings) if cases is None else cases
        jobs = [(case, method) for case in cases for method in methods]
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(jobs) + 1, desc="experiment paper", unit="run")
        runs = []
        for case, method in jobs:  # runs one after the other: their timings must not share the cores
            if bar is not None:
                bar.set_postfix_str(f"{case.model} {case.scenario} {method}")
            runs.append(timed_run(case, method, settings))
            if bar is not None:
                bar.update()
        if bar is not None:
            bar.set_postfix_str("convergence to a static T-pose")
        curves = convergence(settings, settings.convergence_seconds)
        if bar is not None:
            bar.update()
            bar.close()
    finally:
        torch.set_num_threads(threads)
    rows = [statistics(run, settings.transient) for run in runs]
    files = [write_csv(rows, out / "results.csv")]
    files += box_plots(runs, settings.transient, out)
    files.append(convergence_figure(curves, settings.rate, out))
    elbow = [r for r in runs if r.model == "icub" and r.method == "dynamical (midpoint)"]
    if elbow:
        # the motion in which the elbow moves most after the transient (running, of the built-in ones)
        j = cached_model("icub").joint_names.index("r_elbow")
        pick = max(elbow, key=lambda r: float(after_transient(r.trajectory.joint_positions[:, 0, j], r.time,
                                                                 settings.transient).std()))
        files.append(phase_plane_figure(pick, "r_elbow", out, settings.transient))
    text = markdown(rows, settings, source, time.perf_counter() - began)
    (out / "results.md").write_text(text)
    files.insert(1, out / "results.md")
    return rows, files

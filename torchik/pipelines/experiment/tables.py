"""The experiment's table: per run the medians, 99th percentiles and spread after the transient,
per model and scenario the ratios of the instantaneous methods' step times to the dynamical
method's and whether the paper's expectations hold, written as CSV and as markdown."""

from __future__ import annotations

import csv
import platform
from pathlib import Path
from typing import Any

import torch

from ..evaluation import after_transient
from .cases import Settings
from .runs import Run


def statistics(run: Run, transient: float) -> dict:
    """One row of the table: medians, 99th percentiles and the spread after the transient."""
    pick = lambda v: after_transient(v, run.time, transient).double()  # noqa: E731
    known = lambda v: v[torch.isfinite(v)]  # noqa: E731
    m, r, t = known(pick(run.mnte)), known(pick(run.rmse)), pick(run.step_time) * 1e3
    median = lambda v: float(v.median()) if len(v) else float("nan")  # noqa: E731  (no frame with every target)
    p99 = lambda v: float(v.quantile(0.99)) if len(v) else float("nan")  # noqa: E731
    row: dict[str, Any] = dict(model=run.model, scenario=run.scenario, method=run.method, samples=len(t),
               mnte_median=median(m), mnte_p99=p99(m), rmse_median=median(r), rmse_p99=p99(r),
               time_median_ms=median(t), time_p99_ms=p99(t))
    row["spread"] = row["time_p99_ms"] / row["time_median_ms"]
    wall = pick(run.wall_time) * 1e3
    row["wall_median_ms"], row["wall_p99_ms"] = float(wall.median()), float(wall.quantile(0.99))
    iterations = pick(run.iterations)
    row["iterations_mean"], row["iterations_p99"] = float(iterations.mean()), p99(iterations)
    return row


def ratios(rows: list[dict], scheme: str) -> list[dict]:
    """Per model and scenario: baseline / dynamical step times (median, p99), each method's spread
    (p99/median), MNTE of dynamical / whole-body, and which of the paper's expectations hold."""
    by = {(r["model"], r["scenario"], r["method"]): r for r in rows}
    out = []
    for model, name in dict.fromkeys((r["model"], r["scenario"]) for r in rows):
        dyn, wb, pw = (by.get((model, name, m)) for m in (f"dynamical ({scheme})", "whole-body", "pair-wise"))
        if dyn is None or wb is None or pw is None:
            continue
        item = dict(model=model, scenario=name, scheme=scheme,
                    wb_median=wb["time_median_ms"] / dyn["time_median_ms"], wb_p99=wb["time_p99_ms"] / dyn["time_p99_ms"],
                    pw_median=pw["time_median_ms"] / dyn["time_median_ms"], pw_p99=pw["time_p99_ms"] / dyn["time_p99_ms"],
                    spread_dyn=dyn["spread"], spread_wb=wb["spread"], spread_pw=pw["spread"],
                    mnte_ratio=dyn["mnte_median"] / max(wb["mnte_median"], 1e-300))
        item["faster"] = min(item["wb_median"], item["wb_p99"], item["pw_median"], item["pw_p99"]) > 1.0
        item["steadiest"] = item["spread_dyn"] < min(item["spread_wb"], item["spread_pw"])
        item["accurate"] = item["mnte_ratio"] <= 2.0
        out.append(item)
    return out


COLUMNS = ("model", "scenario", "method", "samples", "mnte_median", "mnte_p99", "rmse_median", "rmse_p99",
           "time_median_ms", "time_p99_ms", "spread", "iterations_mean", "iterations_p99", "wall_median_ms",
           "wall_p99_ms")


def write_csv(rows: list[dict], path: Path) -> Path:
    """results.csv: one row per run (`statistics`), the COLUMNS in order."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows({k: row[k] for k in COLUMNS} for row in rows)
    return path


def markdown(rows: list[dict], settings: Settings, source: str, wall_time: float) -> str:
    """The table, the ratios for each discretisation, and the settings."""
    length = f"{settings.duration:g} s at {settings.rate:g} Hz per run, " if source.startswith("built-in") else ""
    lines = [f"# Dynamical IK against instantaneous IK ({source})", "",
             f"{length}statistics after {settings.transient:g} s; K = {settings.gain:g} 1/s; "
             f"QP backend '{settings.backend}' for every method; "
             f"torch threads {settings.threads}; instantaneous IK: tolerance {settings.tolerance:g}, step tolerance "
             f"{settings.step_tolerance:g}, at most {settings.max_iterations} iterations; step times are processor "
             f"time, the least of {settings.repeats} runs (wall-clock in results.csv); "
             f"{platform.processor() or platform.machine()}, torch {torch.__version__}; wall time {wall_time:.0f} s.", "",
             "| model | scenario | method | MNTE median | MNTE p99 | ω RMSE median (rad/s) | ω RMSE p99 | "
             "step median (ms) | step p99 (ms) | spread p99/median | iterations mean, p99 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['scenario']} | {r['method']} | {r['mnte_median']:.2e} | {r['mnte_p99']:.2e} | "
                     f"{r['rmse_median']:.2e} | {r['rmse_p99']:.2e} | {r['time_median_ms']:.2f} | {r['time_p99_ms']:.2f} | "
                     f"{r['spread']:.2f} | {r['iterations_mean']:.1f}, {r['iterations_p99']:.0f} |")
    for scheme in ("midpoint", "paper"):
        table = ratios(rows, scheme)
        if not table:
            continue
        lines += ["", f"## Ratios, dynamical ({scheme})", "",
                  "Step time of whole-body (WB) and pair-wise (PW) over the dynamical method's (above 1: the dynamical "
                  "method is faster); spreads p99/median; MNTE of the dynamical method over whole-body's (where "
                  "whole-body's is below 1e-12 the targets are reachable and reached to its tolerance: the ratio then "
                  "compares two errors far below any sensor's accuracy).", "",
                  "| model | scenario | WB/dyn median | WB/dyn p99 | PW/dyn median | PW/dyn p99 | spread dyn | spread WB | "
                  "spread PW | MNTE dyn/WB | faster | steadiest | MNTE within 2x |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        mark = lambda ok: "yes" if ok else "**no**"  # noqa: E731
        for r in table:
            lines.append(f"| {r['model']} | {r['scenario']} | {r['wb_median']:.1f} | {r['wb_p99']:.1f} | "
                         f"{r['pw_median']:.1f} | {r['pw_p99']:.1f} | {r['spread_dyn']:.2f} | {r['spread_wb']:.2f} | "
                         f"{r['spread_pw']:.2f} | {r['mnte_ratio']:.3g} | {mark(r['faster'])} | "
                         f"{mark(r['steadiest'])} | {mark(r['accurate'])} |")
    return "\n".join(lines) + "\n"

"""The diagnosis loop on the measured recordings in ../shared/data, with Human48 and Human66.

    python experiments/diagnose_measured.py [--out experiments/diagnosis] [--reports DIR] [--only NAME ...]

For every recording (through its link map, calibrated as `torchik track` would) and model, runs
`torchik.pipelines.diagnosis.loop.diagnose` and writes into --out:

    results.md     per recording and model: each effect added, its parameters and score, the MNTE and
                   angular-velocity RMSE before and after it; what was rejected; what remains
    results.json   the same numbers
    <name>.png     Human48's error per link before and after (the model with something to find)
    summary.png    MNTE before and after, every recording and both models

--reports DIR also writes each run's full report (report.md, calibration.json, model.urdf,
residuals.rrd) under DIR/<name>_<model>/ (large: keep it out of the repository). The recordings
are read where they lie; nothing of them is copied.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchik.io import map_recording, read
from torchik.method.kinematics import KinematicModel
from torchik.method.models import TRACKED_LINKS, human_urdf
from torchik.pipelines.diagnosis.loop import Diagnosis, diagnose
from torchik.pipelines.diagnosis.report import errors_figure, write

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
MODELS = ("human48", "human66")


@dataclass(frozen=True)
class Source:
    """A recording: its file under DATA, link map, static trial or frame that calibrates the map."""

    name: str
    file: str
    map: str | None = None
    static: str | None = None
    frame: int | str | None = None
    what: str = ""


SOURCES = (
    Source("HC002D06", "c3d/HC002D06.c3d", "plugin_gait_to_human", "c3d/HC002D02.c3d", None,
           "C3D, subject HC002, straight walk"),
    Source("HC002D25", "c3d/HC002D25.c3d", "plugin_gait_to_human", "c3d/HC002D02.c3d", None,
           "C3D, subject HC002, turning walk"),
    Source("HC030A05", "c3d/HC030A05.c3d", "plugin_gait_to_human", "c3d/HC030A01.c3d", None,
           "C3D, subject HC030, straight walk"),
    Source("HC030A22", "c3d/HC030A22.c3d", "plugin_gait_to_human", "c3d/HC030A01.c3d", None,
           "C3D, subject HC030, turning walk"),
    Source("bandai_walk_1", "bvh/bandai_walk_normal_001.bvh", "bandai_to_human", "bvh/bandai_walk_normal_001.bvh", 0,
           "BVH (Bandai Namco), walk"),
    Source("bandai_walk_2", "bvh/bandai_walk_normal_002.bvh", "bandai_to_human", "bvh/bandai_walk_normal_001.bvh", 0,
           "BVH (Bandai Namco), walk"),
    Source("bandai_run_1", "bvh/bandai_run_normal_001.bvh", "bandai_to_human", "bvh/bandai_walk_normal_001.bvh", 0,
           "BVH (Bandai Namco), run"),
    Source("bandai_run_2", "bvh/bandai_run_normal_002.bvh", "bandai_to_human", "bvh/bandai_walk_normal_001.bvh", 0,
           "BVH (Bandai Namco), run"),
    Source("cmu_131_01", "bvh/cmu_131_01.bvh", "cmu_to_human", None, "rest", "BVH (CMU), start, walk, stop"),
    Source("mvnx", "mvnx/test_mocap.mvnx", None, None, None, "MVNX (Xsens MVN, upper-body configuration)"),
)


def recording_of(source: Source, model: KinematicModel):
    """The recording in the model's links (mapped and calibrated when the source needs it)."""
    recording = read(str(DATA / source.file))
    if source.map:
        static = read(str(DATA / source.static)) if source.static else None
        recording, _ = map_recording(recording, source.map, model, static, source.frame)
    return recording


def run(source: Source, model_name: str, max_effects: int, reports: Path | None) -> tuple[Diagnosis, dict]:
    urdf = human_urdf(int(model_name[-2:]))
    model = KinematicModel.from_urdf(urdf, name=f"Human{model_name[-2:]}")
    recording = recording_of(source, model)
    links = [name for name in TRACKED_LINKS[model_name] if name in recording.links]
    start = time.perf_counter()
    lines: list[str] = []
    d, = diagnose(model, urdf, [recording], links, max_effects=max_effects, log=lines.append)
    seconds = time.perf_counter() - start
    if reports is not None:
        write(d, reports / f"{source.name}_{model_name}", source.file, model.name)
    result = dict(recording=source.name, file=source.file, what=source.what, model=model.name, links=len(links),
                  frames=len(recording.time), rate_hz=recording.frame_rate, seconds=seconds, complete=d.complete,
                  rounds=d.rounds, stop=d.stop, why_stopped=d.why_stopped,
                  before=d.before.overall, after=d.after.overall, log=lines,
                  steps=[dict(effect=s.effect.to_json(), summary=s.effect.summary(), before=s.before.overall,
                              after=s.after.overall) for s in d.steps],
                  rejected=[dict(kind=e.kind, target=e.target, score=e.score, notes=e.notes) for e in d.rejected],
                  best_left=None if d.best_rejected is None else dict(summary=d.best_rejected.summary(),
                                                                       score=d.best_rejected.score,
                                                                       notes=d.best_rejected.notes),
                  unobservable=sorted({f"{e.kind}: {e.notes}" for e in d.unobservable}),
                  unobservable_count={k: sum(e.kind == k for e in d.unobservable)
                                      for k in sorted({e.kind for e in d.unobservable})},
                  remaining=d.remaining[:3])
    return d, result


def _g(x: float) -> str:
    return f"{x:.3g}" if x is not None and math.isfinite(x) else "-"


def markdown(results: list[dict]) -> str:
    lines = ["# Diagnosis of the measured recordings: results", "",
             "Written by `python experiments/diagnose_measured.py`; read README.md for what they mean.", "",
             "| recording | model | frames | rounds | stopped | effects kept | MNTE before → after | ratio "
             "| RMSE (rad/s) before → after | time (s) |",
             "|---|---|---:|---:|---|---:|---|---:|---|---:|"]
    limit = results[0]["max_effects"] if results else 0
    for r in results:
        b, a = r["before"]["mnte"], r["after"]["mnte"]
        lines.append(f"| {r['recording']} | {r['model']} | {r['frames']} | {r['rounds']} | {r['stop']} | "
                     f"{len(r['steps'])} | {_g(b)} → {_g(a)} | "
                     f"{_g(b / a) if a > 0 else '-'} | {_g(r['before']['rmse'])} → {_g(r['after']['rmse'])} | "
                     f"{r['seconds']:.0f} |")
    for r in results:
        lines += ["", f"## {r['recording']} ({r['what']}), {r['model']}", ""]
        if r["steps"]:
            lines += ["| # | effect | score | MNTE before → after | RMSE before → after (rad/s) |", "|---|---|---:|---|---|"]
            for k, s in enumerate(r["steps"], 1):
                lines.append(f"| {k} | {s['summary']} | {s['effect']['score']:.0f} | {_g(s['before']['mnte'])} → "
                             f"{_g(s['after']['mnte'])} | {_g(s['before']['rmse'])} → {_g(s['after']['rmse'])} |")
        else:
            lines.append("Nothing added.")
        for e in r["rejected"]:
            lines.append(f"- not kept: {e['kind']} at {e['target']} (score {e['score']:.0f}): {e['notes']}")
        lines.append(f"- why the loop stopped (after {r['rounds']} rounds that added effects, at most {limit}): "
                     f"{r['why_stopped']}")
        if r["complete"] and r["best_left"]:
            left = r["best_left"]
            why = f": {left['notes']}" if left.get("notes") else ""
            lines.append(f"- best candidate left: {left['summary']} (score {left['score']:.1f}){why}")
        for kind, count in r["unobservable_count"].items():
            lines.append(f"- not identifiable: {kind} at {count} links")
        where = ", ".join(f"{row['link']} {row['rms_deg']:.1f} deg" for row in r["remaining"])
        lines.append(f"- largest residuals left (rms): {where}")
    return "\n".join(lines) + "\n"


def summary_figure(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["recording"] for r in results))
    fig, ax = plt.subplots(figsize=(10, 4))
    x = np.arange(len(names))
    for k, (model, colour) in enumerate((("Human48", "tab:red"), ("Human66", "tab:blue"))):
        rows = {r["recording"]: r for r in results if r["model"] == model}
        before = [rows[n]["before"]["mnte"] if n in rows else np.nan for n in names]
        after = [rows[n]["after"]["mnte"] if n in rows else np.nan for n in names]
        offset = -0.2 + 0.4 * k
        ax.bar(x + offset - 0.09, before, 0.18, color=colour, alpha=0.35, label=f"{model} before")
        ax.bar(x + offset + 0.09, after, 0.18, color=colour, label=f"{model} after")
    ax.set_yscale("log")
    ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("MNTE (1 - cos)")
    ax.set_title("tracking error before and after the effects the loop added")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "diagnosis"))
    parser.add_argument("--reports", help="also write each run's full report under this folder")
    parser.add_argument("--only", nargs="*", help="recordings to run (names as in results.md)")
    parser.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    parser.add_argument("--max-effects", type=int, default=10)
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"{DATA}: no measured data here; nothing to do")
        return 1
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    reports = Path(args.reports) if args.reports else None
    results = []
    for source in SOURCES:
        if args.only and source.name not in args.only:
            continue
        for model_name in args.models:
            d, result = run(source, model_name, args.max_effects, reports)
            result["max_effects"] = args.max_effects
            results.append(result)
            print(f"{source.name} {result['model']}: {len(result['steps'])} effects, MNTE {_g(result['before']['mnte'])} -> "
                  f"{_g(result['after']['mnte'])} ({result['seconds']:.0f} s)", flush=True)
            for line in result["log"]:
                print("    " + line, flush=True)
            if model_name == "human48":
                errors_figure(d, out / f"{source.name}.png", f"{source.name} ({source.what}), Human48: error per link, "
                                                             f"before and after the {len(d.effects)} effects found")
    (out / "results.json").write_text(json.dumps(results, indent=1, default=float) + "\n")
    (out / "results.md").write_text(markdown(results))
    summary_figure(results, out / "summary.png")
    print(f"wrote {out}/results.md, results.json, summary.png and the figures")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

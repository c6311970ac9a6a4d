"""The diagnosis tried on recordings it shares no assumption with, scored against what was injected.

    python experiments/diagnosis_study.py [--seeds 10] [--pairs 10] [--clean 20] [--duration 12]
                                          [--families F1,F2] [--json FILE] [--markdown FILE] [--recordings DIR]

Recordings come from experiments/diagnosis_generator.py: the published Human48 (Human66 for a
missing axis) through pinocchio's kinematics, not torchik's, with white, AR(1) or 1/f noise.

Each recording carries one effect of a family (FAMILIES, on random links with random sizes over
the ranges of diagnosis_generator.draw), two effects of different families, or none. `torchik.diagnose` (the library
API, Human48 as `torchik diagnose --model human48` builds it) runs on each; scored: every injected
effect named on its links, spurious effects kept, nothing on clean ones, and the MNTE after against
tracking the same recording without the effect (same motion and noise).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from diagnosis_generator import FAMILIES, NOISES, OPTIONAL, Case, Injected, generate

# ------------------------------------------------------------------------------ scoring
SIZE = {"misalignment": lambda p: np.degrees(np.linalg.norm(p["rotation_vector"])),
        "gyro_bias": lambda p: np.degrees(np.linalg.norm(p["bias"])), "gyro_scale": lambda p: 100 * p["scale_error"],
        "stream_delay": lambda p: 1e3 * p["delay"], "sensor_delay": lambda p: 1e3 * p["delay"],
        "heading_drift": lambda p: np.degrees(p["rate"]),
        "missing_dof": lambda p: np.degrees(0.5 * (p["angle_range"][1] - p["angle_range"][0]))}


def judge(injected: list[Injected], effects) -> dict:
    """Which injected effects were named on their links, which kept effects name none (spurious)."""
    matched, named, sizes = set(), [], []
    for inj in injected:
        found_all = True
        for target, size in zip(inj.targets, inj.sizes):
            hit = [k for k, e in enumerate(effects) if e.kind in inj.kinds() and e.target == target]
            found_all &= bool(hit)
            matched.update(hit)
            sizes += [dict(family=inj.family, target=target, injected=float(size),
                           found=float(SIZE[effects[k].kind](effects[k].params))) for k in hit[:1]]
        # a device's delay found on single gyros: the right cause, not spurious, not named as one
        matched.update(k for k, e in enumerate(effects) if inj.family == "stream_delay" and e.kind == "stream_delay")
        named.append(found_all)
    spurious = [f"{e.kind} at {e.target}" for k, e in enumerate(effects) if k not in matched]
    return dict(named=all(named), spurious=spurious, sizes=sizes)


def run_case(case: Case, model, urdf: str, links, args) -> dict:
    from torchik import diagnose
    from torchik.pipelines.diagnosis.analysis import analyse
    from torchik.pipelines.diagnosis.loop import errors

    recording, clean, injected, noise = generate(case, links, args.duration, args.rate, args.gyro_frame)
    start = time.perf_counter()
    d = diagnose(model, urdf, [recording], links, max_effects=args.max_effects)[0]
    seconds = time.perf_counter() - start
    reference = errors(analyse(model, [clean], links), 0).overall["mnte"]
    verdict = judge(injected, d.effects)
    return dict(seed=case.seed, group=case.group, families=list(case.families), noise=noise, seconds=seconds,
                injected=[dict(family=i.family, targets=i.targets, sizes=[float(x) for x in i.sizes], unit=i.unit)
                          for i in injected],
                kept=[e.summary() for e in d.effects], rejected=[f"{e.kind} at {e.target}: {e.notes}" for e in d.rejected],
                complete=d.complete, stop=d.stop, noise_share=d.noise.share if d.noise else None,
                mnte_before=d.before.overall["mnte"], mnte_after=d.after.overall["mnte"], mnte_clean=reference, **verdict)


def cases(args) -> list[Case]:
    rng = np.random.default_rng(args.seed)
    out = [Case(args.seed * 10000 + 100 * f + s, (family,), NOISES[(f + s) % len(NOISES)])
           for f, family in enumerate(args.families) for s in range(args.seeds)]
    for k in range(args.pairs):
        pair = tuple(str(x) for x in rng.choice(args.families, 2, replace=False))
        out.append(Case(args.seed * 10000 + 5000 + k, pair, NOISES[k % len(NOISES)]))
    out += [Case(args.seed * 10000 + 7000 + k, (), NOISES[k % len(NOISES)]) for k in range(args.clean)]
    return [case for case in out if not args.only or case.seed in args.only]


# ------------------------------------------------------------------------------ table
def table(results: list[dict]) -> str:
    groups: dict[str, list[dict]] = {}
    for r in results:
        groups.setdefault(r["group"], []).append(r)
    lines = ["| recordings | n | injected named on their links | nothing spurious kept | spurious kept, per recording "
             "| MNTE after / clean (median, max) | time (s, median, max) |", "|---|---|---|---|---|---|---|"]
    for name, rows in groups.items():
        ratio = [r["mnte_after"] / max(r["mnte_clean"], 1e-30) for r in rows]
        named = "-" if name == "clean" else f"{sum(r['named'] for r in rows)} of {len(rows)}"
        seconds = [r["seconds"] for r in rows]
        lines.append(f"| {name} | {len(rows)} | {named} | {sum(not r['spurious'] for r in rows)} of {len(rows)} | "
                     f"{', '.join(str(len(r['spurious'])) for r in rows)} | {np.median(ratio):.2f}, {max(ratio):.2f} | "
                     f"{np.median(seconds):.0f}, {max(seconds):.0f} |")
    effect = [r for r in results if r["group"] != "clean"]
    clean = [r for r in results if r["group"] == "clean"]
    ratio = [r["mnte_after"] / max(r["mnte_clean"], 1e-30) for r in results]
    lines += ["", f"Injected effects all named on their links: {sum(r['named'] for r in effect)} of {len(effect)}; "
              f"nothing spurious kept: {sum(not r['spurious'] for r in effect)} of {len(effect)}; "
              f"nothing kept on clean recordings: {sum(not r['spurious'] for r in clean)} of {len(clean)}; "
              f"MNTE after within 1.5x of the clean recording's: {sum(x <= 1.5 for x in ratio)} of {len(ratio)}."]
    return "\n".join(lines)


_WORKER: dict = {}


def _start_worker(args) -> None:
    """A study process: one torch thread, the diagnosed model loaded once."""
    from torchik.method.models import TRACKED_LINKS, human_urdf, load_model

    torch.set_num_threads(1)
    _WORKER.update(args=args, urdf=human_urdf(48), model=load_model("human48"), links=list(TRACKED_LINKS["human48"]))


def _diagnosed(case: Case) -> dict:
    w = _WORKER
    return run_case(case, w["model"], w["urdf"], w["links"], w["args"])


@contextlib.contextmanager
def _pool(args):
    """An object with imap: --jobs processes (spawned: torch's threads do not survive a fork), or this one."""
    if args.jobs <= 1:
        _start_worker(args)
        yield SimpleNamespace(imap=map)
        return
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(args.jobs, _start_worker, (args,)) as pool:
        yield pool


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="recordings per family (default 10)")
    parser.add_argument("--pairs", type=int, default=10, help="recordings with two effects of different families")
    parser.add_argument("--clean", type=int, default=20, help="recordings with no effect")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds per recording (default 12)")
    parser.add_argument("--rate", type=float, default=50.0, help="frames per second (default 50)")
    parser.add_argument("--families", type=lambda s: tuple(s.split(",")), default=FAMILIES,
                        help=f"comma-separated, of {', '.join(FAMILIES + OPTIONAL)} (default the first six)")
    parser.add_argument("--max-effects", type=int, default=8, help="the loop's rounds (default 8, as torchik diagnose)")
    parser.add_argument("--seed", type=int, default=1, help="the study's seed (default 1)")
    parser.add_argument("--only", type=lambda s: {int(x) for x in s.split(",")}, default=set(),
                        help="comma-separated seeds: only these of the study's recordings (as the table names them)")
    parser.add_argument("--gyro-frame", choices=("true", "estimated"), default="true",
                        help="the orientation that rotates the gyros into the world frame: the noise-free one "
                             "(default, as the study always did) or the recording's own, as a device does "
                             "(diagnosis_generator.generate)")
    parser.add_argument("--jobs", type=int, default=1, help="recordings diagnosed at once, each in its own process on "
                                                           "one thread (default 1)")
    parser.add_argument("--json", metavar="FILE", help="write every recording's result here")
    parser.add_argument("--markdown", metavar="FILE", help="write the table here")
    parser.add_argument("--recordings", metavar="DIR", help="only write each recording to DIR/GROUP_SEED.npz (to time "
                                                            "`torchik diagnose` on them), diagnose none")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    from torchik.method.models import TRACKED_LINKS

    links = list(TRACKED_LINKS["human48"])
    if args.recordings:
        from torchik.io.recording import save_recording

        Path(args.recordings).mkdir(parents=True, exist_ok=True)
        for case in cases(args):
            path = Path(args.recordings) / f"{case.group.replace(' ', '_')}_{case.seed}.npz"
            print(save_recording(generate(case, links, args.duration, args.rate, args.gyro_frame)[0], path))
        return 0
    results = []
    with _pool(args) as pool:
        for case, r in zip(cases(args), pool.imap(_diagnosed, cases(args))):
            results.append(r)
            print(f"{case.group:>14} seed {case.seed} {case.noise:>5}: {'named' if r['named'] else 'MISSED'}, "
                  f"spurious {r['spurious']}, MNTE {r['mnte_after']:.3g} (clean {r['mnte_clean']:.3g}), "
                  f"{r['seconds']:.0f} s", file=sys.stderr, flush=True)
    text = table(results)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

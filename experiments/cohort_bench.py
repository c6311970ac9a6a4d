"""Trials per minute of `torchik cohort` on a generated cohort, with 1 and 2 Dask workers.

Generates the cohort the tests use (`torchik.pipelines.cohort.synthetic`: 10 subjects of 1.50 to 1.95 m, 4
trials each, alternately Human66 and Human48, walking and running, 1 to 2 s at 50 Hz; longer with
--durations and --rate), then for each worker count starts a LocalCluster of that many
single-threaded worker processes and tracks the whole cohort into a fresh folder. Prints, per
worker count: the batch sizes, the seconds from the first task to the last result (which includes
the workers' first import of torch and compiling the subjects' models), the trials per minute over
them, and the cluster's start-up. With --baseline, also the trials per minute of tracking each
trial alone in this process, one after another (what a loop over `torchik track` does, less
starting Python).

    python experiments/cohort_bench.py [--workers 1 2] [--subjects 10] [--trials 4] [--rate 50]
                                       [--durations 1 1.5 2] [--batch-size N] [--baseline] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from torchik.pipelines.cohort import read_manifest, run_cohort, write_synthetic_cohort


def baseline(manifest: Path) -> float:
    """Trials per minute tracking each trial alone, in this process, on one thread."""
    from torchik.method.settings import TrackerSettings
    from torchik.pipelines.cohort.trial import prepare
    from torchik.pipelines.track import track_recording

    specs = read_manifest(manifest)
    start = time.perf_counter()
    for spec in specs:
        p = prepare(spec)
        settings = TrackerSettings(position_gain=spec.position_gain, orientation_gain=spec.orientation_gain,
                                   scheme=spec.scheme, backend=spec.backend)
        track_recording(p.model, p.recording, p.links, settings, transient=spec.transient)
    return 60.0 * len(specs) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts (default 1 2)")
    parser.add_argument("--subjects", type=int, default=10)
    parser.add_argument("--trials", type=int, default=4, help="trials per subject (default 4)")
    parser.add_argument("--rate", type=float, default=50.0, help="Hz (default 50)")
    parser.add_argument("--durations", type=float, nargs="+", default=[1.0, 1.5, 2.0], help="s (default 1 1.5 2)")
    parser.add_argument("--batch-size", type=int, help="trials per batch at most (default: the cohort's choice)")
    parser.add_argument("--baseline", action="store_true", help="also time the trials one by one in this process")
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    torch.set_num_threads(1)

    with tempfile.TemporaryDirectory() as tmp:
        manifest = write_synthetic_cohort(Path(tmp) / "cohort", args.subjects, args.trials, args.rate,
                                          tuple(args.durations))
        print(f"cohort: {len(read_manifest(manifest))} trials, {args.subjects} subjects, {args.rate:g} Hz, "
              f"durations {args.durations} s")
        figures = []
        for n in args.workers:
            wall = time.perf_counter()
            result = run_cohort(manifest, Path(tmp) / f"out{n}", workers=n, batch_size=args.batch_size)
            wall = time.perf_counter() - wall
            figures.append(dict(workers=n, trials=result.tracked, failed=result.failed,
                                batch_sizes=list(result.batch_sizes), seconds=result.seconds,
                                trials_per_minute=result.trials_per_minute, startup_s=result.startup_s,
                                wall_s=wall, trials_per_minute_wall=60.0 * result.tracked / wall))
            sizes = ", ".join(map(str, result.batch_sizes))
            print(f"{n} worker{'s' if n > 1 else ' '}: {result.trials_per_minute:6.0f} trials/min "
                  f"({result.tracked} trials in {result.seconds:.1f} s; batches {sizes}; "
                  f"{result.failed} failed); cluster start {result.startup_s:.1f} s, whole call {wall:.1f} s "
                  f"({figures[-1]['trials_per_minute_wall']:.0f} trials/min)")
        if args.baseline:
            rate = baseline(manifest)
            figures.append(dict(workers=0, trials_per_minute=rate))
            print(f"one by one in this process: {rate:.0f} trials/min")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()

"""`torchik cohort MANIFEST --out DIR`: track the trials a manifest lists, in batches of one
topology, on a local Dask cluster or one given by address. Each trial's results land in
DIR/trials/<trial>/ as its batch finishes (estimate.npz, result.json, trial.rrd with --rrd);
DIR/summary.csv and summary.parquet hold one row per trial (MNTE, RMSE, time, failures). Running
the same command again tracks only the trials not finished. Exit 1 when a trial failed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError

EXAMPLES = """examples:
  torchik cohort study/manifest.toml --out results/          on this machine: one worker per core
  torchik cohort study/manifest.csv --out results/ --workers 2 --batch-size 16
  torchik cohort study/manifest.toml --out /shared/results --scheduler tcp://10.0.0.5:8786
  torchik cohort study/manifest.toml --out results/           again: only the unfinished trials
  python -c "import pandas as pd; print(pd.read_parquet('results/summary.parquet'))"

manifest (TOML; a CSV has the same columns, one row per trial):
  [defaults]
  model = "human48"                  # or human66, icub, a .urdf; height/mass generate a human model
  [subjects.s01]
  height = 1.72
  mass = 70
  [[trials]]
  trial = "s01_walk"
  subject = "s01"
  recording = "s01/walk.npz"         # relative to the manifest; .npz, .mvnx, .bvh, .c3d
  map = "xsens_to_human"             # optional, with calibration = "s01/static.c3d"

columns: trial, subject, recording, model, height, mass, segments, map, calibration,
calibration_frame, scheme, gain, position_gain, orientation_gain, backend, transient, rrd
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `torchik cohort`."""
    parser = subparsers.add_parser(
        "cohort", help="track every trial of a study (a CSV or TOML manifest) on a Dask cluster; resumable",
        description=__doc__, epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("manifest", help="the trials: a .csv or .toml file")
    parser.add_argument("--out", required=True, metavar="DIR", help="the results folder (made when missing)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://10.0.0.5:8786 (workers "
                       "must see the files at the same paths); default: a local cluster")
    where.add_argument("--workers", type=int, metavar="N",
                       help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--batch-size", type=int, metavar="N", help="trials per batch at most (default: two "
                        "batches per worker or more, 64 at most)")
    parser.add_argument("--rrd", action="store_true", help="also write a rerun recording of every trial")
    parser.add_argument("--retry-failed", action="store_true", help="track the trials that failed before again")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar)")
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from ..pipelines.cohort.manifest import read_manifest
    from ..pipelines.cohort.run import run_cohort

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be positive, got {args.workers}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is a file; --out names a folder")
    specs = read_manifest(args.manifest)  # every manifest error before a cluster starts
    try:
        result = run_cohort(specs, out, scheduler=args.scheduler, workers=args.workers, batch_size=args.batch_size,
                            rrd=args.rrd, retry_failed=args.retry_failed, progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"torchik cohort: interrupted; the trials finished are kept in {out / 'trials'}, and "
              f"{out / 'summary.csv'} lists them; run the same command to finish", file=sys.stderr)
        return 130
    failed = [r for r in result.rows if r["status"] == "failed"]
    if not args.quiet:
        print(f"cohort {args.manifest}: {result.trials} trials, {result.skipped} finished before")
        if result.tracked:
            print(f"tracked {result.tracked} trials in {result.seconds:.1f} s "
                  f"({result.trials_per_minute:.0f} trials/min) "
                  f"on {result.workers} workers, in {len(result.batch_sizes)} batches of "
                  f"{', '.join(map(str, result.batch_sizes))}; {result.failed} failed")
        for row in failed:
            print(f"    failed: {row['trial']}: {row['error']}")
        print(f"wrote {out / 'summary.csv'} and {out / 'summary.parquet'}")
    return 1 if failed else 0

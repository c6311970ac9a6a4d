"""Time inverse dynamics, torchik (batched) against a per-configuration loop of pinocchio's rnea.

The measurement is `torchik bench --dynamics`'s (torchik/pipelines/bench_dynamics.py: random states,
checked against pinocchio first, the fastest of repeated calls), here with several batch sizes at
once. torchik.memory's `keep_freed_memory()` is on, as in `torchik bench` (see that module for why).

    python experiments/bench_dynamics.py [--threads 2] [--batches 1 64 1024] [--compile] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from dataclasses import asdict

import torch

from torchik.pipelines import bench_dynamics
from torchik.pipelines.memory import keep_freed_memory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--models", nargs="+", default=list(bench_dynamics.MODELS))
    parser.add_argument("--devices", nargs="+", default=["cpu"])
    parser.add_argument("--compile", action="store_true", help="also CompiledInverseDynamics")
    parser.add_argument("--json", help="write the results here as JSON")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    keep_freed_memory()
    rows = bench_dynamics.run(args.models, args.batches, args.devices, compiled=args.compile, progress=False)
    print(f"inverse dynamics, float64, {args.threads} torch threads, {platform.processor() or platform.machine()}")
    print(bench_dynamics.table(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(threads=args.threads, rows=[asdict(r) for r in rows]), f, indent=2)


if __name__ == "__main__":
    main()

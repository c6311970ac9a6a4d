"""Per-step time of the tracker for Human66 on one CPU core: 23 orientation targets + the base position.

Tracks 2000 steps of a walking-like motion (100 Hz) with the default scheme and prints the median
and 99th percentile of the step time, split into kinematics, QP (PIQP through qpsolvers) and the
rest (target cleaning, residuals, bounds, integration, diagnostics).

With --compile the step is replayed compiled (TrackerSettings(compile=True)): one computation, whose
kinematics and QP are not timed apart, and the capture's seconds are printed.

    python experiments/step_timing.py [--steps 2000] [--scheme midpoint|paper] [--threads 1] [--compile] [--json out.json]
"""

from __future__ import annotations

import argparse
import json

import torch

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.tracker import DynamicalIK
from torchik.pipelines.memory import keep_freed_memory
from torchik.synthetic.motion import periodic_motion, targets_from_motion


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--scheme", default="midpoint", choices=("midpoint", "paper"))
    parser.add_argument("--model", default="human66", choices=("human66", "human48", "icub"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action="store_true", help="replay the usual step compiled")
    parser.add_argument("--json")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    keep_freed_memory()

    model, links = load_model(args.model), TRACKED_LINKS[args.model]
    rate = 100
    motion = periodic_motion(model, (args.steps + 100) / rate, rate)
    sequence = targets_from_motion(model, motion, links)
    tracker = DynamicalIK(model, links, dt=1.0 / rate, scheme=args.scheme, compile=args.compile)
    trajectory = tracker.run(sequence, initial=motion.state(0), progress=False)
    d = {k: v[100:] for k, v in trajectory.diagnostics.items()}  # the first 100 steps warm up
    rest = d["step_time"] - d["kinematics_time"] - d["qp_time"]
    rows = {"step": d["step_time"], "kinematics": d["kinematics_time"], "qp": d["qp_time"], "rest": rest}
    if args.compile:  # the replayed steps are one computation; the others (with an active bound, say) eager
        rows = {"step": d["step_time"]}
        assert tracker.captured is not None and tracker.captured.compile_seconds is not None
        print(f"capture: {tracker.captured.compile_seconds:.1f} s; steps run eagerly after the warm-up: "
              f"{int((~torch.isnan(d['kinematics_time'])).sum())}")
    result = {name: {"median_ms": float(v.median()) * 1e3, "p99_ms": float(v.quantile(0.99)) * 1e3}
              for name, v in rows.items()}
    print(f"{args.model}, {len(links)} orientation targets + base position, scheme {args.scheme}, "
          f"{args.threads} thread(s), {len(rest)} steps{', compiled' if args.compile else ''}")
    print(f"{'':12s} {'median ms':>10s} {'p99 ms':>10s}")
    for name, r in result.items():
        print(f"{name:12s} {r['median_ms']:>10.3f} {r['p99_ms']:>10.3f}")
    err = float((trajectory.joint_positions - motion.joint_positions[: len(trajectory.joint_positions)])[100:].abs().max())
    print(f"max joint error after the transient: {err:.2e} rad")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(model=args.model, scheme=args.scheme, threads=args.threads, **result), f, indent=2)


if __name__ == "__main__":
    main()

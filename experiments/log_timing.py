"""Time to track a long sequence and time to log it to a rerun recording, measured separately.

Tracks the built-in walking scenario (default: 10 minutes at 100 Hz, Human66, one subject) as
`torchik track` does, computes the paper's metrics (MNTE, angular-velocity RMSE) over it, and
writes the .rrd that `torchik track --rrd` writes. Prints the three times and the file's size; the
logging is meant to take less time than the tracking.

    python experiments/log_timing.py [--duration 600] [--rate 100] [--model human66] [--threads N] [--rrd FILE] [--json FILE]

The .rrd goes to a temporary folder and is deleted unless --rrd names where to keep it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from torchik.method.models import TRACKED_LINKS, human_urdf, icub_urdf_path, load_model
from torchik.method.state import TargetSequence
from torchik.method.tracker import DynamicalIK
from torchik.pipelines.evaluation import tracking_errors
from torchik.pipelines.memory import keep_freed_memory
from torchik.pipelines.rrd import log_trajectory
from torchik.synthetic.motion import Motion, targets_from_motion
from torchik.synthetic.scenarios import scenario_motion


def walking_targets(model, links, duration: float, rate: float, chunk: int = 2000) -> TargetSequence:
    """The walking scenario's targets (what `torchik track --scenario walking` tracks), computed a
    few thousand samples at a time: all at once, a 10-minute sequence's Jacobians alone take 5 GB."""
    motion = scenario_motion("walking", model, duration, rate)
    parts = [targets_from_motion(model, Motion(*(x[start:start + chunk] for x in vars(motion).values())), links)
             for start in range(0, len(motion.time), chunk)]
    return TargetSequence(*(torch.cat([vars(p)[name] for p in parts]) for name in vars(parts[0])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("--rate", type=float, default=100.0, help="Hz (default 100)")
    parser.add_argument("--model", default="human66", choices=("human66", "human48", "icub"))
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--rrd", help="keep the recording here")
    parser.add_argument("--json", help="write the times here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    keep_freed_memory()

    model, links = load_model(args.model), TRACKED_LINKS[args.model]
    sequence = walking_targets(model, links, args.duration, args.rate)
    tracker = DynamicalIK(model, links, dt=1.0 / args.rate)

    start = time.perf_counter()
    trajectory = tracker.run(sequence, progress=True, interruptible=True)
    track_s = time.perf_counter() - start

    start = time.perf_counter()
    trajectory.diagnostics.update(tracking_errors(model, trajectory, sequence, links))
    metrics_s = time.perf_counter() - start

    with tempfile.TemporaryDirectory() as folder:
        path = Path(args.rrd) if args.rrd else Path(folder) / "log_timing.rrd"
        urdf = icub_urdf_path() if args.model == "icub" else human_urdf(int(args.model[-2:]))
        start = time.perf_counter()
        log_trajectory(path, model, links, trajectory, sequence, urdf=urdf, progress=True)
        log_s = time.perf_counter() - start
        size_mb = path.stat().st_size / 1e6

    T = len(trajectory.time)
    result = dict(model=model.name, duration_s=args.duration, rate_hz=args.rate, steps=T, track_s=track_s,
                  step_median_ms=float(trajectory.diagnostics["step_time"].median()) * 1e3,
                  metrics_s=metrics_s, log_s=log_s, rrd_mb=size_mb, threads=torch.get_num_threads())
    print(f"{model.name}, walking, {args.duration:g} s at {args.rate:g} Hz: {T} steps, {result['threads']} threads")
    print(f"    track:   {track_s:7.1f} s  (median step {result['step_median_ms']:.2f} ms)")
    print(f"    metrics: {metrics_s:7.1f} s  (MNTE and angular-velocity RMSE of every step)")
    print(f"    log:     {log_s:7.1f} s  ({size_mb:.0f} MB .rrd; {log_s / track_s:.0%} of the tracking time)")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()

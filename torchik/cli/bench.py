"""`torchik bench`: subject-steps per second, batched and per-subject loops."""

from __future__ import annotations

import argparse
import json
import platform
from dataclasses import asdict

import torch

from ..method.models import MODELS
from ..pipelines import bench
from .common import positive


def add_parser(subparsers) -> None:
    """Register `torchik bench`."""
    parser = subparsers.add_parser(
        "bench", help="subject-steps per second, batched and per-subject loops (table and JSON)",
        description=bench.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  torchik bench\n  torchik bench --models human66 --batch 1024 --no-loops\n"
               "  torchik bench --models human66 --batch 128 1024 --no-loops --compile\n"
               "  torchik bench --device cuda --batch 1024 65536 --json gpu.json\n"
               "  torchik bench --models human66 --batch 1024 --no-loops --profile")
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--batch", nargs="+", type=int, default=list(bench.BATCHES),
                        help="batch sizes (default 1 64 1024 8192)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    parser.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--no-loops", action="store_true", help="skip the per-subject loops")
    parser.add_argument("--compile", action="store_true",
                        help="also each batch size's step captured and replayed compiled (TrackerSettings(compile=True)), "
                             "after its eager one; the capture (up to minutes the first time on a machine) is not timed; "
                             "where it cannot be made here (no compiler) the bench stops with exit code 2, "
                             "printing no table and writing no JSON")
    parser.add_argument("--loop-steps", type=int, default=200, help="steps timed per loop (default 200)")
    parser.add_argument("--seconds", type=positive, default=2.0, help="time per batched measurement, at most (default 2)")
    parser.add_argument("--max-steps", type=int, default=50, help="steps per batched measurement, at most (default 50)")
    parser.add_argument("--json", metavar="FILE", help="write the measurements here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--profile", action="store_true",
                        help="after the table, the batched step's roofline per model and batch: per phase its time, "
                             "flops and bytes per subject against this machine's measured peaks (pipelines/roofline.py)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import InputError

    if any(B < 1 for B in args.batch):
        raise InputError(f"batch sizes must be positive, got {args.batch}")
    if torch.device(args.device).type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch here")
    if args.threads:
        torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    results = bench.run(args.models, args.batch, args.device, dtype, not args.no_loops, args.loop_steps, args.seconds,
                  args.max_steps, progress=not args.quiet, compiled=args.compile)
    on_cuda = torch.device(args.device).type == "cuda"
    device_name = torch.cuda.get_device_name(0) if on_cuda else platform.processor() or platform.machine()
    print(f"torchik bench: {args.dtype}, device {args.device} ({device_name}), {torch.get_num_threads()} CPU threads")
    print(bench.table(results))
    profiles = []
    if args.profile:
        from ..pipelines import roofline

        peaks = roofline.measure_peaks(args.device)
        for name in args.models:
            for B in args.batch:
                profiles.append(roofline.profile(name, B, args.device, dtype, peaks=peaks))
                print()
                print(roofline.table(profiles[-1]))
    if args.json:
        info = dict(device=args.device, device_name=device_name, dtype=args.dtype, threads=torch.get_num_threads(),
                    torch=torch.__version__, gain=bench.GAIN, damping=bench.DAMPING, rate_hz=bench.RATE)
        with open(args.json, "w") as f:
            json.dump(dict(settings=info, results=[asdict(r) for r in results], profiles=[asdict(p) for p in profiles]),
                      f, indent=2)
        print(f"wrote {args.json}")
    return 0

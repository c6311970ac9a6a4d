"""`torchik bench`: subject-steps per second, batched and per-subject loops; with --dynamics, inverse
dynamics against a loop of pinocchio's rnea."""

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
               "  torchik bench --models human66 --batch 1024 --no-loops --profile\n"
               "  torchik bench --dynamics --threads 2\n"
               "  torchik bench --dynamics --models human48 --compile")
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--batch", nargs="+", type=int, default=None,
                        help="batch sizes (default 1 64 1024 8192; with --dynamics, 1024)")
    parser.add_argument("--device", default=None,
                        help="cpu or cuda (default cpu; with --dynamics, the CPU and CUDA where there is one)")
    parser.add_argument("--dynamics", action="store_true",
                        help="instead of the tracking step: B configurations' inverse dynamics (tk.inverse_dynamics, "
                             "and compiled with --compile) against a loop of pinocchio's rnea over the same states, "
                             "checked to agree first (pipelines/bench_dynamics.py)")
    parser.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--no-loops", action="store_true", help="skip the per-subject loops")
    parser.add_argument("--compile", action="store_true",
                        help="also each batch size's step captured and replayed compiled (TrackerSettings(compile=True)), "
                             "after its eager one; the capture (up to minutes the first time on a machine) is not timed; "
                             "where it cannot be made here (no compiler) the bench stops with exit code 2, "
                             "printing no table and writing no JSON; with --dynamics, the inverse dynamics compiled "
                             "(CompiledInverseDynamics) beside the eager call")
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

    if args.batch is not None and any(B < 1 for B in args.batch):
        raise InputError(f"batch sizes must be positive, got {args.batch}")
    if args.device is not None and torch.device(args.device).type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch here")
    if args.threads:
        torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    if args.dynamics:
        return _dynamics(args, dtype)
    args.batch = args.batch or list(bench.BATCHES)
    args.device = args.device or "cpu"
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


def _dynamics(args: argparse.Namespace, dtype: torch.dtype) -> int:
    """`torchik bench --dynamics`: the table, and the JSON with --json."""
    from ..pipelines import bench_dynamics

    devices = [args.device] if args.device else ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    models = [m for m in args.models if m in bench_dynamics.MODELS]
    results = bench_dynamics.run(models, args.batch or list(bench_dynamics.BATCHES), devices, dtype, args.compile,
                                 progress=not args.quiet)
    names = [torch.cuda.get_device_name(0) if d.startswith("cuda") else platform.processor() or platform.machine()
             for d in devices]
    print(f"torchik bench --dynamics: {args.dtype}, devices {', '.join(f'{d} ({n})' for d, n in zip(devices, names))}, "
          f"{torch.get_num_threads()} CPU threads; pinocchio float64 on the CPU")
    print(bench_dynamics.table(results))
    if args.json:
        info = dict(devices=devices, device_names=names, dtype=args.dtype, threads=torch.get_num_threads(),
                    torch=torch.__version__)
        rows = [dict(asdict(r), speedup=r.speedup, compiled_speedup=r.compiled_speedup) for r in results]
        with open(args.json, "w") as f:
            json.dump(dict(settings=info, dynamics=rows), f, indent=2)
        print(f"wrote {args.json}")
    return 0

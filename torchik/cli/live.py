"""`torchik live`: track a live stream (Xsens MVN over UDP or TCP, LSL Mocap) as it comes, every
character one row of a batch, and publish the joint states as they are estimated."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError
from ..method.models import MODELS
from ..method.qp import BACKENDS
from ..method.settings import TrackerSettings
from .common import add_command, check_outputs, model_urdf, torch_device

EXAMPLES = """examples:
  torchik live --from udp://:9763 --model human66 --map xsens_to_human --to-lsl torchik
                          track MVN's network stream (port 9763) and publish each character's joint
                          positions as the LSL stream "torchik" (LabRecorder records it); try it
                          without a suit: torchik replay walk.mvnx --to udp://127.0.0.1:9763
  torchik live --from lsl://mocap --model human66 --map xsens_to_human --out live.npz --report live.json
                          an LSL Mocap stream in; the trajectory and the report written on Ctrl-C
  torchik live --from udp://:9763 --model human48 --map xsens_to_human --rrd live.rrd --duration 60
  torchik live --from tcp://:9763 --model human66 --map xsens_to_human --to-lsl torchik --lsl-base --lsl-velocity
"""


def add_parser(subparsers) -> None:
    """Register `torchik live`."""
    p = add_command(subparsers, "live", "track a live stream (MVN UDP/TCP or LSL) and publish the joint states",
                    EXAMPLES)
    p.add_argument("--from", dest="source", required=True, metavar="URL",
                   help="udp://:PORT or udp://HOST:PORT (listen), tcp://:PORT (MVN connects), lsl://NAME")
    p.add_argument("--model", default="human66", choices=[m for m in MODELS if m != "icub"])
    p.add_argument("--map", help="link map from the stream's segments to the model's links (e.g. xsens_to_human); "
                                 "without one the segments must be the model's links")
    p.add_argument("--calibration", metavar="FILE", help="a static trial to calibrate a calibrating map on")
    p.add_argument("--rate", type=float, help="the stream's frame rate, Hz (default: from its time codes)")
    p.add_argument("--gain", type=float, default=TrackerSettings.position_gain,
                   help=f"K for positions and orientations, 1/s (default {TrackerSettings.position_gain:g})")
    p.add_argument("--backend", default=TrackerSettings.backend, choices=("auto", *BACKENDS))
    p.add_argument("--compile", action="store_true", help="replay each subject's usual step compiled: several "
                   "times faster per step, after a capture of seconds at its third step (tens the first time)")
    p.add_argument("--device", default="cpu", help="torch device: cpu (default), cuda or cuda:N")
    p.add_argument("--to-lsl", metavar="NAME", help="publish each character's joint positions as LSL stream NAME "
                   "(character c > 0: NAME-c)")
    p.add_argument("--lsl-base", action="store_true", help="also publish the base pose (x, y, z, qw, qx, qy, qz)")
    p.add_argument("--lsl-velocity", action="store_true", help="also publish the joint velocities")
    p.add_argument("--out", metavar="NPZ", help="write the trajectory here when the session stops (character c > 0: "
                   "NAME.c.npz)")
    p.add_argument("--report", metavar="JSON", help="write the report (counters, errors, latency) here at the end")
    p.add_argument("--rrd", metavar="FILE", help="write a rerun recording of character 0 here at the end")
    p.add_argument("--backlog", type=int, default=1, metavar="N", help="samples queued per character before the "
                   "oldest is stepped over (default 1: always the newest)")
    p.add_argument("--stall", type=float, default=1.0, metavar="S", help="a character silent for S seconds leaves "
                   "the batch until it comes back (default 1)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    p.add_argument("--stop-when-idle", type=float, metavar="S", help="stop once the stream has been silent S seconds")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="how long to look for an LSL stream")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from ..io import write_json
    from ..io.maps import load_map
    from ..live.sources import open_source
    from ..method.models import TRACKED_LINKS, load_model
    from ..pipelines.live import LiveOptions, Publisher, Selection, track_live

    if args.rrd and Path(args.rrd).suffix != ".rrd":
        raise InputError(f"{args.rrd}: a rerun recording's name must end in .rrd")
    check_outputs([args.report, args.out, args.rrd], args.force)
    if args.backlog < 1:
        raise InputError(f"--backlog {args.backlog}: at least 1")
    if args.rate is not None and not args.rate > 0:
        raise InputError(f"--rate {args.rate}: must be positive")
    if args.to_lsl:
        from ..live.lsl import pylsl

        pylsl()  # missing pylsl: said before anything starts
    device = torch_device(args.device)
    source = open_source(args.source, args.rate, args.timeout)  # bad URLs, busy ports, unknown streams: before any work
    if device.type == "cpu":
        torch.set_num_threads(1)  # small per-step tensors: extra threads only wait for each other
    model = load_model(args.model, device=device)
    link_map = None
    if args.map:
        link_map = load_map(args.map)
        if args.calibration:
            from ..io import read
            from ..io.maps import calibrate

            link_map = calibrate(link_map, read(args.calibration), model)
    links = TRACKED_LINKS[args.model]
    publisher = Publisher(args.to_lsl, model, args.lsl_base, args.lsl_velocity, source.rate) if args.to_lsl else None
    options = LiveOptions(backlog=args.backlog, stall_s=args.stall, duration_s=args.duration,
                          stop_when_idle_s=args.stop_when_idle)
    settings = TrackerSettings(position_gain=args.gain, orientation_gain=args.gain, backend=args.backend,
                               compile=args.compile)
    if not args.quiet:
        print(f"listening on {args.source} (Ctrl-C stops)", file=sys.stderr)
    result = track_live(source, model, lambda names: Selection.build(names, links, link_map), settings, options,
                        publisher, progress=None if args.quiet else _progress, keep_targets=bool(args.rrd))
    if not args.quiet:
        print(file=sys.stderr)
    report = dict(result.report(), source_url=args.source, model=model.name)
    if not args.quiet:
        _print_report(report)
    if args.report:
        write_json(report, args.report)
    if args.out:
        from ..io import save_trajectory

        for c, trajectory in result.trajectories.items():
            path = Path(args.out) if c == 0 else Path(args.out).with_suffix(f".{c}.npz")
            save_trajectory(trajectory, model, path)
    if args.rrd and 0 in result.trajectories:
        from ..method.state import TargetSequence
        from ..pipelines.rrd import log_trajectory

        trajectory, targets = result.trajectories[0], result.targets[0]
        stack = lambda name: torch.stack([getattr(t, name) for t in targets])  # noqa: E731
        sequence = TargetSequence(trajectory.time, stack("position"), stack("linear_velocity"), stack("rotation"),
                                  stack("angular_velocity"))
        log_trajectory(args.rrd, model, link_map.links if link_map is not None else links, trajectory, sequence,
                       urdf=model_urdf(args.model))
    if not result.trajectories:
        raise InputError(f"no sample came from {args.source}")
    return 130 if result.interrupted else 0


def _progress(result, elapsed: float) -> None:
    r = result.report()
    s = r["source"]
    latency = r["latency_ms"]
    print(f"\r{elapsed:6.0f} s  characters {len(r['characters'])}  samples {s['samples']}  skipped {r['skipped']}  "
          f"lost {s['lost']}  late {s['late']}  duplicates {s['duplicates']}  malformed {s['malformed']}"
          + (f"  latency p99 {latency['p99']:.2f} ms" if latency else ""), end="", file=sys.stderr, flush=True)


def _print_report(report: dict) -> None:
    s = report["source"]
    print(f"tracked {report['source_url']} at {report['rate_hz']:g} Hz: {s['samples']} samples; skipped "
          f"{report['skipped']}, lost {s['lost']}, late {s['late']}, duplicates {s['duplicates']}, "
          f"incomplete {s['incomplete']}, malformed {s['malformed']}")
    for c, r in report["characters"].items():
        m = r["mnte"]
        print(f"    character {c}: {r['frames']} steps over {r['duration_s']:.1f} s"
              + (f", MNTE median {m['median']:.2e}, p99 {m['p99']:.2e}" if m else ""))
    for event in report["events"]:
        print(f"    {event}")
    if report["latency_ms"]:
        lat = report["latency_ms"]
        print(f"    latency arrival to LSL: median {lat['median']:.2f} ms, p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms")

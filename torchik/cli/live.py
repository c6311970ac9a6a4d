"""`torchik live`: track a live stream (Xsens MVN over UDP or TCP, LSL Mocap) as it comes, every
character one row of a batch, and publish the joint states as they are estimated (LSL, a rerun
viewer, a robot retargeted to as it goes)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError
from ..live.sample import BACKLOG
from ..method.limits import LimitSettings
from ..method.models import MODELS
from ..method.qp import BACKENDS
from ..method.settings import TrackerSettings
from .common import add_command, check_outputs, model_urdf, positive, torch_device

EXAMPLES = """examples:
  torchik live --from udp://:9763 --model human66 --map xsens_to_human --to-lsl torchik
                          track MVN's network stream (port 9763) and publish each character's joint
                          positions as the LSL stream "torchik" (LabRecorder records it); try it
                          without a suit: torchik replay walk.mvnx --to udp://127.0.0.1:9763
  torchik live --from udp://:9763 --map xsens_to_human --viewer
                          spawn a rerun viewer and watch the bodies, targets, errors and the live
                          counters as they come (at most 30 updates a second: --viewer-rate)
  torchik live --from udp://:9763 --map xsens_to_human --viewer rerun+http://192.168.1.5:9876/proxy --rrd live.rrd
                          stream to a viewer already running on another machine, and save the session
  torchik live --from udp://:9763 --map xsens_to_human --retarget icub --to-lsl icub --out icub.npz
                          retarget to iCub as it goes: the LSL stream "icub" carries iCub's joint
                          positions, within every joint and coupled limit, as `torchik retarget` writes
  torchik live --from lsl://mocap --model human66 --map xsens_to_human --out live.npz --report live.json
                          an LSL Mocap stream in; the trajectory and the report written on Ctrl-C
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
    p.add_argument("--mvn-position-unit", choices=("m", "cm"), default="m",
                   help="the unit of an MVN stream's positions (default m, as MVN's manual states; see README)")
    p.add_argument("--gain", type=float, default=TrackerSettings.position_gain,
                   help=f"K for positions and orientations, 1/s (default {TrackerSettings.position_gain:g})")
    p.add_argument("--backend", default=TrackerSettings.backend, choices=("auto", *BACKENDS))
    p.add_argument("--compile", action="store_true", help="replay the batch's usual step compiled: several "
                   "times faster per step (one character, or many: from 32 on the joints' tree), after a capture "
                   "(seconds; one to two minutes the first time on a machine) made before listening where the "
                   "stream's rate is known (--rate, LSL) for one and --characters characters, else at the third step "
                   "of each batch size (the samples meanwhile are skipped, and counted)")
    p.add_argument("--device", default="cpu", help="torch device: cpu (default), cuda or cuda:N")
    p.add_argument("--retarget", choices=("icub",), help="also track iCub from the stream (human_to_icub map) and "
                   "publish and write iCub's joints instead of the human model's")
    p.add_argument("--max-rate", type=positive, default=LimitSettings().max_rate, metavar="RAD_S",
                   help=f"with --retarget: the robot's largest joint rate (default {LimitSettings().max_rate:g})")
    p.add_argument("--to-lsl", metavar="NAME", help="publish each character's joint positions as LSL stream NAME "
                   "(character c > 0: NAME-c)")
    p.add_argument("--lsl-base", action="store_true", help="also publish the base pose (x, y, z, qw, qx, qy, qz)")
    p.add_argument("--lsl-velocity", action="store_true", help="also publish the joint velocities")
    p.add_argument("--viewer", nargs="?", const="spawn", metavar="URL",
                   help="show the session in a rerun viewer: spawn one (no URL), or connect to one at "
                        "rerun+http://HOST:PORT/proxy")
    p.add_argument("--viewer-rate", type=positive, default=30.0, metavar="HZ",
                   help="most updates a second of the viewer and --rrd (default 30)")
    p.add_argument("--rrd", metavar="FILE", help="save the session as a rerun recording (what the viewer shows)")
    p.add_argument("--out", metavar="NPZ", help="write the trajectory here when the session stops (character c > 0: "
                   "NAME.c.npz)")
    p.add_argument("--report", metavar="JSON", help="write the report (counters, errors, latency) here at the end")
    p.add_argument("--backlog", type=int, metavar="N", help="frames per character that came at once tracked in "
                   "order, each with its own dt; further behind, the newest (1: always the newest; default "
                   f"{BACKLOG}, and the newest only while a step costs more than half a frame)")
    p.add_argument("--receiver", choices=("process", "thread"), default="process",
                   help="receive a udp:// stream in a process of its own (default: the tracker then never waits for "
                        "the receiver's Python) or in a thread of the tracker's")
    p.add_argument("--characters", type=int, default=1, metavar="N", help="characters the stream is expected to "
                   "bring (default 1): before saying it is listening, the tracker is warmed up for that batch")
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
    from ..live.sources import open_source
    from ..method.models import TRACKED_LINKS, load_model
    from ..pipelines.live import LiveOptions, Selection, track_live

    _check(args)
    device = torch_device(args.device)
    source = open_source(args.source, args.rate, args.timeout, 0.01 if args.mvn_position_unit == "cm" else 1.0,
                         receiver_process=args.receiver == "process", backlog=args.backlog)
    if device.type == "cpu":
        torch.set_num_threads(1)  # small per-step tensors: extra threads only wait for each other
    model = load_model(args.model, device=device)
    link_map = _link_map(args, model)
    links = link_map.links if link_map is not None else TRACKED_LINKS[args.model]
    publisher, viewer, retarget = _outputs(args, model, links, source.rate)
    options = LiveOptions(backlog=args.backlog, stall_s=args.stall, duration_s=args.duration,
                          stop_when_idle_s=args.stop_when_idle, keep_states=bool(args.out), characters=args.characters)
    settings = TrackerSettings(position_gain=args.gain, orientation_gain=args.gain, backend=args.backend,
                               compile=args.compile)

    def ready() -> None:  # once the tracker is warmed up and the receiver reads: no sample waits for them
        print(f"listening on {args.source} (Ctrl-C stops)", file=sys.stderr, flush=True)

    result = track_live(source, model, lambda names: Selection.build(names, TRACKED_LINKS[args.model], link_map),
                        settings, options, publisher, progress=None if args.quiet else _progress, viewer=viewer,
                        retarget=retarget, links=links, on_ready=None if args.quiet else ready)
    if not args.quiet:
        print(file=sys.stderr)
    report = dict(result.report(), source_url=args.source, model=model.name)
    if not args.quiet:
        _print_report(report)
    if args.report:
        write_json(report, args.report)
    if args.out:
        _write_out(args.out, result, model, retarget)
    if not result.characters:
        raise InputError(f"no sample came from {args.source}")
    return 130 if result.interrupted else 0


def _check(args: argparse.Namespace) -> None:
    """Refuse bad options before anything listens or loads."""
    if args.rrd and Path(args.rrd).suffix != ".rrd":
        raise InputError(f"{args.rrd}: a rerun recording's name must end in .rrd")
    check_outputs([args.report, args.out, args.rrd], args.force)
    if args.backlog is not None and args.backlog < 1:
        raise InputError(f"--backlog {args.backlog}: at least 1")
    if args.characters < 1:
        raise InputError(f"--characters {args.characters}: at least 1")
    if args.rate is not None and not args.rate > 0:
        raise InputError(f"--rate {args.rate}: must be positive")
    if args.viewer not in (None, "spawn"):
        from ..pipelines.live.viewer import viewer_url

        viewer_url(args.viewer)
    if args.to_lsl:
        from ..live.lsl import pylsl

        pylsl()  # missing pylsl: said before anything starts


def _link_map(args: argparse.Namespace, model):
    if not args.map:
        return None
    from ..io.maps import load_map

    link_map = load_map(args.map)
    if args.calibration:
        from ..io import read
        from ..io.maps import calibrate

        link_map = calibrate(link_map, read(args.calibration), model)
    return link_map


def _outputs(args: argparse.Namespace, model, links, rate):
    """The LSL publisher (of iCub's joints when retargeting), the viewer and the robot, as asked."""
    from ..pipelines.live import LiveRetarget, Publisher

    retarget = None
    if args.retarget:
        retarget = LiveRetarget(args.gain, LimitSettings(max_rate=args.max_rate), args.backend, model.device)
    published = retarget.model if retarget is not None else model
    publisher = Publisher(args.to_lsl, published, args.lsl_base, args.lsl_velocity, rate) if args.to_lsl else None
    viewer = None
    if args.viewer or args.rrd:
        from ..pipelines.live.viewer import LiveViewer, ViewerSpec
        from ..pipelines.visuals import visuals

        spec = ViewerSpec(model.to(device="cpu"), tuple(links), visuals(model_urdf(args.model)),
                          spawn=args.viewer == "spawn", url=None if args.viewer in (None, "spawn") else args.viewer,
                          path=args.rrd)
        viewer = LiveViewer(spec, args.viewer_rate)
    return publisher, viewer, retarget


def _write_out(out: str, result, model, retarget) -> None:
    """Each character's trajectory (character c > 0: OUT.c.npz): the robot's, as `torchik retarget`
    writes it, when retargeting, else as `torchik track --out` writes it."""
    from ..io import save_trajectory
    from ..pipelines.live.batch import as_retargeted
    from ..pipelines.retarget import LIMIT_TOLERANCE, save

    trajectories = result.retargeted if retarget is not None else result.trajectories
    for c, trajectory in trajectories.items():
        path = Path(out) if c == 0 else Path(out).with_suffix(f".{c}.npz")
        if retarget is None:
            save_trajectory(trajectory, model, path)
            continue
        robot = as_retargeted(trajectory, retarget.model)
        if robot.limit_excess > LIMIT_TOLERANCE:  # as `torchik retarget` refuses to
            print(f"torchik live: character {c}'s {retarget.model.name} trajectory exceeds a limit by "
                  f"{robot.limit_excess:.3g}; {path} not written", file=sys.stderr)
            continue
        save(robot, path, dict(source="live"))


def _progress(counters: dict, elapsed: float) -> None:
    latency = counters["latency_ms"]
    print(f"\r{elapsed:6.0f} s  characters {counters['characters']}  samples {counters['samples']}  skipped "
          f"{counters['skipped']}  lost {counters['lost']}  late {counters['late']}  duplicates {counters['duplicates']}"
          f"  malformed {counters['malformed']}  stalls {counters['stalls']}"
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
    if "retarget" in report:
        r = report["retarget"]
        print(f"    retargeted to {r['robot']}: largest limit excess {r['limit_excess']:.1e} rad, "
              f"{r['refused_beyond_limits']} samples beyond a limit not published")

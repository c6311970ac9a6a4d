"""`torchik replay`: a recording played as a live stream (MVN over UDP or TCP, or LSL), with faults."""

from __future__ import annotations

import argparse
import math

from ..errors import InputError
from ..method.models import MODELS
from .common import add_command, add_map_arguments

EXAMPLES = """examples:
  torchik replay walk.mvnx --to udp://127.0.0.1:9763
                          play an MVNX recording as Xsens MVN streams it; in another terminal:
                          torchik live --from udp://:9763 --model human66 --map xsens_to_human --to-lsl torchik
  torchik replay walk.mvnx --to udp://127.0.0.1:9763 --characters 4 --speed 0.5
                          four characters, each a quarter of the recording ahead, at half speed
  torchik replay walk.mvnx --to udp://127.0.0.1:9763 --loss 0.05 --reorder 0.02 --duplicate 0.02 --jitter 3
                          the faults of a busy wireless network
  torchik replay walk.bvh --map cmu_to_human --to lsl://mocap
                          a BVH file, its skeleton mapped to Xsens' segments, as an LSL Mocap stream
  torchik replay walk.mvnx --to tcp://127.0.0.1:9763   MVN's TCP streaming (torchik live listens)
"""


def add_parser(subparsers) -> None:
    """Register `torchik replay`."""
    p = add_command(subparsers, "replay", "play a recording as a live stream (MVN UDP/TCP or LSL), with faults",
                    EXAMPLES)
    p.add_argument("recording", metavar="RECORDING", help="any recording torchik reads (.mvnx, .bvh, .c3d, .npz)")
    p.add_argument("--to", required=True, metavar="URL", help="udp://HOST:PORT, tcp://HOST:PORT or lsl://NAME")
    add_map_arguments(p, "Xsens' segments (the human models' links)")
    p.add_argument("--model", default="human66", choices=[m for m in MODELS if m != "icub"],
                   help="the human model a calibrating map calibrates on (default human66)")
    p.add_argument("--speed", type=float, default=1.0, help="times the recording's rate (default 1; inf: as fast as "
                   "the network takes it)")
    p.add_argument("--characters", type=int, default=1, metavar="N",
                   help="stream N characters, character c a fraction c/N of the recording ahead (default 1)")
    p.add_argument("--loss", type=float, default=0.0, metavar="P", help="lose a frame with probability P")
    p.add_argument("--reorder", type=float, default=0.0, metavar="P", help="send a frame after the next, probability P")
    p.add_argument("--duplicate", type=float, default=0.0, metavar="P", help="send a datagram twice, probability P")
    p.add_argument("--jitter", type=float, default=0.0, metavar="MS", help="delay each frame by up to MS ms")
    p.add_argument("--stall", type=float, default=0.0, metavar="S", help="pause the stream S seconds halfway")
    p.add_argument("--seed", type=int, default=0, help="of the faults' random draws (default 0)")
    p.add_argument("--max-datagram", type=int, default=1472, metavar="BYTES",
                   help="split MVN messages into datagrams of at most this (default 1472, Ethernet's UDP payload)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..io import map_recording, read
    from ..live.sample import parse_url
    from ..pipelines.replay import Faults, replay

    url = parse_url(args.to, listening=False)
    if args.characters < 1 or args.characters > 255:
        raise InputError(f"--characters {args.characters}: from 1 to 255 (MVN's character ID is a byte)")
    if args.max_datagram < 100:
        raise InputError(f"--max-datagram {args.max_datagram}: too small for a header and an item")
    faults = Faults(args.loss, args.reorder, args.duplicate, args.jitter, args.stall, args.seed)
    faults.check(url)
    recording = read(args.recording)
    if args.map:
        from ..method.models import load_model

        static = read(args.calibration) if args.calibration else None
        recording, _ = map_recording(recording, args.map, load_model(args.model), static, args.calibration_frame,
                                     args.heading_axis)
    if len(recording.time) < 2:
        raise InputError(f"{args.recording}: a stream needs at least two frames")
    if not args.quiet:
        duration = recording.duration / args.speed if math.isfinite(args.speed) else 0.0
        print(f"replaying {args.recording} ({len(recording.time)} frames at {recording.frame_rate:.4g} Hz) to {url} "
              f"as {args.characters} character(s), {duration:.1f} s; Ctrl-C stops")
    log = replay(recording, url, args.speed, args.characters, faults, args.max_datagram)
    if not args.quiet:
        print(f"sent {log.frames} frames, {log.datagrams} datagrams; lost {log.lost}, reordered {log.reordered}, "
              f"duplicated {log.duplicated}, stalled {log.stalled_s:g} s")
    return 0

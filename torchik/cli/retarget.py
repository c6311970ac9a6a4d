"""`torchik retarget`: a human recording to iCub joint trajectories within every limit."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from ..errors import InputError
from ..method.limits import LimitSettings
from ..method.settings import TrackerSettings
from ..pipelines.retarget import LIMIT_TOLERANCE, retarget, save
from .common import add_map_arguments, add_subject_argument, positive, subject_from


def run(args: argparse.Namespace) -> int:
    from ..io import map_recording, read
    from ..io.maps import default_map
    from ..method.models import load_model

    out = Path(args.out)
    if out.suffix != ".npz":
        raise InputError(f"{out}: the output must be a .npz file")
    if out.exists() and not args.force:
        raise InputError(f"{out} exists; add --force to overwrite it")
    if not Path(args.recording).is_file():
        raise InputError(f"{args.recording}: no such file")
    recording = read(args.recording)
    human = load_model("human66", subject_from(args.subject_from, args.map, say=(lambda _: None) if args.quiet else print))
    map_name = args.map or default_map(recording.links, human)
    if map_name:
        static = read(args.calibration) if args.calibration else None
        recording, _ = map_recording(recording, map_name, human, static, args.calibration_frame,
                                     args.heading_axis)
    elif args.calibration:
        raise InputError("--calibration calibrates a --map; give the map too")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one subject's problems are too small for threads to pay
    try:
        result, report = retarget(recording, args.rate, args.gain, progress=False if args.quiet else None,
                                  limits=LimitSettings(max_rate=args.max_rate))
    finally:
        torch.set_num_threads(threads)
    if result.limit_excess > LIMIT_TOLERANCE:
        print(f"torchik retarget: the iCub trajectory exceeds a limit by {result.limit_excess:.3g}; nothing written",
              file=sys.stderr)
        return 1
    save(result, out, dict(source=args.recording))
    if not args.quiet:
        m = report["mnte"]
        print(f"retargeted {args.recording} to iCub: {report['frames']} frames at {args.rate:g} Hz "
              f"({report['duration_s']:.1f} s)")
        if m:
            print(f"    MNTE of iCub's links against the mapped human ones: median {m['median']:.2e}, p99 {m['p99']:.2e}")
        print(f"    within every joint and coupled limit at every frame (largest excess {max(result.limit_excess, 0.0):.1e} "
              f"rad); largest joint rate {report['max_joint_rate']:.2f} rad/s; QP fallbacks {report['qp_fallbacks']}")
        print(f"wrote {out}")
    return 0


EXAMPLES = """examples:
  torchik retarget walk.npz --to icub --out icub.npz      a recording in the human models' links
  torchik retarget ../shared/data/mvnx/test_mocap.mvnx --to icub --out icub.npz
  torchik retarget walk.bvh --map bandai_to_human --to icub --out icub.npz --rate 200
  python -c "import numpy as np; d = np.load('icub.npz'); print(d['joint_names'], d['joint_positions'].shape)"
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `torchik retarget`."""
    parser = subparsers.add_parser(
        "retarget", help="retarget a human recording to iCub joint trajectories within every limit",
        description="Track a human recording with the iCub model (through the human-to-iCub link map) and write "
                    "iCub joint trajectories (names, angles, rates, time) within every joint limit and the coupled "
                    "shoulder limits, at a rate a position controller can stream (50 Hz or more).",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", help="a recording (.npz, .mvnx, .bvh, .c3d) in the human models' links, or "
                                          "any skeleton with --map")
    parser.add_argument("--to", required=True, choices=("icub",), help="the robot: icub")
    parser.add_argument("--out", required=True, metavar="NPZ", help="the iCub trajectories to write (.npz)")
    add_map_arguments(parser, "the human models' links")
    add_subject_argument(parser)
    parser.add_argument("--rate", type=positive, default=100.0,
                        help="output rate in Hz, 50 or more (default 100); the recording is resampled to it")
    parser.add_argument("--gain", type=positive, default=TrackerSettings.position_gain,
                        help=f"K of the tracker, 1/s (default {TrackerSettings.position_gain:g})")
    parser.add_argument("--max-rate", type=positive, default=LimitSettings().max_rate,
                        help=f"the largest joint rate, rad/s (default {LimitSettings().max_rate:g}): set it to the "
                             f"robot's own")
    parser.add_argument("--force", action="store_true", help="overwrite the output if it exists")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.set_defaults(run=run)
    return parser

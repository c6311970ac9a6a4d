"""`torchik info` and `torchik convert`: what a recording holds, and any source file as a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import add_command, check_outputs
from .track import EXAMPLES


def add_parser(subparsers) -> None:
    """Register `torchik info` and `torchik convert`."""
    info = add_command(subparsers, "info", "print a recording's segments, rate, duration and gaps", EXAMPLES)
    info.add_argument("file", help="a recording (.npz) or a source file (.mvnx, .bvh, .c3d, OpenSense .sto)")
    info.set_defaults(run=run_info)

    convert = add_command(subparsers, "convert", "convert a source file to a torchik recording (.npz)", EXAMPLES)
    convert.add_argument("input", help="a source file (.mvnx, .bvh, .c3d, OpenSense .sto) or a recording (.npz)")
    convert.add_argument("output", help="the recording to write (.npz)")
    convert.add_argument("--force", action="store_true", help="overwrite the output if it exists")
    convert.set_defaults(run=run_convert)


def run_info(args: argparse.Namespace) -> int:
    from ..io import read
    from ..io.base_position import NOT_MEASURED

    rec = read(args.file)
    print(f"{args.file}: {len(rec.time)} frames, {rec.frame_rate:.2f} Hz, {rec.duration:.3f} s, "
          f"{len(rec.links)} segments, base {rec.base_link}")
    print(f"    segments: {', '.join(rec.links)}")
    gaps = rec.gaps()
    print(f"    gaps (frames missing per segment): {gaps if gaps else 'none'}")
    if rec.joint_names:
        print(f"    ground truth: {len(rec.joint_names)} joint positions")
    if rec.meta.get("base_position") == NOT_MEASURED:
        print("    base position: not measured (orientations only: track holds the base or leaves it free, "
              "--base-position)")
    if rec.meta.get("angular_velocity") == "derived":
        print("    angular velocity: derived from the orientations (no gyroscope)")
    if rec.meta.get("calibration"):
        print(f"    calibration frames: {', '.join(rec.meta['calibration'])}")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from ..io import RecordingError, read, save_recording

    out = Path(args.output)
    if out.suffix != ".npz":
        raise RecordingError(f"{out}: the output must be a .npz recording")
    check_outputs([out], args.force)
    rec = read(args.input)
    save_recording(rec, out)
    print(f"wrote {out}: {len(rec.time)} frames, {len(rec.links)} segments")
    return 0

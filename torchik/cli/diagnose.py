"""`torchik diagnose RECORDING --model M --report DIR`: the loop on one recording, written out.

    torchik diagnose walk.mvnx --model human48 --report diag/
    torchik diagnose walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48 --report diag/

writes DIR/report.md (with errors.png, residual.png), DIR/calibration.json, DIR/model.urdf where a
model effect was added, DIR/residuals.rrd and DIR/diagnosis.json (report.py), and prints the command
that tracks the recording again with what was found.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..errors import InputError
from ..method.settings import TrackerSettings
from .common import add_map_arguments, add_subject_argument, positive, subject_from

EXAMPLES = """examples:
  torchik diagnose walk.npz --model human48 --report diag/
  torchik diagnose ../shared/data/mvnx/test_mocap.mvnx --model human48 --report mvn/
  torchik diagnose walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48 --report diag/
  torchik diagnose walk.bvh --map cmu_to_human --model human48 --report diag/ --kinds misalignment,missing_dof
then track again with what was found:
  torchik track --input walk.npz --model human48 --sensor-calibration diag/calibration.json --urdf diag/model.urdf
"""

OUTPUTS = ("report.md", "calibration.json", "model.urdf", "residuals.rrd", "diagnosis.json", "errors.png",
           "residual.png")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `torchik diagnose`."""
    from ..pipelines.diagnosis.loop import KINDS

    parser = subparsers.add_parser(
        "diagnose", help="find what a recording carries that the model lacks, add it, report before and after",
        description="Track a recording, analyse the residual, fit every candidate effect (sensor misalignment, "
                    "gyro bias and scale, stream and sensor delays, heading drift, a missing joint axis, joint "
                    "limits narrower than the motion, a position target's offset), add the most significant on "
                    "held-out time, track again, and repeat until nothing more is significant.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", help="a recording (.npz, .mvnx, .bvh, .c3d) in the model's links, or any "
                                          "skeleton with --map")
    parser.add_argument("--model", default="human48", choices=("human66", "human48"),
                        help="the model (default human48); its links name the targets")
    parser.add_argument("--urdf", metavar="FILE", help="start from this URDF of the model instead (e.g. a model.urdf "
                                                       "an earlier diagnosis wrote)")
    parser.add_argument("--report", required=True, metavar="DIR", help="the folder to write the report into")
    add_map_arguments(parser, "the model's links")
    add_subject_argument(parser)
    parser.add_argument("--gain", type=positive, default=TrackerSettings.position_gain,
                        help=f"K of the tracker, 1/s (default {TrackerSettings.position_gain:g})")
    parser.add_argument("--max-effects", type=int, default=8, help="stop after adding this many effects (default 8)")
    parser.add_argument("--kinds", type=_kinds, default=KINDS, metavar="K1,K2",
                        help=f"the candidate effects, comma-separated (default all: {','.join(KINDS)})")
    parser.add_argument("--no-rrd", action="store_true", help="do not write residuals.rrd")
    parser.add_argument("--force", action="store_true", help="write into a report folder that already holds a report")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.set_defaults(run=run)
    return parser


def _kinds(text: str) -> tuple[str, ...]:
    from ..pipelines.diagnosis.loop import KINDS

    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise argparse.ArgumentTypeError(f"unknown effects {unknown}; valid: {', '.join(KINDS)}")
    return kinds


def run(args: argparse.Namespace) -> int:
    import torch

    from ..io import read
    from ..io.base_position import measures_base_position, standing_base_position, unmeasured_base
    from ..method.kinematics import KinematicModel
    from ..method.models import TRACKED_LINKS, human_urdf
    from ..pipelines.diagnosis.loop import diagnose
    from ..pipelines.diagnosis.report import write

    out = Path(args.report)
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not args.force:
        raise InputError(f"{out} already holds {', '.join(existing)}; add --force to overwrite")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is a file; --report names a folder")
    if not Path(args.recording).is_file():
        raise InputError(f"{args.recording}: no such file")
    if args.calibration and not args.map:
        raise InputError("--calibration calibrates a --map; give the map too")
    if args.urdf and not Path(args.urdf).is_file():
        raise InputError(f"{args.urdf}: no such URDF file")
    if args.urdf and args.subject_from:
        raise InputError("--urdf and --subject-from both give the model; give one")
    subject = subject_from(args.subject_from, args.map, say=(lambda _: None) if args.quiet else print)
    urdf = Path(args.urdf).read_text() if args.urdf else human_urdf(int(args.model[-2:]), subject)
    model = KinematicModel.from_urdf(urdf, name=f"Human{args.model[-2:]}" + ("+" if args.urdf else ""))
    recording = read(args.recording)
    from ..io.maps import default_map

    map_name = args.map or default_map(recording.links, model)
    if map_name:
        from ..io import map_recording

        static = read(args.calibration) if args.calibration else None
        recording, _ = map_recording(recording, map_name, model, static, args.calibration_frame, args.heading_axis)
    if not measures_base_position(recording):  # an IMU set's: the base held where the model stands
        recording, note = unmeasured_base(recording, "held", standing_base_position(model))
        if not args.quiet:
            print(f"base position {note}")
    links = [name for name in TRACKED_LINKS[args.model] if name in recording.links]
    if model.base_link not in links:
        raise InputError(f"{args.recording}: no {model.base_link} among its segments {list(recording.links)}; "
                         f"give --map to name them as the model's links")
    say = (lambda _: None) if args.quiet else print
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one subject's problems are too small for threads to pay
    start = time.perf_counter()
    try:
        diagnosis, = diagnose(model, urdf, [recording], links, gain=args.gain, max_effects=args.max_effects,
                              kinds=args.kinds, log=lambda line: say("    " + line))
    finally:
        torch.set_num_threads(threads)
    paths = write(diagnosis, out, args.recording, model.name or Path(model.source).stem, rrd=not args.no_rrd)
    if not args.quiet:
        before, after = diagnosis.before.overall, diagnosis.after.overall
        print(f"diagnosed {args.recording} with {model.name} ({len(links)} links) in {time.perf_counter() - start:.0f} s: "
              f"{len(diagnosis.effects) or 'no'} effect{'s' if len(diagnosis.effects) != 1 else ''} found")
        for k, effect in enumerate(diagnosis.effects, 1):
            print(f"    {k}. {effect.summary()}")
        print(f"    MNTE {before['mnte']:.3g} -> {after['mnte']:.3g}; angular velocity RMSE {before['rmse']:.3g} -> "
              f"{after['rmse']:.3g} rad/s")
        print(f"wrote {', '.join(str(p) for p in paths.values())}")
        again = [f"torchik track --input {args.recording}", f"--model {args.model}"]
        again += [f"--map {args.map}"] if args.map else []
        again += [f"--calibration {args.calibration}"] if args.calibration else []
        again += [f"--calibration-frame {args.calibration_frame}"] if args.calibration_frame is not None else []
        again += [f"--heading-axis {args.heading_axis}"] if args.heading_axis else []
        again += [f"--sensor-calibration {paths['calibration']}"]
        again += [f"--urdf {paths['urdf']}"] if "urdf" in paths else []
        print("track again with what was found: " + " ".join(again))
    return 0

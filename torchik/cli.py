"""The `torchik` command line. Exit codes: 0 ok, 2 bad input, 1 failure."""

from __future__ import annotations

import argparse
import sys

from .errors import TorchikError

EXAMPLES = """examples:
  torchik track --scenario walking --model human66 --report walk.json
                                          track the built-in walking scenario and report the errors
  torchik track --input walk.npz --model human66 --out estimate.npz
  torchik track --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48
  torchik models                          list the models with their DoF, links and limits
  torchik info walk.mvnx                  segments, rate, duration and gaps of a recording
  torchik convert walk.mvnx walk.npz      convert to torchik's recording format
  torchik models --links human48          also list each model's links and joint limits
  torchik models --write models/          write human66.urdf and human48.urdf (subject 1)
  torchik models --write out/ --height 1.85 --mass 80 --segment RightUpperArm=0.31
"""


def _models(args: argparse.Namespace) -> int:
    from .models import MODELS, TRACKED_LINKS, HumanSubject, load_model, write_human_models

    subject = HumanSubject(height=args.height, mass=args.mass, segment_lengths=dict(args.segment or []))
    if args.write:
        for path in write_human_models(args.write, subject):
            print(f"wrote {path}")
        return 0
    names = MODELS if not args.links else [args.links]
    for name in names:
        model = load_model(name, None if name == "icub" else subject)
        print(model.summary())
        print(f"    tracked links ({len(TRACKED_LINKS[name])}): {', '.join(TRACKED_LINKS[name])}")
        if args.links:
            for joint, lo, hi in zip(model.joint_names, model.lower.tolist(), model.upper.tolist()):
                print(f"    {joint:28s} [{lo:+.4f}, {hi:+.4f}] rad")
            if model.linear_limits is not None:
                for row in model.linear_limits.names:
                    print(f"    coupled: {row}")
    return 0


def read_any(path: str):
    """A Recording from any supported file, by its suffix."""
    from pathlib import Path

    from .io import RecordingError, load_recording, read_bvh, read_c3d, read_mvnx

    readers = {".npz": load_recording, ".mvnx": read_mvnx, ".bvh": read_bvh, ".c3d": read_c3d}
    suffix = Path(path).suffix.lower()
    if suffix not in readers:
        raise RecordingError(f"{path}: unsupported format {suffix!r}; supported: {', '.join(readers)}")
    return readers[suffix](path)


def _info(args: argparse.Namespace) -> int:
    rec = read_any(args.file)
    print(f"{args.file}: {len(rec.time)} frames, {rec.frame_rate:.2f} Hz, {rec.duration:.3f} s, "
          f"{len(rec.links)} segments, base {rec.base_link}")
    print(f"    segments: {', '.join(rec.links)}")
    gaps = rec.gaps()
    print(f"    gaps (frames missing per segment): {gaps if gaps else 'none'}")
    if rec.joint_names:
        print(f"    ground truth: {len(rec.joint_names)} joint positions")
    if rec.meta.get("calibration"):
        print(f"    calibration frames: {', '.join(rec.meta['calibration'])}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .io import RecordingError, save_recording

    out = Path(args.output)
    if out.suffix != ".npz":
        raise RecordingError(f"{out}: the output must be a .npz recording")
    if out.exists() and not args.force:
        raise RecordingError(f"{out} exists; add --force to overwrite it")
    rec = read_any(args.input)
    save_recording(rec, out)
    print(f"wrote {out}: {len(rec.time)} frames, {len(rec.links)} segments")
    return 0


def _track(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from .errors import InputError
    from .models import TRACKED_LINKS, load_model
    from .scenarios import SCENARIOS, scenario
    from .track import save_trajectory, track_recording, write_report

    outputs = [Path(p) for p in (args.report, args.out) if p]
    for path in outputs:
        if path.exists() and not args.force:
            raise InputError(f"{path} exists; add --force to overwrite it")
    model = load_model(args.model)
    links = TRACKED_LINKS[args.model]
    if args.input:
        recording = read_any(args.input)
        source = args.input
        if args.map:
            from .io import apply_map, calibrate, load_map

            link_map = load_map(args.map)
            if args.calibration:
                link_map = calibrate(link_map, read_any(args.calibration), model, args.calibration_frame)
            recording = apply_map(recording, link_map, model, args.calibration_frame)
            links = recording.links
            source += f" through map {link_map.name!r}"
    elif args.map or args.calibration:
        raise InputError("--map and --calibration apply to --input recordings; the scenarios are in the model's links")
    else:
        if args.scenario not in SCENARIOS:
            raise InputError(f"unknown scenario {args.scenario!r}; valid: {', '.join(SCENARIOS)}")
        recording = scenario(args.scenario, model, links, duration=args.duration, rate=args.rate, seed=args.seed)
        source = f"scenario {args.scenario} ({args.duration} s at {args.rate} Hz)"
    start = time.perf_counter()
    trajectory, report = track_recording(model, recording, links, args.gain, args.gain, args.scheme, args.backend,
                                         progress=False if args.quiet else None)
    report.update(source=source, wall_time_s=time.perf_counter() - start)
    if not args.quiet:
        m, r, st = report["mnte"], report["angular_velocity_rmse"], report["step_time_ms"]
        print(f"tracked {source} with {model.name}: {report['frames']} frames in {report['wall_time_s']:.1f} s")
        if m:
            print(f"    MNTE after {report['transient_s']:.0f} s: median {m['median']:.2e}, p99 {m['p99']:.2e}")
            print(f"    angular velocity RMSE: median {r['median']:.2e} rad/s, p99 {r['p99']:.2e} rad/s")
        if "joint_error_rad" in report:
            print(f"    joint error against ground truth: max {report['joint_error_rad']['max']:.2e} rad")
        print(f"    step time: median {st['median']:.2f} ms, p99 {st['p99']:.2f} ms; "
              f"QP fallbacks {report['qp_fallbacks']}, dropped targets {report['dropped_targets']}")
    if args.report:
        write_report(report, args.report)
        if not args.quiet:
            print(f"wrote {args.report}")
    if args.out:
        save_trajectory(trajectory, model, args.out)
        if not args.quiet:
            print(f"wrote {args.out}")
    return 0


def _frame(text: str) -> int | str:
    if text == "rest":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame index or 'rest', got {text!r}") from None


def _segment(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SEGMENT=METRES, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="torchik",
        description="Real-time motion tracking of people and humanoids by dynamical inverse kinematics.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    track = sub.add_parser("track", help="track a recording or a built-in scenario and report the errors",
                           epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    source = track.add_mutually_exclusive_group()
    source.add_argument("--scenario", default="walking", help="built-in scenario: tpose, walking, running (default walking)")
    source.add_argument("--input", metavar="FILE", help="a recording (.npz) or source file whose segments are the model's links")
    track.add_argument("--map", help="link map from the input's segments to the model's links: a built-in name "
                       "(xsens_to_human, plugin_gait_to_human, human_to_icub) or a .toml file")
    track.add_argument("--calibration", metavar="FILE", help="a static trial to calibrate the map's offsets on")
    track.add_argument("--calibration-frame", type=_frame, default=None,
                       help="the frame holding the reference pose: an index, or 'rest' for a BVH rest pose "
                            "(default: the map's own choice, else 0)")
    track.add_argument("--model", default="human66", choices=("human66", "human48", "icub"))
    track.add_argument("--duration", type=float, default=10.0, help="scenario length in seconds (default 10)")
    track.add_argument("--rate", type=float, default=100.0, help="scenario rate in Hz (default 100)")
    track.add_argument("--seed", type=int, default=0)
    track.add_argument("--gain", type=float, default=20.0, help="K for positions and orientations, 1/s (default 20)")
    track.add_argument("--scheme", default="midpoint", choices=("midpoint", "paper"))
    track.add_argument("--backend", default="piqp", choices=("piqp",))
    track.add_argument("--report", metavar="JSON", help="write the metrics here")
    track.add_argument("--out", metavar="NPZ", help="write the estimated trajectory here")
    track.add_argument("--force", action="store_true", help="overwrite existing outputs")
    track.add_argument("--quiet", action="store_true", help="print nothing but errors")
    track.set_defaults(run=_track)

    models = sub.add_parser("models", help="list the built-in models, or write the human URDFs",
                            epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    models.add_argument("--links", metavar="MODEL", choices=("human66", "human48", "icub"),
                        help="show one model's joints and limits")
    models.add_argument("--write", metavar="DIR", help="write human66.urdf and human48.urdf into DIR")
    models.add_argument("--height", type=float, default=1.68, help="subject height in metres (default 1.68)")
    models.add_argument("--mass", type=float, default=62.2, help="subject mass in kg (default 62.2)")
    models.add_argument("--segment", type=_segment, action="append", metavar="NAME=METRES",
                        help="a measured segment length, e.g. RightUpperArm=0.31 (repeatable)")
    models.set_defaults(run=_models)

    info = sub.add_parser("info", help="print a recording's segments, rate, duration and gaps",
                          epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    info.add_argument("file", help="a recording (.npz) or a source file (.mvnx, .bvh, .c3d)")
    info.set_defaults(run=_info)

    convert = sub.add_parser("convert", help="convert a source file to a torchik recording (.npz)",
                             epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    convert.add_argument("input", help="a source file (.mvnx, .bvh, .c3d) or a recording (.npz)")
    convert.add_argument("output", help="the recording to write (.npz)")
    convert.add_argument("--force", action="store_true", help="overwrite the output if it exists")
    convert.set_defaults(run=_convert)
    return parser


def main(argv: list[str] | None = None) -> int:
    from .memory import keep_freed_memory

    parser = build_parser()
    args = parser.parse_args(argv)
    keep_freed_memory()
    try:
        return args.run(args)
    except TorchikError as exc:
        print(f"torchik {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader (head, less) closed the pipe: not an error of ours
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())

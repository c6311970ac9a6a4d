"""The `torchik` command line.

Exit codes: 0 ok; 2 bad input (one line on stderr saying what is wrong and what would be right);
1 failure; 130 interrupted by Ctrl-C (`track` has then written its outputs for the frames done).
"""

from __future__ import annotations

import argparse
import sys

from .errors import TorchikError

EXAMPLES = """examples:
  torchik track --scenario walking --model human66 --rrd walk.rrd --report walk.json
                                          track the built-in walking scenario, write a rerun recording
                                          (open it with: rerun walk.rrd) and report the errors
  torchik track --input walk.npz --model human66 --out estimate.npz
  torchik track --scenario running --duration 60 --gain 30 --backend batched --device cuda --quiet --rrd run.rrd
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
        from pathlib import Path

        from .errors import InputError

        existing = [str(p) for p in (Path(args.write) / "human66.urdf", Path(args.write) / "human48.urdf") if p.exists()]
        if existing and not args.force:  # the folder itself is made when missing
            raise InputError(f"{' and '.join(existing)} {'exists' if len(existing) == 1 else 'exist'}; "
                             f"add --force to overwrite")
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
    _check_outputs([out], args.force)
    rec = read_any(args.input)
    save_recording(rec, out)
    print(f"wrote {out}: {len(rec.time)} frames, {len(rec.links)} segments")
    return 0


def _track(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    import torch

    from .errors import InputError
    from .models import TRACKED_LINKS, load_model
    from .scenarios import SCENARIOS, recording_targets, scenario
    from .track import save_trajectory, track_recording, write_report

    if args.rrd and Path(args.rrd).suffix != ".rrd":
        raise InputError(f"{args.rrd}: a rerun recording's name must end in .rrd (e.g. walk.rrd)")
    _check_outputs([args.report, args.out, args.rrd], args.force)
    if not args.input and args.scenario not in SCENARIOS:
        raise InputError(f"unknown scenario {args.scenario!r}; valid: {', '.join(SCENARIOS)}")
    try:
        device = torch.device(args.device)
    except RuntimeError:
        raise InputError(f"--device {args.device!r}: expected cpu, cuda or cuda:N") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch here; use --device cpu")
    if device.type == "cpu":
        # one subject's tensors are too small for torch to split, and on a busy machine its idle
        # threads spin and wait for each other: a step then takes several times longer
        torch.set_num_threads(1)
    if args.urdf:  # e.g. the augmented model a diagnosis wrote
        from .diagnosis.calibration import load_urdf_model

        model = load_urdf_model(args.urdf, args.model, device)
    else:
        model = load_model(args.model, device=device)
    links = TRACKED_LINKS[args.model]
    if args.input:
        recording = read_any(args.input)
        source = args.input
        if args.map:
            from .io import map_recording

            static = read_any(args.calibration) if args.calibration else None
            recording, link_map = map_recording(recording, args.map, model, static, args.calibration_frame)
            links = recording.links
            source += f" through map {link_map.name!r}"
    elif args.map or args.calibration:
        raise InputError("--map and --calibration apply to --input recordings; the scenarios are in the model's links")
    else:
        recording = scenario(args.scenario, model.to(device="cpu"), links, duration=args.duration, rate=args.rate,
                             seed=args.seed)
        source = f"scenario {args.scenario} ({args.duration:g} s at {args.rate:g} Hz)"
    if args.sensor_calibration:  # the sensor effects a diagnosis found, undone
        from .diagnosis.calibration import apply_calibration_file

        recording = apply_calibration_file(recording, args.sensor_calibration)
        source += f" with sensor calibration {args.sensor_calibration}"
    position_gain = args.gain if args.position_gain is None else args.position_gain
    orientation_gain = args.gain if args.orientation_gain is None else args.orientation_gain
    start = time.perf_counter()
    trajectory, report = track_recording(model, recording, links, position_gain, orientation_gain, args.scheme,
                                         args.backend, progress=not args.quiet)
    report.update(source=source, device=str(device), wall_time_s=time.perf_counter() - start)
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
    if args.rrd:
        from .rrd import log_trajectory

        start = time.perf_counter()
        targets = recording_targets(recording, links, dtype=model.dtype, device=model.device)
        log_trajectory(args.rrd, model, links, trajectory, targets, urdf=args.urdf or _model_urdf(args.model),
                       progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {args.rrd} in {time.perf_counter() - start:.1f} s; open it with: rerun {args.rrd}")
    if report["interrupted"]:
        print(f"torchik track: interrupted; the outputs hold the {report['frames']} frames tracked", file=sys.stderr)
        return 130
    return 0


def _model_urdf(name: str):
    """A built-in model's URDF (text or path): what draws its body in a rerun recording."""
    from .models import human_urdf, icub_urdf_path

    return icub_urdf_path() if name == "icub" else human_urdf(int(name[-2:]))


def _check_outputs(paths, force: bool) -> None:
    """Refuse, before any work, outputs that exist (without --force) or whose folder does not."""
    from pathlib import Path

    from .errors import InputError

    for path in (Path(p) for p in paths if p):
        if path.exists() and not force:
            raise InputError(f"{path} exists; add --force to overwrite it")
        if not path.parent.is_dir():
            raise InputError(f"{path}: no folder {path.parent} to write into; create it first")


def frame_argument(text: str) -> int | str:
    """argparse type of --calibration-frame: a frame index, or 'rest' (a BVH's rest pose)."""
    if text == "rest":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame index or 'rest', got {text!r}") from None


def add_map_arguments(parser: argparse.ArgumentParser, target: str = "the model's links") -> None:
    """--map, --calibration and --calibration-frame: how a recording's segments become `target`."""
    parser.add_argument("--map", help=f"link map from the recording's segments to {target}: a built-in name "
                                      "(xsens_to_human, plugin_gait_to_human, bandai_to_human, cmu_to_human, "
                                      "human_to_icub) or a .toml file")
    parser.add_argument("--calibration", metavar="FILE", help="a static trial to calibrate the map's offsets on")
    parser.add_argument("--calibration-frame", type=frame_argument, default=None,
                        help="the frame holding the reference pose: an index, or 'rest' for a BVH rest pose "
                             "(default: the map's own choice, else 0)")


def _segment(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SEGMENT=METRES, got {text!r}") from None


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: what is wrong and where the usage is, no usage dump."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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
    add_map_arguments(track)
    track.add_argument("--model", default="human66", choices=("human66", "human48", "icub"))
    track.add_argument("--urdf", metavar="FILE", help="track with this URDF of --model instead, e.g. the model.urdf "
                       "`torchik diagnose` writes (--model still names the tracked links)")
    track.add_argument("--sensor-calibration", metavar="JSON", help="undo the sensor effects (offsets, biases, delays, "
                       "drift) in the calibration.json `torchik diagnose` wrote for this session, after --map")
    track.add_argument("--duration", type=float, default=10.0, help="scenario length in seconds (default 10)")
    track.add_argument("--rate", type=float, default=100.0, help="scenario rate in Hz (default 100)")
    track.add_argument("--seed", type=int, default=0)
    track.add_argument("--gain", type=float, default=20.0, help="K for positions and orientations, 1/s (default 20)")
    track.add_argument("--position-gain", type=float, metavar="K", help="K of the position target, 1/s (default --gain)")
    track.add_argument("--orientation-gain", type=float, metavar="K",
                       help="K of the orientation targets, 1/s (default --gain)")
    track.add_argument("--scheme", default="midpoint", choices=("midpoint", "paper"))
    track.add_argument("--backend", default="auto", choices=("auto", "piqp", "batched"),
                       help="QP solver: PIQP per subject, batched in torch, or auto (batched for batches, default)")
    track.add_argument("--device", default="cpu", help="torch device: cpu (default), cuda or cuda:N")
    track.add_argument("--report", metavar="JSON", help="write the metrics here")
    track.add_argument("--out", metavar="NPZ", help="write the estimated trajectory here")
    track.add_argument("--rrd", metavar="FILE", help="write a rerun recording here (.rrd): the body, targets and "
                       "diagnostics over time; open it with `rerun FILE`")
    track.add_argument("--force", action="store_true", help="overwrite existing outputs")
    track.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bars)")
    track.set_defaults(run=_track)

    models = sub.add_parser("models", help="list the built-in models, or write the human URDFs",
                            epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    models.add_argument("--links", metavar="MODEL", choices=("human66", "human48", "icub"),
                        help="show one model's joints and limits")
    models.add_argument("--write", metavar="DIR", help="write human66.urdf and human48.urdf into DIR")
    models.add_argument("--force", action="store_true", help="overwrite the URDFs in DIR if they exist")
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

    # sub-commands defined next to what they run: each module's add_parser(sub) registers its own
    from . import bench, cohort, experiment, retarget
    from .diagnosis import command as diagnose

    for module in (bench, experiment, retarget, cohort, diagnose):
        module.add_parser(sub)
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
        print(f"torchik {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader (head, less) closed the pipe: not an error of ours
        sys.stderr.close()
        return 0
    except OSError as exc:  # a file that cannot be read or written: the system's reason, in one line
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"torchik {args.command}: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

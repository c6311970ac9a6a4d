"""`torchik models`: the built-in models, or the human URDFs written for a subject."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError, MissingDependencyError
from ..method.models import MODELS
from .common import add_command, positive
from .track import EXAMPLES


def _segment(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SEGMENT=METRES, got {text!r}") from None


def add_parser(subparsers) -> None:
    """Register `torchik models`."""
    models = add_command(subparsers, "models", "list the built-in models, or write the human URDFs", EXAMPLES)
    models.add_argument("--links", metavar="MODEL", choices=MODELS,
                        help="show one model's joints and limits")
    models.add_argument("--write", metavar="DIR", help="write human66.urdf and human48.urdf into DIR")
    models.add_argument("--force", action="store_true", help="overwrite the URDFs in DIR if they exist")
    models.add_argument("--height", type=positive, help="subject height in metres (default 1.68, or the recording's)")
    models.add_argument("--mass", type=positive, help="subject mass in kg (default 62.2, or the recording's)")
    models.add_argument("--segment", type=_segment, action="append", metavar="NAME=METRES",
                        help="a measured segment length, e.g. RightUpperArm=0.31 (repeatable)")
    models.add_argument("--from", dest="recording", metavar="RECORDING",
                        help="build the subject from a recording: MVNX joint points, BVH bone offsets through the "
                             "link map, a C3D static trial's Plug-in Gait lengths (with --write; --height and --mass "
                             "given override the file's)")
    models.add_argument("--model", choices=("human66", "human48"), help="with --write: write only this model")
    models.add_argument("--map", help="with --from: the link map of a BVH or C3D recording (default: auto)")
    models.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..method.models import MODELS, TRACKED_LINKS, HumanSubject, load_model, write_human_models

    if args.recording:
        if not args.write:
            raise InputError("--from builds a subject's model: give --write DIR to write it")
        if args.segment:
            raise InputError("--segment and --from both set segment lengths; give one")
        subject = _subject_from_recording(args)
    else:
        subject = HumanSubject(height=1.68 if args.height is None else args.height,
                               mass=62.2 if args.mass is None else args.mass, segment_lengths=dict(args.segment or []))
    if args.write:
        chosen = [args.model] if args.model else ["human66", "human48"]
        existing = [str(p) for p in (Path(args.write) / f"{name}.urdf" for name in chosen) if p.exists()]
        if existing and not args.force:  # the folder itself is made when missing
            raise InputError(f"{' and '.join(existing)} {'exists' if len(existing) == 1 else 'exist'}; "
                             f"add --force to overwrite")
        for path in write_human_models(args.write, subject, [int(name[-2:]) for name in chosen]):
            print(f"wrote {path}")
        return 0
    names = MODELS if not args.links else [args.links]
    for name in names:
        try:
            model = load_model(name, None if name == "icub" else subject)
        except MissingDependencyError as exc:
            if args.links:
                raise
            print(f"{name}: not available here: {exc}")
            continue
        print(model.summary())
        print(f"    tracked links ({len(TRACKED_LINKS[name])}): {', '.join(TRACKED_LINKS[name])}")
        if args.links:
            for joint, lo, hi in zip(model.joint_names, model.lower.tolist(), model.upper.tolist()):
                print(f"    {joint:28s} [{lo:+.4f}, {hi:+.4f}] rad")
            if model.linear_limits is not None:
                for row in model.linear_limits.names:
                    print(f"    coupled: {row}")
    return 0


def _subject_from_recording(args: argparse.Namespace):
    """The subject a recording measures, its report printed and written as DIR/subject.json."""
    from ..io import read, write_json
    from ..io.subjects import subject_from_recording
    from ..method.models import SEGMENTS

    built = subject_from_recording(read(args.recording), args.height, args.mass,
                                   None if args.map in (None, "auto") else args.map)
    report = built.report()
    print(f"subject from {built.source}" + (f" through map {built.link_map!r}" if built.link_map else ""))
    print(f"    height {built.subject.height:.3f} m ({built.height_from}); mass {built.subject.mass:.1f} kg "
          f"({built.mass_from})")
    print(f"    from the file: {', '.join(f'{k} {v:.4f} m' for k, v in built.from_file.items()) or 'no segment length'}")
    if built.subject.joint_origins:
        print(f"    joint placements from the file: {len(built.subject.joint_origins)} of {len(SEGMENTS) - 1}")
    print(f"    scaled from the height: {', '.join(built.scaled) or 'none'}")
    if built.rejected:
        print(f"    not used (outside 0.005..1.5 m): {', '.join(f'{k} {v:.4f} m' for k, v in built.rejected.items())}")
    Path(args.write).mkdir(parents=True, exist_ok=True)
    print(f"wrote {write_json(report, Path(args.write) / 'subject.json')}")
    return built.subject

"""`torchik models`: the built-in models, or the human URDFs written for a subject."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError, MissingDependencyError
from ..method.models import MODELS
from .common import add_command
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
    models.add_argument("--height", type=float, default=1.68, help="subject height in metres (default 1.68)")
    models.add_argument("--mass", type=float, default=62.2, help="subject mass in kg (default 62.2)")
    models.add_argument("--segment", type=_segment, action="append", metavar="NAME=METRES",
                        help="a measured segment length, e.g. RightUpperArm=0.31 (repeatable)")
    models.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..method.models import MODELS, TRACKED_LINKS, HumanSubject, load_model, write_human_models

    subject = HumanSubject(height=args.height, mass=args.mass, segment_lengths=dict(args.segment or []))
    if args.write:
        existing = [str(p) for p in (Path(args.write) / "human66.urdf", Path(args.write) / "human48.urdf") if p.exists()]
        if existing and not args.force:  # the folder itself is made when missing
            raise InputError(f"{' and '.join(existing)} {'exists' if len(existing) == 1 else 'exist'}; "
                             f"add --force to overwrite")
        for path in write_human_models(args.write, subject):
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

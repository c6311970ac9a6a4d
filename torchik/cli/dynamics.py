"""`torchik dynamics`: a recording with force plates tracked, its ground reactions on the model's
feet, and the forces of the motion: joint torques and powers, the base's residual, a report.

    torchik dynamics --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human66 --report dyn/

writes into DIR what `pipelines/dynamics_report.py` lists (tables, OpenSim .sto files, figures,
report.md) and, with --rrd, a rerun recording with the ground reactions as arrows.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import InputError
from ..method.dynamics import CUTOFF
from ..method.settings import TrackerSettings
from .common import (
    add_command,
    add_map_arguments,
    add_subject_argument,
    build_subject,
    check_outputs,
    model_urdf,
    positive,
    subject_source,
)

EXAMPLES = """examples:
  torchik dynamics --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human66 --report dyn/
  torchik dynamics --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48 --report dyn/ \\
      --rrd dyn/walk.rrd                  also a rerun recording: the body and its ground reactions as arrows
  torchik dynamics --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --report dyn/ --no-fit
                                          the forces with the model and plates as given: no loop on forces
  torchik dynamics --input walk.npz --model human66 --report dyn/ --no-plates
                                          a recording without plates: the base's residual is the whole
                                          ground reaction
  torchik dynamics --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --report dyn/ \
      --mass-from bodymass                the mass the file states (PROCESSING:Bodymass), not the plates'
The model's masses follow the subject: --subject-from, else a --calibration trial or the input that
weighs or states the body mass, else the default subject (62.2 kg). Its mass: --mass, else what the
trial's plates weigh the subject at standing still on them (a static trial), else the stated one
(Plug-in Gait's PROCESSING:Bodymass); the output says which, and both where they differ.
"""


def add_parser(subparsers) -> None:
    """Register `torchik dynamics`."""
    parser = add_command(subparsers, "dynamics", "the forces of a recorded motion with force plates: joint torques "
                         "and powers, the base's residual", EXAMPLES,
                         description="Track a recording, put its force plates' ground reactions on the model's feet "
                                     "and compute the motion's inverse dynamics; write the joint torques and powers "
                                     "(CSV, OpenSim .sto), the base's residual wrench, figures and a report.")
    parser.add_argument("--input", required=True, metavar="FILE",
                        help="a recording with force plates (a C3D file; an .npz keeps them), in the model's links "
                             "or any skeleton with --map")
    add_map_arguments(parser)
    parser.add_argument("--model", default="human66", choices=("human66", "human48"),
                        help="the human model (default human66: three axes at every joint, as Plug-in Gait's)")
    add_subject_argument(parser, calibration_builds=True)
    parser.add_argument("--mass-from", choices=("plates", "bodymass"), default="plates",
                        help="the subject's mass: what the static trial's plates weigh it at, where it stands still "
                             "with every foot on a plate (default; else the stated one, and the output says why), "
                             "or the mass the file states (Plug-in Gait's PROCESSING:Bodymass)")
    parser.add_argument("--mass", type=positive, metavar="KG", help="the subject's mass in kg: overrides both")
    parser.add_argument("--report", required=True, metavar="DIR", help="the folder to write the report into")
    parser.add_argument("--rrd", metavar="FILE", help="also write a rerun recording (.rrd): the tracked body, its ground "
                                                      "reactions as arrows, the residual and sagittal series")
    parser.add_argument("--cutoff", type=positive, default=CUTOFF, metavar="HZ",
                        help=f"low-pass the tracked velocity at this frequency before differentiating (default {CUTOFF:g})")
    parser.add_argument("--wrench-cutoff", type=positive, metavar="HZ",
                        help="low-pass the ground reactions too (default: as the plates give them, as Plug-in Gait "
                             "takes them)")
    parser.add_argument("--wrench-at", choices=("segment", "model"), default="segment",
                        help="the point a foot's ground reaction moment is taken about and put on the model's foot: "
                             "the recording's own joint centre of the segment (default; the measured lever arm about "
                             "the ankle) or the model's foot origin (the force where the plate measured it)")
    parser.add_argument("--no-plates", action="store_true",
                        help="compute without ground reactions (a recording without plates): the base's residual is "
                             "then the whole ground reaction")
    parser.add_argument("--no-fit", action="store_true",
                        help="skip the loop on forces (by default the segment masses, the trunk's centre of mass, "
                             "the plates' centres of pressure and lag that the base's residual shows off are fitted "
                             "with held-out significance, applied, and the forces computed again)")
    parser.add_argument("--gain", type=positive, default=TrackerSettings.position_gain,
                        help=f"K of the tracker, 1/s (default {TrackerSettings.position_gain:g})")
    parser.add_argument("--force", action="store_true", help="write into a report folder that already holds a report")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bars)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from ..io import map_recording, read
    from ..io.base_position import measures_base_position
    from ..io.maps import default_map
    from ..method.models import TRACKED_LINKS, load_model
    from ..method.models.human import HumanSubject
    from ..pipelines.dynamics import motion_dynamics, summary
    from ..pipelines.dynamics_report import OUTPUTS, write_report, write_rrd

    say = (lambda _: None) if args.quiet else print
    out = Path(args.report)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is a file; --report names a folder")
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not args.force:
        raise InputError(f"{out} already holds {', '.join(existing)}; add --force to overwrite")
    if args.rrd and Path(args.rrd).suffix != ".rrd":
        raise InputError(f"{args.rrd}: a rerun recording's name must end in .rrd (e.g. walk.rrd)")
    check_outputs([args.rrd], args.force, inputs=[args.input, args.calibration])
    if not Path(args.input).is_file():
        raise InputError(f"{args.input}: no such file")
    if args.calibration and not args.map:
        raise InputError("--calibration calibrates a --map; give the map too")
    torch.set_num_threads(1)  # one subject's problems are too small for threads to pay
    start = time.perf_counter()
    built = build_subject(subject_source(args, args.input), args.map, say=say, mass=args.mass,
                          weighed=args.mass_from == "plates")
    subject = None if built is None else built.subject
    if subject is None and args.mass:
        subject = HumanSubject(mass=args.mass)
        say(f"subject: the default's height (1.68 m), mass {args.mass:g} kg (given)")
    elif subject is None:
        say("subject: the default (1.68 m, 62.2 kg): the file states no body mass; give --subject-from for the "
            "subject's own")
    model = load_model(args.model, subject)
    recording = read(args.input)
    map_name = args.map or default_map(recording.links, model)
    if map_name:
        static = read(args.calibration) if args.calibration else None
        recording, _ = map_recording(recording, map_name, model, static, args.calibration_frame, args.heading_axis)
    if model.base_link not in recording.links:
        raise InputError(f"{args.input}: no {model.base_link} among its segments {list(recording.links)}; give --map "
                         f"to name them as the model's links")
    if not measures_base_position(recording):
        raise InputError(f"{args.input} measures no base position: the base's acceleration, which the dynamics need, "
                         f"is unknown (a recording of orientations only)")
    if recording.external_wrench is None and not args.no_plates:
        raise InputError(f"{args.input} has no force plates (no ground reactions read): give a trial with plates, or "
                         f"--no-plates to compute without them (the base's residual then carries the whole ground "
                         f"reaction)")
    links = [name for name in TRACKED_LINKS[args.model] if name in recording.links]
    settings = TrackerSettings(position_gain=args.gain, orientation_gain=args.gain)
    dynamics = motion_dynamics(model, recording, links, settings=settings, cutoff=args.cutoff,
                               wrench_cutoff=args.wrench_cutoff, wrench_at=args.wrench_at, plates=not args.no_plates,
                               progress=not args.quiet)
    loop = None
    if not args.no_fit and not args.no_plates:
        from ..pipelines.dynamics_loop import close_loop

        loop = close_loop(model, recording, dynamics)
        dynamics = loop.after
    kinetics, agreement = {}, []
    if Path(args.input).suffix.lower() == ".c3d" and dynamics.wrench_links:
        from ..pipelines.plug_in_gait import agreement as agree
        from ..pipelines.plug_in_gait import plug_in_gait_kinetics

        kinetics = plug_in_gait_kinetics(args.input)
        agreement = agree(dynamics, kinetics)
    model_name = model.name or args.model
    paths = write_report(dynamics, out, model_name, None if built is None else built.report(), kinetics, agreement,
                         loop)
    if args.rrd:
        paths["rrd"] = write_rrd(dynamics, model, links, args.rrd, model_urdf(args.model, subject))
    if not args.quiet:
        numbers = summary(dynamics)
        print(f"dynamics of {args.input} with {model_name} ({dynamics.mass:.1f} kg): {len(dynamics.time)} frames in "
              f"{time.perf_counter() - start:.1f} s; MNTE median {dynamics.tracking['mnte']['median']:.2e}")
        stances = ", ".join(f"{s['link']} {s['start_frame']}-{s['stop_frame'] - 1}" for s in numbers["stance"])
        print(f"    on the plates (frames): {stances or 'none'}")
        covered = numbers["residual_force_per_weight"]["covered"]
        if covered and loop is None:
            print(f"    residual where the plates carry every foot on the ground ({numbers['covered_loaded_frames']} "
                  f"frames): force rms {100 * covered['rms']:.1f} % of body weight, moment rms "
                  f"{numbers['residual_moment_n_m_per_kg']['covered']['rms']:.3f} N m/kg")
        for line in [] if loop is None else loop.lines():
            print(f"    {line}")
        held = dynamics.notes.get("at_limits") or {}
        if held:
            print(f"    joints held at a limit (frames): {', '.join(f'{j} {n}' for j, n in held.items())}: the motion "
                  f"goes beyond {model_name}'s range there")
        for a in agreement:
            print(f"    {a.side.lower()} {a.joint.lower()} power against Plug-in Gait's in stance ({a.frames} frames): "
                  f"r sagittal {a.r_sagittal:.3f}, total {a.r_total:.3f}")
        print(f"wrote {out}/ ({', '.join(p.name for k, p in paths.items() if k != 'rrd')})")
        if "rrd" in paths:
            print(f"wrote {paths['rrd']}; open it with: rerun {paths['rrd']}")
    if dynamics.tracking.get("interrupted"):
        print(f"torchik dynamics: interrupted; the outputs hold the {len(dynamics.time)} frames tracked", file=sys.stderr)
        return 130
    return 0


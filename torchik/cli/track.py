"""`torchik track`: a recording or a built-in scenario tracked, with a report, a trajectory and a
rerun recording."""

from __future__ import annotations

import argparse
import builtins
import contextlib
import dataclasses
import functools
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.base_position import BASE_POSITION_MODES
from ..io.outputs import check_output_suffix
from ..io.plausible import Plausibility
from ..method.models import MODELS
from ..method.qp import BACKENDS
from ..method.settings import SCHEMES, TrackerSettings
from ..pipelines.contacts import (
    CONTACT_WEIGHT,
    FEET,
    HEIGHT,
    SPEED,
    CentreOfMassOffsets,
    LinkPositions,
    PostureDistance,
    contact_mask,
    log_tasks,
    task_report,
    tracking_tasks,
)
from ..pipelines.track import SETTLE
from ..synthetic.scenarios import SCENARIOS
from .common import (
    Terminated,
    add_command,
    add_map_arguments,
    add_subject_argument,
    check_outputs,
    fraction,
    model_urdf,
    more_than_one,
    non_negative,
    positive,
    subject_from,
    subject_source,
    torch_device,
)

MAX_FAILED = 0.01  # a restart now and then is recovery; one step in a hundred is a run not to trust

EXAMPLES = """examples:
  torchik track --scenario walking --model human66 --rrd walk.rrd --report walk.json
                                          track the built-in walking scenario, write a rerun recording
                                          (open it with: rerun walk.rrd) and report the errors
  torchik track --input walk.npz --model human66 --out estimate.npz
  torchik track --scenario running --duration 60 --gain 30 --backend batched --device cuda --quiet --rrd run.rrd
  torchik track --input walk.c3d --map plugin_gait_to_human --calibration static.c3d --model human48
  torchik track --input walk_orientations.sto --model human48 --out estimate.mot --out errors.sto
                                          an OpenSense IMU table: calibrated on its first frame, the base
                                          held; OpenSim's joint angles and OpenSense's orientation errors
  torchik models                          list the models with their DoF, links and limits
  torchik info walk.mvnx                  segments, rate, duration and gaps of a recording
  torchik convert walk.mvnx walk.npz      convert to torchik's recording format
  torchik models --links human48          also list each model's links and joint limits
  torchik models --write models/          write human66.urdf and human48.urdf (subject 1)
  torchik models --write out/ --height 1.85 --mass 80 --segment RightUpperArm=0.31
"""


def add_parser(subparsers) -> None:
    """Register `torchik track`."""
    track = add_command(subparsers, "track", "track a recording or a built-in scenario and report the errors",
                        EXAMPLES)
    source = track.add_mutually_exclusive_group()
    source.add_argument("--scenario", default="walking", help=f"built-in scenario: {', '.join(SCENARIOS)} (default walking)")
    source.add_argument("--input", metavar="FILE",
                        help="a recording (.npz) or source file whose segments are the model's links")
    add_map_arguments(track)
    track.add_argument("--model", default="human66", choices=MODELS)
    add_subject_argument(track, calibration_builds=True)
    track.add_argument("--urdf", metavar="FILE", help="track with this URDF of --model instead, e.g. the model.urdf "
                       "`torchik diagnose` writes (--model still names the tracked links)")
    track.add_argument("--sensor-calibration", metavar="JSON", help="undo the sensor effects (offsets, biases, delays, "
                       "drift) in the calibration.json `torchik diagnose` wrote for this session, after --map")
    track.add_argument("--position-targets", nargs="+", metavar="LINK",
                       help="links with position targets besides the base (e.g. RightHand LeftHand RightFoot LeftFoot): "
                            "the recording's segment origins, as MVNX, BVH and C3D files give them")
    track.add_argument("--contacts", nargs="+", metavar="LINK",
                       help="hold these links still while on the ground (auto: the feet), from their height and "
                            "speed in a first run without; the report gives their slide before and after")
    track.add_argument("--contact-weight", type=_contact_weight, default=CONTACT_WEIGHT, metavar="WEIGHT",
                       help=f"the contacts' weight against the targets' 1 (default {CONTACT_WEIGHT:g}), or exact: held "
                            "as equality rows of the QP, whatever the targets say")
    track.add_argument("--com", type=positive, metavar="WEIGHT",
                       help="hold the centre of mass over the middle of the feet with this weight (a balance prior)")
    track.add_argument("--posture", type=positive, metavar="WEIGHT",
                       help="pull the joints towards the zero posture with this weight (1e-3: what no target sees)")
    track.add_argument("--duration", type=positive, default=10.0, help="scenario length in seconds (default 10)")
    track.add_argument("--rate", type=positive, default=100.0, help="scenario rate in Hz (default 100)")
    track.add_argument("--seed", type=int, default=0)
    track.add_argument("--gain", type=positive, default=TrackerSettings.position_gain,
                       help=f"K for positions and orientations, 1/s (default {TrackerSettings.position_gain:g})")
    track.add_argument("--position-gain", type=positive, metavar="K", help="K of the position target, 1/s (default --gain)")
    track.add_argument("--orientation-gain", type=positive, metavar="K",
                       help="K of the orientation targets, 1/s (default --gain)")
    track.add_argument("--scheme", default=TrackerSettings.scheme, choices=tuple(SCHEMES))
    track.add_argument("--backend", default=TrackerSettings.backend, choices=("auto", *BACKENDS),
                       help="QP solver: PIQP per subject, batched in torch, or auto (batched for batches, default)")
    track.add_argument("--compile", action="store_true",
                       help="replay the usual step compiled: several times faster per step, one subject or a batch, "
                            "after a capture of seconds (one to two minutes the first time on a machine): for long "
                            "recordings and large batches")
    track.add_argument("--settle", type=non_negative, default=SETTLE, metavar="SECONDS",
                       help="start at rest in the first frame's posture, the tracker held this long on its targets "
                            f"(default {SETTLE:g}; 0: from the zero posture, the first tenths of a second a transient)")
    track.add_argument("--max-gap", type=more_than_one, default=TrackerSettings.max_gap, metavar="STEPS",
                       help="a gap in time longer than this many frame intervals starts a new segment: the tracker "
                            f"restarts from the targets after it (default {TrackerSettings.max_gap:g})")
    track.add_argument("--max-failed", type=fraction, default=MAX_FAILED, metavar="FRACTION",
                       help="exit 1, writing nothing, when steps failed (the state not finite or beyond the limits, "
                            f"the subject restarted) on more than this fraction of the steps (default {MAX_FAILED:g})")
    track.add_argument("--max-angular-velocity", type=positive, default=Plausibility.max_angular_velocity,
                       metavar="RAD_S", help="drop, as missing, link samples turning faster than this "
                       f"(default {Plausibility.max_angular_velocity:g} rad/s, beyond any human motion)")
    track.add_argument("--max-linear-velocity", type=positive, default=Plausibility.max_linear_velocity,
                       metavar="M_S", help="drop, as missing, base samples moving (or jumping between samples) "
                       f"faster than this (default {Plausibility.max_linear_velocity:g} m/s)")
    track.add_argument("--device", default="cpu", help="torch device: cpu (default), cuda or cuda:N")
    track.add_argument("--report", metavar="JSON", help="write the metrics here (- : standard output)")
    track.add_argument("--out", action="append", metavar="FILE",
                       help="write the estimated trajectory here, by the suffix: .npz (torchik's), .mot (the joint "
                            "angles as an OpenSim motion, degrees) or .sto (each IMU's orientation error, rad, as "
                            "OpenSense's orientationErrors.sto); repeat for several")
    track.add_argument("--base-position", choices=BASE_POSITION_MODES, default="held",
                       help="for a recording that measures no base position (an OpenSense IMU table): hold the base "
                            "in place (default, as OpenSense's IMU IK) or leave it free (no position target)")
    track.add_argument("--rrd", metavar="FILE", help="write a rerun recording here (.rrd): the body, targets and "
                       "diagnostics over time; open it with `rerun FILE`")
    track.add_argument("--force", action="store_true", help="overwrite existing outputs")
    track.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bars)")
    # one recording's steps are small: keeping every freed block on the heap only fragments it (an
    # hour's arrays and their temporaries then never return), which doubles the peak of a long run
    track.set_defaults(run=run, keep_freed_memory=False)


def run(args: argparse.Namespace) -> int:
    import torch

    from ..pipelines.track import nominal_dt, track_chunks

    if args.rrd and Path(args.rrd).suffix != ".rrd":
        raise InputError(f"{args.rrd}: a rerun recording's name must end in .rrd (e.g. walk.rrd)")
    args.out = args.out or []
    if "-" in args.out or args.rrd == "-":
        raise InputError("only --report may be - (standard output); --out and --rrd are files")
    for path in args.out:
        check_output_suffix(path, "--out")
    check_outputs([args.report, *args.out, args.rrd], args.force, inputs=[args.input, args.calibration,
                                                                           args.sensor_calibration, args.urdf])
    if not args.input and args.scenario not in SCENARIOS:
        raise InputError(f"unknown scenario {args.scenario!r}; valid: {', '.join(SCENARIOS)}")
    device = torch_device(args.device)
    if device.type == "cpu":
        # one subject's tensors are too small for torch to split, and on a busy machine its idle
        # threads spin and wait for each other: a step then takes several times longer
        torch.set_num_threads(1)
    model, subject, recording, links, source, left_out, base_note = _load(args, device)
    settings = TrackerSettings(position_gain=args.gain if args.position_gain is None else args.position_gain,
                               orientation_gain=args.gain if args.orientation_gain is None else args.orientation_gain,
                               scheme=args.scheme, backend=args.backend, max_gap=args.max_gap, compile=args.compile)
    settings = dataclasses.replace(settings, dt=nominal_dt(recording, settings))
    _check_stability(settings, settings.dt)
    start = time.perf_counter()
    position_links: tuple[str, ...] | None = None
    if args.position_targets:
        position_links = (model.base_link, *[name for name in args.position_targets if name != model.base_link])
    elif base_note and args.base_position == "free":
        position_links = ()  # nothing measures a position: no position target
    bounds = Plausibility(max_angular_velocity=args.max_angular_velocity, max_linear_velocity=args.max_linear_velocity)
    common = dict(progress=not args.quiet, position_links=position_links, plausibility=bounds, settle=args.settle)
    contacts = _contact_links(args, model)
    before = None
    if contacts:  # where the feet are on the ground, from a run without the contacts
        before = LinkPositions(model, contacts)
        track_chunks(model, recording, links, settings, [before], **common)
    masks = {link: contact_mask(before.position[:, k], before.time) for k, link in enumerate(contacts)} if before else {}
    tasks, limits = tracking_tasks(model, args.model, contacts, masks, args.com, args.posture, args.contact_weight)
    with _outputs(args, model, subject, links, position_links, recording, base_note) as outputs:  # written as it goes
        after, com, posture = LinkPositions(model, contacts), CentreOfMassOffsets(model, FEET[args.model]), PostureDistance()
        measured = ([after] if contacts else []) + ([posture] if args.posture else [])
        summary, implausible, interrupted = track_chunks(model, recording, links, settings,
                                                         [*outputs.values(), *measured, *([com] if args.com else [])],
                                                         tasks=tasks, constraints=limits, **common)
        report = summary.report(settings, implausible, interrupted)
        if tasks or limits:
            report["tasks"] = task_report(contacts, masks, before, after, com if args.com else None,
                                          posture if args.posture else None, args.com, args.posture)
        report.update(source=source, left_to_model=left_out, device=str(device), wall_time_s=time.perf_counter() - start)
        if base_note:
            report["base_position"] = base_note
        if not args.quiet:  # beside a report on standard output, on standard error
            _print_report(report, source, model.name or Path(model.source).stem,
                          sys.stderr if args.report == "-" else sys.stdout)
        if "rrd" in outputs and report.get("tasks"):
            log_tasks(outputs["rrd"], contacts, masks, after, com if args.com else None)
        fault = summary.fault(report, args.max_failed)
        if fault:  # the outputs are left uncommitted: nothing is written
            print(f"torchik track: {fault}", file=sys.stderr)
            return 1
        _write_outputs(args, report, outputs)
    if interrupted:
        how = "terminated" if Terminated.received else "interrupted"
        print(f"torchik track: {how}; the outputs hold the {report['frames']} frames tracked", file=sys.stderr)
        return 143 if Terminated.received else 130
    return 0


@contextlib.contextmanager
def _outputs(args: argparse.Namespace, model, subject, links, position_links, recording, base_note: str | None):
    """The writers of --out and --rrd, by file: each part of the run goes to them as it is
    tracked; their files appear when committed (`_write_outputs`), and none if the run fails."""
    from ..io.outputs import trajectory_writer

    with contextlib.ExitStack() as stack:
        writers: dict[str, Any] = {}
        segments = recording.meta.get("link_map", {}).get("segments", {})  # each link's source name (an IMU's)
        notes = dict(base_position=base_note) if base_note else None
        for path in args.out:
            writers[path] = stack.enter_context(trajectory_writer(path, model, links, segments, notes))
        if args.rrd:
            from ..pipelines.rrd import RrdWriter

            writers["rrd"] = stack.enter_context(RrdWriter(args.rrd, model, links, position_links=position_links,
                                                           urdf=args.urdf or model_urdf(args.model, subject)))
        yield writers


def _load(args: argparse.Namespace, device):
    """The model (its subject from --subject-from, else a --calibration trial stating the body mass:
    `subject_source`), the recording in its links (a .npz file read as its frames are needed; another
    format, or one mapped or calibrated, read whole; or a scenario), the tracked links, a phrase naming
    the source, the links the map found no segment for (left to the model: no target pulls them), and,
    for a recording that measures no base position, how the base is tracked (--base-position; None otherwise)."""
    from ..io import Recording, RecordingFile, map_recording, open_recording, read
    from ..io.base_position import NOT_MEASURED, measures_base_position, standing_base_position, unmeasured_base
    from ..io.maps import default_map
    from ..method.models import TRACKED_LINKS, load_model
    from ..synthetic.scenarios import ScenarioSource

    if args.subject_from and (args.urdf or args.model == "icub"):
        raise InputError("--subject-from builds a human model: give it with --model human66 or human48, without --urdf")
    subject = subject_from(subject_source(args) if args.input else args.subject_from, args.map,
                           say=(lambda _: None) if args.quiet else print)
    if args.urdf:  # e.g. the augmented model a diagnosis wrote
        from ..pipelines.diagnosis.calibration import load_urdf_model

        model = load_urdf_model(args.urdf, args.model, device)
    else:
        model = load_model(args.model, subject, device=device)
    links, left_out = TRACKED_LINKS[args.model], []
    recording: Recording | RecordingFile | ScenarioSource  # a file read, or a scenario made, as it is tracked
    if args.input:
        recording = open_recording(args.input)
        source = args.input
        map_name = args.map or default_map(recording.links, model)
        if map_name:
            static = read(args.calibration) if args.calibration else None
            recording, link_map = map_recording(_whole(recording), map_name, model, static, args.calibration_frame,
                                                args.heading_axis)
            links = recording.links
            left_out = list(recording.meta["link_map"]["left_out"])
            source += f" through map {link_map.name!r}"
    elif args.map or args.calibration:
        raise InputError("--map and --calibration apply to --input recordings; the scenarios are in the model's links")
    else:
        # made a chunk at a time as it is tracked, as a file is read: an hour takes a chunk's memory
        recording = ScenarioSource(args.scenario, model.to(device="cpu"), links, duration=args.duration,
                                   rate=args.rate, seed=args.seed)
        source = f"scenario {args.scenario} ({args.duration:g} s at {args.rate:g} Hz)"
    if args.sensor_calibration:  # the sensor effects a diagnosis found, undone
        from ..pipelines.diagnosis.calibration import apply_calibration_file

        recording = apply_calibration_file(_whole(recording), args.sensor_calibration)
        source += f" with sensor calibration {args.sensor_calibration}"
    base_note = None
    unmeasured = args.input and (recording.meta.get("base_position") == NOT_MEASURED or (
        isinstance(recording, Recording) and not measures_base_position(recording)))  # a file's: its meta says
    if unmeasured:  # held where the model stands at the origin, or free
        recording, base_note = unmeasured_base(_whole(recording), args.base_position, standing_base_position(model))
    return model, subject, recording, links, source, left_out, base_note


def _whole(recording):
    """A recording in memory, from a file's if need be (to map it or undo its sensor effects)."""
    from ..io import Recording

    return recording if isinstance(recording, Recording) else recording.read()


def _contact_weight(text: str) -> float:
    """--contact-weight: a positive number, or exact (inf: equality rows)."""
    return math.inf if text == "exact" else positive(text)


def _contact_links(args: argparse.Namespace, model) -> tuple[str, ...]:
    """The links of --contacts (auto: the model's feet)."""
    if not args.contacts:
        return ()
    feet = FEET[args.model]
    links = tuple(dict.fromkeys(link for name in args.contacts for link in (feet if name == "auto" else (name,))))
    unknown = [link for link in links if link not in model.link_names]
    if unknown:
        raise InputError(f"--contacts: model {model.name!r} has no link {unknown[0]!r}; its feet: {', '.join(feet)}")
    return links


def _write_outputs(args: argparse.Namespace, report: dict, outputs: dict) -> None:
    """The report (a file, or - for standard output), then the trajectory (--out) and the rerun
    recording (--rrd) committed."""
    from ..io import write_json

    if args.report == "-":
        print(json.dumps(report, indent=2))
    elif args.report:
        write_json(report, args.report)
        if not args.quiet:
            print(f"wrote {args.report}")
    for name, writer in outputs.items():
        path = writer.commit()
        if not args.quiet:
            print(f"wrote {path}" + (f"; open it with: rerun {path}" if name == "rrd" else ""))


def _check_stability(settings: TrackerSettings, dt: float) -> None:
    """Refuse gains beyond the scheme's stability bound K dt < 2 (the error would grow every step)."""
    largest = max(settings.position_gain, settings.orientation_gain)
    if largest * dt >= SCHEMES[settings.scheme]:
        raise InputError(f"gain {largest:g} at {1 / dt:g} Hz gives K dt = {largest * dt:.3g}, beyond the stability bound "
                         f"{SCHEMES[settings.scheme]:g}: use a gain below {SCHEMES[settings.scheme] / dt:g}")


def _print_report(report: dict, source: str, model_name: str, file=sys.stdout) -> None:
    m, r, st = report["mnte"], report["angular_velocity_rmse"], report["step_time_ms"]
    print = functools.partial(builtins.print, file=file)  # noqa: A001
    print(f"tracked {source} with {model_name}: {report['frames']} frames in {report['wall_time_s']:.1f} s")
    if m:
        print(f"    MNTE {_window(report)}: median {m['median']:.2e}, p99 {m['p99']:.2e}")
        if r:
            print(f"    angular velocity RMSE: median {r['median']:.2e} rad/s, p99 {r['p99']:.2e} rad/s")
    if "joint_error_rad" in report:
        print(f"    joint error against ground truth: max {report['joint_error_rad']['max']:.2e} rad")
    print(f"    step time: median {st['median']:.2f} ms, p99 {st['p99']:.2f} ms; "
          f"QP fallbacks {report['qp_fallbacks']}, dropped targets {report['dropped_targets']} "
          f"(implausible samples {report['implausible_samples']}), projected {report['projected_targets']}")
    if report["steps_without_targets"]:
        print(f"    {report['steps_without_targets']} steps without any target: their MNTE and RMSE are NaN")
    for name, task in report.get("tasks", {}).items():
        if name == "posture" and task["median_rms_rad"] is not None:
            print(f"    posture (weight {task['weight']:g}): the joints {task['median_rms_rad']:.3f} rad rms from it "
                  "(median)")
        if name == "centre of mass over the feet" and task["median_offset_m"] is not None:
            print(f"    {name} (weight {task['weight']:g}): {1e3 * task['median_offset_m']:.0f} mm off the feet's middle "
                  f"(median)")
        if name.startswith("contact "):
            b, a = task["slide_before"], task["slide_after"]
            if a["phases"]:
                print(f"    {name}: {100 * task['contact_share']:.0f} % of the time, {a['phases']} phases; slide per "
                      f"phase {b['mean_mm']:.1f} mm without (max {b['max_mm']:.1f}), {a['mean_mm']:.1f} mm with "
                      f"(max {a['max_mm']:.1f})")
            else:
                print(f"    {name}: never on the ground (lower than {HEIGHT * 1e3:.0f} mm above its lowest, slower "
                      f"than {SPEED:g} m/s)")
    if report.get("base_position"):
        print(f"    base position {report['base_position']}")
    if report["left_to_model"]:
        print(f"    left to the model (no segment in the recording): {', '.join(report['left_to_model'])}")
    if report["failed_steps"] or len(report["segments"]) > 1:
        print(f"    failed steps {report['failed_steps']} (restarted); segments (s): "
              + ", ".join(f"{a:.2f}-{b:.2f}" for a, b in report["segments"]))
    if m is None:
        builtins.print("    no step has any target: nothing was measured", file=sys.stderr)


def _window(report: dict) -> str:
    """The time the report's statistics cover, in words: never a window the recording does not have."""
    if report["statistics_from_s"]:
        return f"after {report['statistics_from_s']:g} s"
    whole, transient = f"over the whole {report['duration_s']:.2f} s", report["transient_s"]
    start = "settled on the first frame" if report["settled_s"] else "from the zero posture"
    if not transient:
        return whole
    why = "shorter than" if report["duration_s"] < transient else "no target after"
    return f"{whole} ({why} the {transient:g} s transient; tracking started {start})"

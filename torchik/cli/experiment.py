"""`torchik experiment paper`: the paper's comparison, table and figures."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError
from ..method.models import MODELS
from ..pipelines.experiment import OUTPUTS, PERSON, Settings, data_cases, run_paper, scenario_cases
from ..synthetic.scenarios import SCENARIOS
from .common import frame_argument, positive


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    existing = [out / name for name in OUTPUTS if (out / name).exists()]
    if existing and not args.force:
        raise InputError(f"{existing[0]} exists; add --force to overwrite the experiment's outputs in {out}")
    if min(args.duration, args.rate, args.convergence_seconds) <= 0 or args.transient < 0:
        raise InputError("--duration, --rate and --convergence-seconds must be positive, --transient not negative")
    if args.repeats < 1 or args.threads < 1 or args.max_iterations < 0:
        raise InputError("--repeats and --threads must be at least 1, --max-iterations not negative")
    settings = Settings(duration=args.duration, rate=args.rate, transient=args.transient, gain=args.gain,
                        backend=args.backend, tolerance=args.tolerance, step_tolerance=args.step_tolerance,
                        max_iterations=args.max_iterations, threads=args.threads, repeats=args.repeats,
                        convergence_seconds=args.convergence_seconds)
    if args.data:
        missing = [p for p in args.data if not Path(p).is_file()]
        if missing:
            raise InputError(f"--data {missing[0]}: no such file")
        cases = data_cases(args.data, args.models, args.map, args.calibration_frame)
        source = ", ".join(Path(p).name for p in args.data)
    else:
        if args.map:
            raise InputError("--map applies to --data recordings; the built-in scenarios are in the models' links")
        cases = scenario_cases(settings, args.models, args.scenarios)
        source = f"built-in scenarios generated on {PERSON}"
    rows, files = run_paper(out, settings, cases, progress=not args.quiet, source=source)
    if not args.quiet:
        print((out / "results.md").read_text())
        for path in files:
            print(f"wrote {path}")
    return 0


EXAMPLES = """examples:
  torchik experiment paper --out paper/          the whole comparison on the built-in scenarios
                                                 (3 models x 3 motions x 4 methods, 10 s at 100 Hz each)
  torchik experiment paper --out quick/ --duration 3 --models human48 icub --scenarios walking
  torchik experiment paper --out real/ --data ../shared/data/bvh/bandai_walk_normal_001.bvh --map bandai_to_human
  torchik experiment paper --out mvn/ --data ../shared/data/mvnx/test_mocap.mvnx
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `torchik experiment`."""
    parser = subparsers.add_parser(
        "experiment", help="reproduce the paper's comparison: dynamical against instantaneous IK, table and figures",
        description="Reproduce the paper's experiments: Human66, Human48 and iCub (through the human-to-iCub map) "
                    "track a T-pose, walking (4 km/h) and running (10 km/h) with whole-body and pair-wise "
                    "instantaneous IK and dynamical IK (paper and midpoint discretisations). Writes results.csv, "
                    "results.md (table and ratios) and the figures as PNG into --out.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", choices=("paper",), help="the experiment: paper")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for the table and figures")
    parser.add_argument("--data", action="append", metavar="FILE",
                        help="a recording to use instead of the built-in scenarios (repeatable; any format "
                             "`torchik track` reads)")
    parser.add_argument("--map", help="link map from the recordings' segments to the human models' links "
                                      "(e.g. bandai_to_human, cmu_to_human, plugin_gait_to_human)")
    parser.add_argument("--calibration-frame", type=frame_argument, default=None,
                        help="the frame holding the map's reference pose: an index or 'rest' (default: the map's)")
    parser.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS), help="default: all three")
    parser.add_argument("--scenarios", nargs="+", choices=tuple(SCENARIOS), default=list(SCENARIOS),
                        help="built-in scenarios (default: all three)")
    parser.add_argument("--duration", type=positive, default=Settings.duration, help="scenario length, s (default 10)")
    parser.add_argument("--rate", type=positive, default=Settings.rate, help="scenario rate, Hz (default 100)")
    parser.add_argument("--transient", type=float, default=Settings.transient,
                        help="seconds left out of the statistics (default 2, as the paper)")
    parser.add_argument("--gain", type=positive, default=Settings.gain,
                        help=f"K of the dynamical method, 1/s (default {Settings.gain:g})")
    parser.add_argument("--backend", choices=("batched", "piqp"), default=Settings.backend,
                        help="QP backend of every method (default batched)")
    parser.add_argument("--tolerance", type=positive, default=Settings.tolerance,
                        help="instantaneous IK: residual tolerance (default 1e-10)")
    parser.add_argument("--step-tolerance", type=positive, default=Settings.step_tolerance,
                        help="instantaneous IK: stop when an increment is below this, rad (default 1e-6)")
    parser.add_argument("--max-iterations", type=int, default=Settings.max_iterations,
                        help="instantaneous IK: iteration cap (default 50)")
    parser.add_argument("--threads", type=int, default=Settings.threads, help="torch threads while timing (default 1)")
    parser.add_argument("--repeats", type=int, default=Settings.repeats,
                        help="runs of each method; a step counts with its fastest (default 2)")
    parser.add_argument("--convergence-seconds", type=positive, default=Settings.convergence_seconds,
                        help="length of the convergence runs to a static T-pose, s (default 3)")
    parser.add_argument("--force", action="store_true", help="overwrite the outputs in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no table on stdout")
    parser.set_defaults(run=run)
    return parser

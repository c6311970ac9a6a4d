"""The `torchik` command line: one module per command (its arguments, progress, printing and exit
code), the options several commands share in `common.py`. Nothing outside this package imports it.

Exit codes: 0 ok; 2 bad input (one line on stderr saying what is wrong and what would be right);
1 failure; 130 interrupted by Ctrl-C, 143 by SIGTERM (`timeout`, a batch scheduler, `docker stop`),
which is handled as Ctrl-C (`track` has then written its outputs for the frames done).
"""

from __future__ import annotations

import argparse
import atexit
import os
import signal
import sys
import threading

from ..data import version
from ..errors import TorchikError
from . import bench, cohort, diagnose, dynamics, experiment, live, models, recordings, replay, retarget, track
from .common import Parser, Terminated, terminate_as_interrupt

# in --help's order
COMMANDS = (track, models, recordings, bench, experiment, retarget, cohort, diagnose, dynamics, live, replay)


def build_parser() -> Parser:
    parser = Parser(
        prog="torchik",
        description="Real-time motion tracking of people and humanoids by dynamical inverse kinematics.",
        epilog=track.EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"torchik {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from ..pipelines.memory import keep_freed_memory

    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "keep_freed_memory", True):
        keep_freed_memory()
    previous = terminate_as_interrupt()
    try:
        return args.run(args)
    except TorchikError as exc:
        print(f"torchik {args.command}: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        print(f"torchik {args.command}: terminated", file=sys.stderr)
        return 143
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
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)



def command() -> None:
    """The `torchik` console command (and `python -m torchik`): `main`, then the process ends without
    the interpreter's teardown when nothing else runs. Unloading torch and freeing what its modules
    hold takes far longer than `os._exit` (the timing: experiments/speed_history.md), after every
    output is written and closed. The exit
    handlers (multiprocessing's, rerun's, logging's) still run and the standard streams are flushed;
    with another thread still alive the usual exit waits for it."""
    code = main()
    if threading.active_count() > 1:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError):  # a reader that closed the pipe; a stream main closed
            pass
    os._exit(code)

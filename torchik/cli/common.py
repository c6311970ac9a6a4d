"""What every command shares: the parser, options that several commands take, checks made before
any work, and the device."""

from __future__ import annotations

import argparse
import math
import os
import signal
from pathlib import Path

from ..errors import InputError
from ..io.files import file_kind, is_replaceable


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: what is wrong and where the usage is, no usage dump."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def add_command(subparsers, name: str, help: str, examples: str, description: str | None = None):
    """A sub-command's parser, its examples shown after the options."""
    return subparsers.add_parser(name, help=help, description=description, epilog=examples,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)


def frame_argument(text: str) -> int | str:
    """argparse type of --calibration-frame: a frame index, or 'rest' (a BVH's rest pose)."""
    from ..io.maps import calibration_frame

    try:
        return calibration_frame(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_map_arguments(parser: argparse.ArgumentParser, target: str = "the model's links") -> None:
    """--map, --calibration, --calibration-frame and --heading-axis: how a recording's segments become `target`."""
    from ..io.maps import HEADING_AXES, built_in_maps

    parser.add_argument("--map", help=f"link map from the recording's segments to {target}: a built-in name "
                                      f"({', '.join(built_in_maps())}), a .toml file, or auto (the built-in map "
                                      f"whose segments the recording has; the default when its segments are not "
                                      f"the model's links)")
    parser.add_argument("--calibration", metavar="FILE", help="a static trial to calibrate the map's offsets on")
    parser.add_argument("--calibration-frame", type=frame_argument, default=None,
                        help="the frame holding the reference pose: an index, or 'rest' for a BVH rest pose "
                             "(default: the map's own choice, else 0)")
    parser.add_argument("--heading-axis", choices=HEADING_AXES, default=None,
                        help="the base segment's axis that points forward in the calibration frame (default the "
                             "map's: x for Plug-in Gait's pelvis, -z for OpenSense's pelvis_imu, as its "
                             "base_heading_axis)")


def check_outputs(paths, force: bool, inputs=()) -> None:
    """Refuse, before any work, outputs that exist (without --force), that are not regular files (a
    FIFO, a device, a socket, a symlink: replacing them would destroy them), that are one of the
    `inputs` or named twice, or whose folder does not exist or cannot be written. '-' (standard
    output) passes."""
    sources = {Path(p).resolve() for p in inputs if p}
    named = [Path(p).resolve() for p in paths if p and p != "-"]
    twice = next((path for path in named if named.count(path) > 1), None)
    if twice is not None:
        raise InputError(f"{twice} is given twice as an output; give each output once")
    for path in (Path(p) for p in paths if p and p != "-"):
        if not is_replaceable(path):
            raise InputError(f"{path} is {file_kind(path)}, which an output would replace; give a regular file's name"
                             " (or - for standard output where the option takes it)")
        if path.resolve() in sources:
            raise InputError(f"{path} is also an input; write the output to another file")
        if path.exists() and not force:
            raise InputError(f"{path} exists; add --force to overwrite it")
        if not path.parent.is_dir():
            raise InputError(f"{path}: no folder {path.parent} to write into; create it first")
        if not os.access(path.parent, os.W_OK | os.X_OK):
            raise InputError(f"{path}: the folder {path.parent} is not writable")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be: every `finally` (the `.part` files')
    and every handler of Ctrl-C (`track` keeping the frames done) runs for it too."""

    received = False  # since terminate_as_interrupt: a run that stopped tells SIGTERM from Ctrl-C by it


def terminate_as_interrupt():
    """Raise Terminated on SIGTERM from now on; returns the previous handler (None off the main
    thread, where Python cannot handle signals)."""
    def terminate(signum, frame):
        Terminated.received = True
        raise Terminated()

    Terminated.received = False
    try:
        return signal.signal(signal.SIGTERM, terminate)
    except ValueError:  # not the main thread
        return None


def positive(text: str) -> float:
    """argparse type of a quantity that must be a finite number above zero (a rate, a gain, a length)."""
    value = float(text)  # ValueError: argparse says "invalid float value"
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive, finite number")
    return value


def non_negative(text: str) -> float:
    """argparse type of a finite number from zero up (a duration that may be none)."""
    value = float(text)
    if not 0.0 <= value < math.inf:  # False for NaN
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number from 0 up")
    return value


def more_than_one(text: str) -> float:
    """argparse type of a count of frame intervals that must exceed one (a gap of one interval is no gap)."""
    value = positive(text)
    if value <= 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected more than 1 frame interval")
    return value


def fraction(text: str) -> float:
    """argparse type of a fraction, a finite number from 0 to 1."""
    value = float(text)
    if not 0.0 <= value <= 1.0:  # False for NaN
        raise argparse.ArgumentTypeError(f"{text!r}: expected a fraction from 0 to 1")
    return value


# what argparse names in "invalid float value: 'fast'"
positive.__name__ = non_negative.__name__ = more_than_one.__name__ = fraction.__name__ = "float"


def torch_device(text: str):
    """A torch.device from --device, refused before any work when torch has no such device here
    (the tracker runs on the CPU and on CUDA only: MPS has no float64)."""
    import torch

    try:
        device = torch.device(text)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise InputError(f"--device {text!r}: expected cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch here; use --device cpu")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise InputError(f"--device {text}: torch sees {torch.cuda.device_count()} CUDA devices here")
    return device


def model_urdf(name: str, subject=None):
    """A built-in model's URDF (text or path), for `subject` (a HumanSubject; default subject 1): what
    draws its body in a rerun recording."""
    from ..method.models import human_urdf, icub_urdf_path

    return icub_urdf_path() if name == "icub" else human_urdf(int(name[-2:]), subject)


def add_subject_argument(parser: argparse.ArgumentParser, calibration_builds: bool = False) -> None:
    """--subject-from: track with the subject's own human model, built from a recording (calibration_builds:
    the command builds it from a --calibration trial that states the body mass when none is given,
    `subject_source`)."""
    default = ("; without it, a --calibration trial that weighs the subject on its plates or states the body "
               "mass (Plug-in Gait's PROCESSING:Bodymass) builds it" if calibration_builds else "")
    parser.add_argument("--subject-from", metavar="RECORDING",
                        help="build the human model from this recording's skeleton (MVNX joint points, BVH bone "
                             "offsets through the map, a C3D static trial's Plug-in Gait lengths; a converted .npz "
                             "keeps them) instead of the default subject" + default)


def states_mass(path: str | None) -> bool:
    """Whether a recording states the subject's body mass (a Plug-in Gait trial's PROCESSING:Bodymass) or
    weighs it (a static trial's force plates, io/weighing.py)."""
    if not path:
        return False
    from ..io import read

    skeleton = read(path).meta.get("skeleton") or {}
    return bool(skeleton.get("mass") or (skeleton.get("weighed") or {}).get("mass_kg"))


def subject_source(args: argparse.Namespace, *more: str | None) -> str | None:
    """The recording a human model's subject is built from: --subject-from, else the first of
    --calibration and `more` (e.g. the input) that states or weighs the body mass (a Plug-in Gait trial:
    the model's segment masses, centres of mass and inertias then follow the mass its plates weigh or
    PROCESSING:Bodymass, and its lengths), else None (the default subject). None for a model given as a
    URDF or not human."""
    if getattr(args, "subject_from", None):
        return args.subject_from
    if getattr(args, "urdf", None) or not str(getattr(args, "model", "")).startswith("human"):
        return None
    return next((path for path in (getattr(args, "calibration", None), *more) if states_mass(path)), None)


def subject_from(path: str | None, map_name: str | None = None, say=print):
    """The HumanSubject a recording measures (None without a path), with one line saying where its
    numbers came from."""
    built = build_subject(path, map_name, say)
    return None if built is None else built.subject


def build_subject(path: str | None, map_name: str | None = None, say=print, mass: float | None = None,
                  weighed: bool = True):
    """`subject_from`'s BuiltSubject (the subject and where each of its numbers came from), or None; mass
    (kg) given and weighed: `subject_from_recording`'s."""
    if path is None:
        return None
    from ..io import read
    from ..io.subjects import WEIGHED, subject_from_recording

    built = subject_from_recording(read(path), mass=mass, map_name=None if map_name in (None, "auto") else map_name,
                                   weighed=weighed)
    say(f"subject from {path}: height {built.subject.height:.3f} m ({built.height_from}), mass "
        f"{built.subject.mass:.{2 if built.mass_from.startswith(WEIGHED) else 1}f} kg ({built.mass_from}); "
        f"{len(built.from_file)} segment lengths and "
        f"{len(built.subject.joint_origins)} joint placements from the file, {len(built.scaled)} segments scaled")
    return built

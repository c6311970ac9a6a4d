"""`torchik retarget`: a human recording to iCub joint trajectories a position controller can stream.

The recording (the human models' links, or any skeleton through --map) goes through the built-in
human-to-iCub map (models/maps/human_to_icub.toml), is resampled to the controller's rate when it
has another (orientations by slerp, velocities and the base position linearly), and iCub tracks it
with dynamical IK (midpoint scheme). The start is the whole-body IK solution of the first frame,
inside every limit, so every sample is: each step's velocity bounds keep the joints within
their limits and the coupled shoulder/elbow limits A s <= b, and the output is checked against
both before it is written (1e-6 rad).

Output (.npz): time [T] s, joint_names [n], joint_positions [T,n] rad, joint_velocities [T,n]
rad/s, base_position [T,3], base_rotation [T,3,3], mnte [T] (iCub link orientations against the
mapped human ones), rate_hz. The rates are the steps' own: s_k = s_{k-1} + dt * rate_k exactly, so
angles and rates agree, and both are what the limits allowed.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import so3
from .baselines import WholeBodyIK
from .errors import InputError
from .cli import add_map_arguments
from .experiment import human_to_icub, link_motion
from .io.maps import map_recording
from .io.recording import Recording
from .kinematics import KinematicModel
from .limits import LimitSettings
from .metrics import mnte, summary
from .models import load_model
from .scenarios import recording_targets
from .tracker import DynamicalIK

LIMIT_TOLERANCE = 1e-6  # rad (and the units of A s <= b): the largest excursion accepted in the output
MIN_RATE = 50.0  # Hz: slower streams make a position controller's steps too coarse


@dataclass(frozen=True)
class Retargeted:
    """iCub trajectories: time [T]; joint_names (n); joint_positions, joint_velocities [T,n];
    base_position [T,3]; base_rotation [T,3,3]; mnte [T]; limit_excess: the largest excursion
    beyond a joint or coupled limit over the whole trajectory (<= 0: all inside)."""

    time: np.ndarray
    joint_names: tuple[str, ...]
    joint_positions: np.ndarray
    joint_velocities: np.ndarray
    base_position: np.ndarray
    base_rotation: np.ndarray
    mnte: np.ndarray
    limit_excess: float


def resample(recording: Recording, rate: float) -> Recording:
    """The recording at `rate` Hz over its own time span: orientations by slerp between the frames
    around each new instant, angular velocities, base position and velocity linearly. A new sample
    next to a missing frame (NaN) is missing too."""
    t = recording.time
    new = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1) / rate
    k = np.clip(np.searchsorted(t, new, side="right") - 1, 0, len(t) - 2)  # frame before each new instant
    alpha = np.clip((new - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
    R0, R1 = torch.from_numpy(recording.orientation[k]), torch.from_numpy(recording.orientation[k + 1])
    a = torch.from_numpy(alpha)[:, None, None]
    rotation = R0 @ so3.exp(a * so3.log(R0.transpose(-1, -2) @ R1))  # [T',L,3,3]
    lerp = lambda x: x[k] + alpha.reshape((-1,) + (1,) * (x.ndim - 1)) * (x[k + 1] - x[k])  # noqa: E731
    meta = dict(recording.meta, resampled_from_hz=recording.frame_rate, frame_rate=rate)
    return Recording(time=new, links=recording.links, orientation=rotation.numpy(),
                     angular_velocity=lerp(recording.angular_velocity), base_link=recording.base_link,
                     base_position=lerp(recording.base_position), base_linear_velocity=lerp(recording.base_linear_velocity),
                     meta=meta)


def limit_excess(model: KinematicModel, joint_positions: torch.Tensor) -> float:
    """The largest amount by which joint_positions [T,n] exceed a joint limit or a coupled limit
    row (negative: the smallest margin)."""
    excess = torch.maximum(joint_positions - model.upper, model.lower - joint_positions).amax()
    if model.linear_limits is not None:
        A, b = model.linear_limits.A, model.linear_limits.b
        excess = torch.maximum(excess, (joint_positions @ A.T - b).amax())
    return float(excess)


def retarget(recording: Recording, rate: float = 100.0, gain: float = 20.0, progress: bool | None = None,
             transient: float = 2.0, limits: LimitSettings = LimitSettings()) -> tuple[Retargeted, dict]:
    """Retarget a recording in the human models' links to iCub at `rate` Hz with gain K (1/s) and
    the tracker's `limits` (limits.max_rate caps every joint's rate, rad/s). Returns the iCub
    trajectories and a report (MNTE after `transient` s, the limits' margin, the rate)."""
    if rate < MIN_RATE:
        raise InputError(f"rate {rate:g} Hz: a position controller needs {MIN_RATE:g} Hz or more")
    if gain <= 0 or gain / rate >= 2.0:
        raise InputError(f"gain {gain:g} 1/s at {rate:g} Hz: K must be positive with K dt < 2 (stability)")
    if limits.max_rate <= 0:
        raise InputError(f"the largest joint rate must be positive, got {limits.max_rate:g} rad/s")
    icub = load_model("icub")
    mapped = human_to_icub(recording, icub)
    if len(mapped.time) < 2:
        raise InputError("the recording has fewer than two frames")
    if abs(mapped.frame_rate - rate) > 1e-6 * rate:
        mapped = resample(mapped, rate)
    links = mapped.links
    sequence = recording_targets(mapped, links, dtype=icub.dtype, device=icub.device)
    tracker = DynamicalIK(icub, links, position_gain=gain, orientation_gain=gain, dt=1.0 / rate, limits=limits)
    # start inside every limit, at the first frame's best fit: iCub's zero configuration is outside
    # its coupled shoulder limits, and the tracker would return from there at a bounded rate only
    start = WholeBodyIK(icub, links).solve(sequence[0], tracker.initial_state(sequence[0])).state
    trajectory = tracker.run(sequence, start, progress=progress)
    R_hat, _ = link_motion(icub, trajectory, links, centred=True)
    R_target = sequence.rotation[:, 0]
    known = torch.isfinite(R_target).flatten(-3).all(-1)
    error = torch.where(known, mnte(torch.where(known[:, None, None, None], R_target, torch.eye(3, dtype=R_target.dtype)),
                                    R_hat), torch.nan)
    s = trajectory.joint_positions[:, 0]
    host = lambda x: x.detach().cpu().numpy()  # noqa: E731
    result = Retargeted(host(trajectory.time), icub.joint_names, host(s), host(trajectory.velocity[:, 0, 6:]),
                        host(trajectory.base_position[:, 0]), host(trajectory.base_rotation[:, 0]), host(error),
                        limit_excess(icub, s))
    report = dict(frames=len(result.time), rate_hz=rate, duration_s=float(result.time[-1] - result.time[0]),
                  mnte=summary(error[known], trajectory.time[known], transient) if bool(known.any()) else None,
                  limit_excess=result.limit_excess, max_joint_rate=float(np.abs(result.joint_velocities).max()),
                  qp_fallbacks=int((~trajectory.diagnostics["solved"]).sum()))
    return result, report


def save(result: Retargeted, path: str | Path, meta: dict | None = None) -> Path:
    """Write `result` as .npz (see the module docstring), replacing `path` only once complete."""
    path = Path(path)
    arrays = dict(time=result.time, joint_names=np.array(result.joint_names, dtype=str),
                  joint_positions=result.joint_positions, joint_velocities=result.joint_velocities,
                  base_position=result.base_position, base_rotation=result.base_rotation, mnte=result.mnte,
                  rate_hz=np.array(1.0 / np.median(np.diff(result.time))),
                  source=np.array(str((meta or {}).get("source", ""))))
    part = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:  # written aside, then renamed: an interrupted write leaves the old file or none
        with open(part, "wb") as f:
            np.savez(f, **arrays)
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)
    return path


def _run(args: argparse.Namespace) -> int:
    from .cli import read_any

    out = Path(args.out)
    if out.suffix != ".npz":
        raise InputError(f"{out}: the output must be a .npz file")
    if out.exists() and not args.force:
        raise InputError(f"{out} exists; add --force to overwrite it")
    if not Path(args.recording).is_file():
        raise InputError(f"{args.recording}: no such file")
    recording = read_any(args.recording)
    if args.map:
        static = read_any(args.calibration) if args.calibration else None
        recording, _ = map_recording(recording, args.map, load_model("human66"), static, args.calibration_frame)
    elif args.calibration:
        raise InputError("--calibration calibrates a --map; give the map too")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one subject's problems are too small for threads to pay
    try:
        result, report = retarget(recording, args.rate, args.gain, progress=False if args.quiet else None,
                                  limits=LimitSettings(max_rate=args.max_rate))
    finally:
        torch.set_num_threads(threads)
    if result.limit_excess > LIMIT_TOLERANCE:
        print(f"torchik retarget: the iCub trajectory exceeds a limit by {result.limit_excess:.3g}; nothing written",
              file=sys.stderr)
        return 1
    save(result, out, dict(source=args.recording))
    if not args.quiet:
        m = report["mnte"]
        print(f"retargeted {args.recording} to iCub: {report['frames']} frames at {args.rate:g} Hz "
              f"({report['duration_s']:.1f} s)")
        if m:
            print(f"    MNTE of iCub's links against the mapped human ones: median {m['median']:.2e}, p99 {m['p99']:.2e}")
        print(f"    within every joint and coupled limit at every frame (largest excess {max(result.limit_excess, 0.0):.1e} "
              f"rad); largest joint rate {report['max_joint_rate']:.2f} rad/s; QP fallbacks {report['qp_fallbacks']}")
        print(f"wrote {out}")
    return 0


EXAMPLES = """examples:
  torchik retarget walk.npz --to icub --out icub.npz      a recording in the human models' links
  torchik retarget ../shared/data/mvnx/test_mocap.mvnx --to icub --out icub.npz
  torchik retarget walk.bvh --map bandai_to_human --to icub --out icub.npz --rate 200
  python -c "import numpy as np; d = np.load('icub.npz'); print(d['joint_names'], d['joint_positions'].shape)"
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `torchik retarget`."""
    parser = subparsers.add_parser(
        "retarget", help="retarget a human recording to iCub joint trajectories within every limit",
        description="Track a human recording with the iCub model (through the human-to-iCub link map) and write "
                    "iCub joint trajectories (names, angles, rates, time) within every joint limit and the coupled "
                    "shoulder limits, at a rate a position controller can stream (50 Hz or more).",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", help="a recording (.npz, .mvnx, .bvh, .c3d) in the human models' links, or "
                                          "any skeleton with --map")
    parser.add_argument("--to", required=True, choices=("icub",), help="the robot: icub")
    parser.add_argument("--out", required=True, metavar="NPZ", help="the iCub trajectories to write (.npz)")
    add_map_arguments(parser, "the human models' links")
    parser.add_argument("--rate", type=float, default=100.0,
                        help="output rate in Hz, 50 or more (default 100); the recording is resampled to it")
    parser.add_argument("--gain", type=float, default=20.0, help="K of the tracker, 1/s (default 20)")
    parser.add_argument("--max-rate", type=float, default=LimitSettings().max_rate,
                        help=f"the largest joint rate, rad/s (default {LimitSettings().max_rate:g}): set it to the "
                             f"robot's own")
    parser.add_argument("--force", action="store_true", help="overwrite the output if it exists")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.set_defaults(run=_run)
    return parser

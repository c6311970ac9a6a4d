"""The loop on forces on the shared Vicon walks: the base's residual before and after it.

    python experiments/dynamics_loop.py [--out experiments/dynamics/loop.md] [--figures experiments/dynamics]
                                        [--mass-from plates|bodymass]

Each walk goes through `torchik dynamics`'s pipeline as `dynamics_plugin_gait.py` runs it (the subject
from the static trial, its mass what the static trial's plates weigh, io/weighing.py, or with
--mass-from bodymass PROCESSING:Bodymass; Human66, plugin_gait_to_human calibrated on the static
trial, the plates as read),
then `close_loop` (pipelines/dynamics_loop.py). Nothing was tuned on any walk: the effects, their
limits and the significance are `dynamics_fit.py`'s as the tests on synthetic walks set them.

A row per walk. Columns: the residual over `residual_frames` (the plates carry every foot wholly, and
none is missing within the 6 Hz low-pass' reach), with the plates low-passed at the motion's 6 Hz
(force % of the body weight given, rms and max; moment N m/kg rms), before and after, the effects
kept and refused, and the subject's mass and where it came from (the static trial's plates: the
mean vertical force over g where the subject stands still with every foot on a plate, against the
file's Bodymass). A figure per walk: <figures>/loop_<walk>.png, the residual force over time before and
after, those frames shaded.
"""

from __future__ import annotations

import argparse
import time
from datetime import date
from pathlib import Path

import torch

from torchik.io import map_recording, read
from torchik.io.subjects import subject_from_recording
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.dynamics import motion_dynamics
from torchik.pipelines.dynamics_loop import close_loop
from torchik.pipelines.dynamics_report import loop_figure

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
WALKS = (("HC002D06", "HC002D02"), ("HC002D25", "HC002D02"), ("HC030A05", "HC030A01"), ("HC030A22", "HC030A01"))
MAP = "plugin_gait_to_human"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    parser.add_argument("--figures", type=Path, default=Path("experiments/dynamics"), help="the figures' folder")
    parser.add_argument("--mass-from", choices=("plates", "bodymass"), default="plates",
                        help="the subject's mass: the static trial's plates' (default) or PROCESSING:Bodymass")
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.figures.mkdir(parents=True, exist_ok=True)
    lines = [f"# The loop on forces on the shared walks, {date.today()}", "",
             "| walk | frames | force rms before -> after (% BW) | force max before -> after | "
             "moment rms before -> after (N m/kg) | kept | refused | the subject's mass |",
             "|---|---:|---|---|---|---|---|---|"]
    start = time.perf_counter()
    for walk, static_name in WALKS:
        if not (DATA / f"{walk}.c3d").is_file():
            print(f"skipped {walk}: {DATA / f'{walk}.c3d'} absent")
            continue
        static = read(DATA / f"{static_name}.c3d")
        built = subject_from_recording(static, map_name=MAP, weighed=args.mass_from == "plates")
        model = load_model("human66", built.subject)
        recording, _ = map_recording(read(DATA / f"{walk}.c3d"), MAP, model, static)
        links = [link for link in TRACKED_LINKS["human66"] if link in recording.links]
        loop = close_loop(model, recording, motion_dynamics(model, recording, links))
        b, a = loop.residual(loop.wrench_before), loop.residual(loop.wrench_after)
        kept = "; ".join(f"{e.name} " + ", ".join(f"{v:+.3g}" for v in e.value) + f" {e.labels[0]}"
                         + ("" if e.relative is None else f" ({100 * e.relative:+.0f} %)")
                         for e in loop.fit.effects) if loop.fit else loop.reason
        refused = "; ".join(f"{r.name}: {r.reason}" for r in loop.fit.refused) if loop.fit else ""
        weighed = f"{built.subject.mass:.2f} kg: {built.mass_from}"
        lines += [f"| {walk} | {int(loop.frames.sum())} | {100 * b.force_rms:.1f} -> {100 * a.force_rms:.1f} | "
                  f"{100 * b.force_max:.1f} -> {100 * a.force_max:.1f} | {b.moment_rms:.3f} -> {a.moment_rms:.3f} | "
                  f"{kept or 'nothing'} | {refused or '-'} | {weighed} |"]
        print(lines[-1], flush=True)
        loop_figure(loop, args.figures / f"loop_{walk}.png",
                    f"{walk}: base residual force, rms over the shaded frames (the plates carry every foot) "
                    f"{100 * b.force_rms:.1f} -> {100 * a.force_rms:.1f} % of body weight")
    lines += ["", f"({time.perf_counter() - start:.0f} s)"]
    print(lines[-1])
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

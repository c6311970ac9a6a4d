"""Hands and feet as position targets on the shared C3D walks: the subject's own model (built from
its Plug-in Gait static trial) against the default subject (1.68 m, 62.2 kg).

    python experiments/position_targets.py [--model human48] [--transient 1.0] [--out FILE.md]

For each walk, mapped through plugin_gait_to_human calibrated on its static trial as `torchik
track --calibration` does, and each model: tracked twice with the orientation targets of every
mapped link and the pelvis position, (a) with hands and feet as position targets too (`torchik
track --position-targets RightHand LeftHand RightFoot LeftFoot`), (b) without them, where the hand
and foot positions are predicted by the model's kinematics from the orientations alone. The table
gives the distance from the estimated hand and foot origins (wrist and ankle joint centres) to the
Plug-in Gait joint centres, median and 99th percentile in mm over the four links and the frames
after --transient seconds (the walks are 2 to 5 s long). The recordings are read where they lie.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from torchik.io import map_recording, read
from torchik.io.subjects import subject_from_recording
from torchik.io.targets import recording_targets
from torchik.method.models import load_model
from torchik.method.settings import TrackerSettings
from torchik.pipelines.evaluation import after_transient, position_errors
from torchik.pipelines.track import track_recording

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
WALKS = (("HC002D06", "HC002D02"), ("HC002D25", "HC002D02"), ("HC030A05", "HC030A01"), ("HC030A22", "HC030A01"))
ENDS = ("RightHand", "LeftHand", "RightFoot", "LeftFoot")


def errors_mm(model, recording, with_targets: bool, transient: float) -> torch.Tensor:
    """Hand and foot position errors (mm) after the transient, tracked with or without their targets."""
    position_links = (model.base_link, *ENDS) if with_targets else None
    trajectory, _ = track_recording(model, recording, recording.links, TrackerSettings(), transient=transient,
                                    position_links=position_links)
    sequence = recording_targets(recording, recording.links, ENDS, dtype=model.dtype)
    error = position_errors(model, trajectory, sequence, ENDS)[:, 0]  # [T,4]
    error = after_transient(error, trajectory.time, transient)
    return 1e3 * error[torch.isfinite(error)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="human48", choices=("human48", "human66"))
    parser.add_argument("--transient", type=float, default=1.0)
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    lines = ["| walk | subject (static trial) | model | with hand and foot targets: median, p99 (mm) | "
             "orientations only: median, p99 (mm) |", "|---|---|---|---|---|"]
    for walk, static_name in WALKS:
        static = read(DATA / f"{static_name}.c3d")
        built = subject_from_recording(static)
        for label, subject in (("default (1.68 m, 62.2 kg)", None),
                               (f"from {static_name} ({built.subject.height:.2f} m, {built.subject.mass:.1f} kg)",
                                built.subject)):
            model = load_model(args.model, subject)
            recording, _ = map_recording(read(DATA / f"{walk}.c3d"), "plugin_gait_to_human", model, static)
            cells = []
            for with_targets in (True, False):
                e = errors_mm(model, recording, with_targets, args.transient)
                cells.append(f"{e.median():.0f}, {e.quantile(0.99):.0f}")
            lines.append(f"| {walk} | {label} | {args.model} | {cells[0]} | {cells[1]} |")
            print(lines[-1], flush=True)
    table = "\n".join(lines)
    print("\n" + table)
    if args.out:
        args.out.write_text(table + "\n")


if __name__ == "__main__":
    main()

"""Feet held on the ground: the slide of a tracked foot during stance, without contacts and with them
(a stiff task, and equality rows), on the built-in walking scenario and the shared C3D walks.

    python experiments/contacts.py [--model human48] [--out experiments/contacts.md]

Each walk is tracked as `torchik track` does (settled on its first frame; the C3D walks mapped
through plugin_gait_to_human calibrated on their static trial), first without contacts: where a
foot is within 3 cm of the lowest it goes and moves slower than 0.3 m/s, it is in stance
(pipelines/contacts.py). Then again with each foot held there, as `torchik track --contacts auto`
(a task of weight 100) and `--contact-weight exact` (equality rows). The table gives, per walk, the
feet's slide per stance phase (the largest horizontal distance the foot's origin travels from where
the phase began; mean and largest over the phases of both feet, mm), the orientation error (MNTE
median, rad, as `torchik track` reports it: after 2 s, or over a shorter walk) and how far the
pelvis is from its position target (median, mm): orientations alone fix every joint, so a foot held
still moves the base off the pelvis' measured position, and that is where the contacts cost. The built-in
scenario's walk is kinematic (no foot is ever still in it: its slowest foot moves at 0.1 m/s), so
its stance is found by height alone. The recordings are read
where they lie; absent, their rows are skipped, saying so.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch

from torchik.io import map_recording, read
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.settings import TrackerSettings
from torchik.pipelines.contacts import FEET, LinkPositions, contact_mask, foot_slide, tracking_tasks
from torchik.pipelines.track import SETTLE, nominal_dt, track_chunks
from torchik.synthetic.scenarios import scenario

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
WALKS = (("HC002D06", "HC002D02"), ("HC002D25", "HC002D02"), ("HC030A05", "HC030A01"), ("HC030A22", "HC030A01"))
MODES = (("without", None), ("task (weight 100)", 100.0), ("equality rows", math.inf))


def walks(model, name: str):
    """(label, recording in the model's links, speed threshold) of the built-in walk and the C3D walks."""
    yield "built-in walking scenario (10 s)", scenario("walking", model, TRACKED_LINKS[name], 10.0, 100.0), math.inf
    for walk, static in WALKS:
        if not (DATA / f"{walk}.c3d").is_file():
            print(f"skipped {walk}: {DATA / f'{walk}.c3d'} absent")
            continue
        recording, _ = map_recording(read(DATA / f"{walk}.c3d"), "plugin_gait_to_human", model, read(DATA / f"{static}.c3d"))
        yield f"{walk} (calibrated on {static})", recording, 0.3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="human48", choices=("human48", "human66"))
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, feet = load_model(args.model), FEET[args.model]
    header = " | ".join(f"{mode}: slide mean, max (mm); MNTE; pelvis off (mm)" for mode, _ in MODES)
    lines = [f"| walk | stance (share of the time, phases) | {header} |", "|---|---|" + "---|" * len(MODES)]
    for label, recording, speed in walks(model, args.model):
        links = tuple(n for n in TRACKED_LINKS[args.model] if n in recording.links)
        settings = TrackerSettings(dt=nominal_dt(recording, TrackerSettings()))
        masks, cells, share = {}, [], ""
        for mode, weight in MODES:
            start = time.perf_counter()
            tasks, limits = tracking_tasks(model, args.model, feet if masks else (), masks, None, None,
                                       weight or 100.0)
            positions = LinkPositions(model, feet + (model.base_link,))
            summary, _, _ = track_chunks(model, recording, links, settings, [positions], settle=SETTLE,
                                         tasks=tasks, constraints=limits)
            if not masks:  # the stance, from the run without contacts
                masks = {foot: contact_mask(positions.position[:, k], positions.time, speed=speed)
                         for k, foot in enumerate(feet)}
                on = np.stack(list(masks.values()))
            slides = [foot_slide(positions.position[:, k], masks[foot]) for k, foot in enumerate(feet)]
            phases = sum(s["phases"] for s in slides)
            per_phase = [s["mean_mm"] * s["phases"] for s in slides if s["phases"]]
            mean = sum(per_phase) / phases if phases else math.nan
            largest = max((s["max_mm"] for s in slides if s["phases"]), default=math.nan)
            mnte = summary.report(settings, 0, False)["mnte"]["median"]  # after the report's transient
            # where holding the feet costs: the pelvis moved off its position target (the orientations stay)
            pelvis = 1e3 * np.nanmedian(np.linalg.norm(positions.position[:, -1] - recording.base_position, axis=-1))
            cells.append(f"{mean:.1f}, {largest:.1f}; {mnte:.2e}; {pelvis:.0f}")
            share = f"{100 * on.mean():.0f} %, {phases}"
            print(f"{label}: {mode}: slide {mean:.2f} mm mean, {largest:.2f} max; MNTE {mnte:.3g}; pelvis {pelvis:.1f} mm; "
                  f"{time.perf_counter() - start:.1f} s")
        lines.append(f"| {label} | {share} | " + " | ".join(cells) + " |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()

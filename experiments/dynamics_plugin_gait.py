"""torchik's sagittal joint powers against Plug-in Gait's own, on the shared Vicon walks.

    python experiments/dynamics_plugin_gait.py [--variants default,human48,...] [--out table.md]

Each walk goes through `torchik dynamics`'s pipeline (`motion_dynamics`): mapped through
plugin_gait_to_human calibrated on its static trial, the subject built from that trial (its
PROCESSING:Bodymass, Height and lengths, its hip joint centres), tracked, its plates' ground
reactions on the feet, inverse dynamics at 6 Hz. For each side whose foot stands on a plate, and each
joint, Pearson's r over the frames of that stance between torchik's sagittal power (the y degree of
freedom's torque times its rate, per kg) and Plug-in Gait's sagittal term (its moment's x component
times the relative angular velocity about the distal segment's lateral axis, W/kg), and between the
total powers (torchik's summed over the joint's degrees of freedom; Plug-in Gait's stored
`<S><J>Power`, z component); `torchik/pipelines/plug_in_gait.py` says how Plug-in Gait's outputs
were read.

Variants (each changes one thing from `default`, Human66 as the command runs it):

    default            Human66, the map as shipped (thigh and shank calibrated about their long axes only)
    human48            Human48: its joint limits and reduced axes
    human48-no-limits  Human48 with its joint limits removed (every joint +-10 rad)
    full-calibration   the legs' offsets calibrated whole on the static pose, as before (calibrate = true)
    wrench-at-model    the ground reaction's moment about the model's foot origin, not the markers' ankle
    wrench-6hz         the ground reactions low-passed at 6 Hz, as the motion is

The recordings are read where they lie (../shared/data/c3d); absent, their rows are skipped, saying so.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np
import torch

from torchik.io import map_recording, read
from torchik.io.subjects import subject_from_recording
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.dynamics import motion_dynamics, summary
from torchik.pipelines.plug_in_gait import agreement, plug_in_gait_kinetics

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
WALKS = (("HC002D06", "HC002D02"), ("HC002D25", "HC002D02"), ("HC030A05", "HC030A01"), ("HC030A22", "HC030A01"))
VARIANTS = ("default", "human48", "human48-no-limits", "full-calibration", "wrench-at-model", "wrench-6hz")
MAP = "plugin_gait_to_human"


def full_calibration_map(folder: Path) -> Path:
    """The built-in map with the legs calibrated whole (`calibrate = true`), as before the twist."""
    from torchik.data import maps_folder

    text = (maps_folder() / f"{MAP}.toml").read_text().replace('calibrate = "twist"', "calibrate = true")
    path = folder / "full_calibration.toml"
    path.write_text(text)
    return path


def run(walk: str, static_name: str, variant: str, folder: Path) -> tuple[list, dict]:
    """The agreement rows of one walk under one variant, and the summary of its dynamics (the residual)."""
    static = read(DATA / f"{static_name}.c3d")
    subject = subject_from_recording(static, map_name=MAP).subject
    model_name = "human48" if variant.startswith("human48") else "human66"
    model = load_model(model_name, subject)
    if variant == "human48-no-limits":
        model.lower, model.upper = torch.full_like(model.lower, -10.0), torch.full_like(model.upper, 10.0)
    link_map = full_calibration_map(folder) if variant == "full-calibration" else MAP
    recording, _ = map_recording(read(DATA / f"{walk}.c3d"), link_map, model, static)
    links = [link for link in TRACKED_LINKS[model_name] if link in recording.links]
    dynamics = motion_dynamics(model, recording, links, wrench_at="model" if variant == "wrench-at-model" else "segment",
                               wrench_cutoff=6.0 if variant == "wrench-6hz" else None)
    return agreement(dynamics, plug_in_gait_kinetics(DATA / f"{walk}.c3d")), summary(dynamics)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    parser.add_argument("--out", type=Path, help="also write the tables here (Markdown)")
    args = parser.parse_args()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; valid: {', '.join(VARIANTS)}")
    torch.set_num_threads(1)
    lines = [f"# torchik's sagittal joint powers against Plug-in Gait's, {date.today()}", ""]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for variant in variants:
            rows, residuals = [], []
            for walk, static in WALKS:
                if not (DATA / f"{walk}.c3d").is_file():
                    print(f"skipped {walk}: {DATA / f'{walk}.c3d'} absent")
                    continue
                found, numbers = run(walk, static, variant, Path(tmp))
                rows += [(walk, a) for a in found]
                residuals.append((walk, numbers))
            sagittal = np.array([a.r_sagittal for _, a in rows])
            total = np.array([a.r_total for _, a in rows])
            lines += [f"## {variant}", "", "| walk | side | joint | frames | r sagittal | r total | rms diff / rms PiG |",
                      "|---|---|---|---:|---:|---:|---:|"]
            lines += [f"| {walk} | {a.side.lower()} | {a.joint.lower()} | {a.frames} | {a.r_sagittal:.3f} | "
                      f"{a.r_total:.3f} | {a.rms_difference:.2f} / {a.rms_plug_in_gait:.2f} |" for walk, a in rows]
            if rows:
                lines += ["", f"r sagittal: min {sagittal.min():.3f}, median {np.median(sagittal):.3f}; r total: min "
                          f"{total.min():.3f}, median {np.median(total):.3f} ({len(rows)} joints)", ""]
            lines += ["| walk | frames the plates carry every foot | residual force rms, max (% of weight) | "
                      "residual moment rms (N m/kg) |", "|---|---:|---:|---:|"]
            for walk, numbers in residuals:
                force = numbers["residual_force_per_weight"]["covered"]
                moment = numbers["residual_moment_n_m_per_kg"]["covered"]
                lines += [f"| {walk} | {numbers['covered_loaded_frames']} | {100 * force['rms']:.1f}, "
                          f"{100 * force['max']:.1f} | {moment['rms']:.3f} |"]
            lines += [""]
            print("\n".join(lines[-len(rows) - len(residuals) - 9:]), flush=True)
    lines += [f"({time.perf_counter() - start:.0f} s)"]
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

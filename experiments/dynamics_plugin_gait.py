"""torchik's sagittal joint powers against Plug-in Gait's own, on the shared Vicon walks.

    python experiments/dynamics_plugin_gait.py [--variants default,human48,...] [--opensim] [--out table.md]

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

With `--opensim` (OpenSim 4.6, the extra torchik[opensim]), the default variant's walks go through
OpenSim's inverse dynamics too, on an OpenSim model of the same Human66 (torchik/io/opensim_model.py:
the same bodies, masses and joint axes), with the same ground reactions on the same feet:

- **same inputs**: InverseDynamicsSolver given torchik's own coordinates, speeds (low-passed at 6 Hz)
  and accelerations: the largest and the rms difference of every joint's torque from torchik's, which
  measures the two implementations alone;
- **OpenSim's tool**: InverseDynamicsTool on the tracked joint angles alone, low-passed at 6 Hz by
  OpenSim (a Butterworth IIR both ways) and differentiated through its quintic splines, as an OpenSim
  user runs it: its sagittal powers (torque times the splines' rate) against Plug-in Gait's (the
  column `r OpenSim`), and the rms difference of its sagittal moments from torchik's (N m/kg).

The recordings are read where they lie (../shared/data/c3d); absent, their rows are skipped, saying so.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np
import torch

from torchik.io import map_recording, read
from torchik.io.subjects import subject_from_recording
from torchik.method.dynamics import low_pass
from torchik.method.kinematics import KinematicModel
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.dynamics import (
    JOINTS,
    SIDES,
    MotionDynamics,
    _about,
    _wrench_origins,
    link_origins,
    motion_dynamics,
    summary,
)
from torchik.pipelines.plug_in_gait import Agreement, agreement, plug_in_gait_kinetics

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


def run(walk: str, static_name: str, variant: str, folder: Path, opensim: bool = False) -> tuple[list, dict, dict]:
    """The agreement rows of one walk under one variant, the summary of its dynamics (the residual), and
    with `opensim` OpenSim's (`opensim_columns`; empty without)."""
    static = read(DATA / f"{static_name}.c3d")
    subject = subject_from_recording(static, map_name=MAP).subject
    model_name = "human48" if variant.startswith("human48") else "human66"
    model = load_model(model_name, subject)
    if variant == "human48-no-limits":
        model.lower, model.upper = torch.full_like(model.lower, -10.0), torch.full_like(model.upper, 10.0)
    link_map = full_calibration_map(folder) if variant == "full-calibration" else MAP
    recording, _ = map_recording(read(DATA / f"{walk}.c3d"), link_map, model, static)
    links = [link for link in TRACKED_LINKS[model_name] if link in recording.links]
    wrench_at = "model" if variant == "wrench-at-model" else "segment"
    wrench_cutoff = 6.0 if variant == "wrench-6hz" else None
    dynamics = motion_dynamics(model, recording, links, wrench_at=wrench_at, wrench_cutoff=wrench_cutoff)
    kinetics = plug_in_gait_kinetics(DATA / f"{walk}.c3d")
    found = agreement(dynamics, kinetics)
    extra = opensim_columns(model, recording, dynamics, kinetics, wrench_at, wrench_cutoff, folder / walk) if opensim else {}
    return found, summary(dynamics), extra


def opensim_columns(model: KinematicModel, recording, dynamics: MotionDynamics, kinetics, wrench_at: str,
                    wrench_cutoff: float | None, folder: Path) -> dict:
    """OpenSim's inverse dynamics of the walk (module docstring): `same_inputs` (max and rms of the joint
    torques' difference from torchik's, N m, over every joint and frame with known ground reactions),
    `tool` (the agreement rows of the tool's powers with Plug-in Gait's) and `moment_rms` (per side
    and joint, the rms difference of the tool's sagittal moment from torchik's over the stance, N m/kg)."""
    from torchik.io import opensim_model as om

    trajectory, links = dynamics.trajectory, dynamics.wrench_links
    time = trajectory.time.double().numpy()
    rate = 1.0 / float(np.mean(np.diff(time)))
    about = _wrench_origins(model, recording, trajectory, links, wrench_at)
    wrenches = _about(dynamics.wrenches, about, model, rate, wrench_cutoff)[:, 0].numpy()  # [T,L,6] about the links' origins
    folder.mkdir(parents=True, exist_ok=True)
    loads = om.external_loads(folder / "loads.xml", time, links, wrenches, link_origins(model, trajectory, links))
    names = om.coordinate_names(model)
    velocity = low_pass(trajectory.velocity[:, 0], rate, dynamics.notes["cutoff_hz"])
    acceleration = torch.gradient(velocity, spacing=1.0 / rate, dim=0)[0]
    motion = om.opensim_motion(trajectory.base_position[:, 0], trajectory.base_rotation[:, 0],
                               trajectory.joint_positions[:, 0], velocity, acceleration)
    solver = om.opensim_model(model)
    om.add_external_loads(solver, loads)
    forces = om.solve(solver, names, motion, time)
    known = np.isfinite(dynamics.joint_torques).all(-1)
    difference = forces[known, 6:] - dynamics.joint_torques[known]
    tool = om.inverse_dynamics_tool(om.opensim_model(model), names, time, motion.q, loads, folder / "tool",
                                    cutoff=dynamics.notes["cutoff_hz"])
    torques = np.where(known[:, None], tool.forces[:, 6:], np.nan)
    theirs = dataclasses.replace(dynamics, joint_torques=torques, joint_powers=torques * tool.speeds[:, 6:])
    moment_rms = {}
    for side in SIDES:
        foot = dynamics.foot(side)
        if foot is None:
            continue
        on = dynamics.stance[:, links.index(foot)] & known
        for joint in JOINTS:
            a, b = dynamics.sagittal(side, joint)[0][on], theirs.sagittal(side, joint)[0][on]
            moment_rms[(side, joint)] = float(np.sqrt(np.mean((a - b) ** 2)))
    worst = np.unravel_index(np.abs(difference).argmax(), difference.shape)
    return dict(same_inputs=dict(max=float(np.abs(difference).max()), rms=float(np.sqrt(np.mean(difference ** 2))),
                                 frames=int(known.sum()), worst=f"{model.joint_names[worst[1]]}, "
                                 f"{float(time[known][worst[0]]):.2f} s"),
                tool=agreement(theirs, kinetics), moment_rms=moment_rms)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    parser.add_argument("--out", type=Path, help="also write the tables here (Markdown)")
    parser.add_argument("--opensim", action="store_true", help="the default variant through OpenSim's inverse dynamics too")
    args = parser.parse_args()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; valid: {', '.join(VARIANTS)}")
    if args.opensim:
        from torchik.io.opensim_model import require_opensim

        require_opensim().Logger.setLevelString("warn")
    torch.set_num_threads(1)
    lines = [f"# torchik's sagittal joint powers against Plug-in Gait's, {date.today()}", ""]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for variant in variants:
            rows, residuals, opensim = [], [], {}
            for walk, static in WALKS:
                if not (DATA / f"{walk}.c3d").is_file():
                    print(f"skipped {walk}: {DATA / f'{walk}.c3d'} absent")
                    continue
                found, numbers, theirs = run(walk, static, variant, Path(tmp), args.opensim and variant == "default")
                rows += [(walk, a) for a in found]
                residuals.append((walk, numbers))
                if theirs:
                    opensim[walk] = theirs
            lines += table(variant, rows, residuals, opensim)
            print("\n".join(lines[-len(rows) - len(residuals) - 9 - (len(opensim) + 6 if opensim else 0):]), flush=True)
    lines += [f"({time.perf_counter() - start:.0f} s)"]
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")


def table(variant: str, rows: list[tuple[str, Agreement]], residuals: list[tuple[str, dict]], opensim: dict) -> list[str]:
    """A variant's Markdown: the agreement rows (with OpenSim's columns where it ran), their summary, the
    residuals, and OpenSim's agreement with torchik on the same inputs."""
    sagittal = np.array([a.r_sagittal for _, a in rows])
    total = np.array([a.r_total for _, a in rows])
    tool = {(walk, a.side, a.joint): a for walk, numbers in opensim.items() for a in numbers["tool"]}
    head = "| walk | side | joint | frames | r sagittal | r total | rms diff / rms PiG |"
    rule = "|---|---|---|---:|---:|---:|---:|"
    if opensim:
        head += " r OpenSim | moment rms torchik - OpenSim (N m/kg) |"
        rule += "---:|---:|"
    lines = [f"## {variant}", "", head, rule]
    for walk, a in rows:
        line = (f"| {walk} | {a.side.lower()} | {a.joint.lower()} | {a.frames} | {a.r_sagittal:.3f} | {a.r_total:.3f} | "
                f"{a.rms_difference:.2f} / {a.rms_plug_in_gait:.2f} |")
        if opensim:
            theirs = tool.get((walk, a.side, a.joint))
            moment = opensim.get(walk, {}).get("moment_rms", {}).get((a.side, a.joint))
            line += f" {theirs.r_sagittal:.3f} |" if theirs else " - |"
            line += f" {moment:.3f} |" if moment is not None else " - |"
        lines.append(line)
    if rows:
        lines += ["", f"r sagittal: min {sagittal.min():.3f}, median {np.median(sagittal):.3f}; r total: min "
                  f"{total.min():.3f}, median {np.median(total):.3f} ({len(rows)} joints)"]
        if tool:
            theirs_r = np.array([a.r_sagittal for a in tool.values()])
            lines += [f"r OpenSim: min {theirs_r.min():.3f}, median {np.median(theirs_r):.3f} ({len(tool)} joints)"]
        lines += [""]
    lines += ["| walk | frames the plates carry every foot | residual force rms, max (% of weight) | "
              "residual moment rms (N m/kg) |", "|---|---:|---:|---:|"]
    for walk, numbers in residuals:
        force = numbers["residual_force_per_weight"]["covered"]
        moment = numbers["residual_moment_n_m_per_kg"]["covered"]
        lines += [f"| {walk} | {numbers['covered_loaded_frames']} | {100 * force['rms']:.1f}, "
                  f"{100 * force['max']:.1f} | {moment['rms']:.3f} |"]
    lines += [""]
    if opensim:
        lines += ["OpenSim's InverseDynamicsSolver on torchik's own coordinates, speeds and accelerations, every joint's "
                  "torque against torchik's:", "", "| walk | frames | max abs diff (N m) | where | rms diff (N m) |",
                  "|---|---:|---:|---|---:|"]
        lines += [f"| {walk} | {n['same_inputs']['frames']} | {n['same_inputs']['max']:.2e} | "
                  f"{n['same_inputs']['worst']} | {n['same_inputs']['rms']:.2e} |" for walk, n in opensim.items()]
        lines += [""]
    return lines


if __name__ == "__main__":
    main()

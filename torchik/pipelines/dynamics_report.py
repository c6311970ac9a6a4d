"""What `torchik dynamics --report DIR` writes of a motion's forces (`MotionDynamics`):

    joint_torques.csv, joint_torques.sto   every joint's torque (N m), a column per joint; the .sto is
                                           OpenSim's inverse-dynamics table (columns <joint>_moment)
    joint_powers.csv, joint_powers.sto     every joint's power (W): torque times rate (<joint>_power)
    residual.csv                           the base's residual force per body weight (fx, fy, fz) and
                                           moment per kg (mx, my, mz, N m/kg, about the base's origin),
                                           and whether the plates carry every foot on the ground then
    ground_reactions.csv                   each foot's ground reaction as measured: force (N), moment
                                           about the world origin (N m), centre of pressure (m)
    sagittal.png                           hip, knee and ankle sagittal moments (N m/kg, extensor
                                           positive) and powers (W/kg) over each gait cycle whose
                                           stance is on a plate (over time without gait events), and
                                           Plug-in Gait's own where the file holds them
    residual.png                           the residual force and moment over time, the plates'
                                           stances shaded, the frames a foot stands off them greyed
    residual_loop.png                      with the loop on forces (`dynamics_loop.py`): the residual
                                           force over time before and after it, the frames fitted
                                           (the plates carry every foot) shaded
    summary.json, report.md                the numbers and the report

and, with `write_rrd`, a rerun recording of the tracked body with the ground reactions as arrows.
Every file is written beside its name and moved onto it when complete.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..io.files import replacing
from ..io.foot_contacts import runs
from ..io.opensim_table import write_table
from ..method.dynamics.inverse import GRAVITY
from ..method.kinematics import KinematicModel
from .dynamics import JOINTS, SIDES, MotionDynamics, gait_cycles, stance_phases, summary
from .plotting import figure, pyplot
from .plug_in_gait import Agreement, PlugInGaitKinetics

if TYPE_CHECKING:
    from .dynamics_loop import ClosedLoop

SIDE_COLORS = {"Right": "tab:green", "Left": "tab:red"}  # Vicon's: right green, left red
OUTPUTS = ("joint_torques.csv", "joint_torques.sto", "joint_powers.csv", "joint_powers.sto", "residual.csv",
           "ground_reactions.csv", "sagittal.png", "residual.png", "residual_loop.png", "summary.json", "report.md")


def write_report(dynamics: MotionDynamics, out: str | Path, model_name: str, subject: dict | None = None,
                 kinetics: dict[tuple[str, str], PlugInGaitKinetics] | None = None,
                 agreement: Sequence[Agreement] = (), loop: ClosedLoop | None = None) -> dict[str, Path]:
    """The files of the module docstring in folder `out` (made if missing); subject: where the body's
    numbers came from; kinetics, agreement: Plug-in Gait's own and how torchik's agree with them; loop:
    the loop on forces, whose `after` is `dynamics`. Returns the paths by file name."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    d, paths = dynamics, {}
    paths["joint_torques.csv"] = _csv(out / "joint_torques.csv", d.time, d.joint_names, d.joint_torques)
    paths["joint_powers.csv"] = _csv(out / "joint_powers.csv", d.time, d.joint_names, d.joint_powers)
    header = dict(version="1", inDegrees="no", DataType="double")
    paths["joint_torques.sto"] = write_table(out / "joint_torques.sto", d.time, [f"{j}_moment" for j in d.joint_names],
                                             d.joint_torques, header, name="Inverse Dynamics Generalized Forces")
    paths["joint_powers.sto"] = write_table(out / "joint_powers.sto", d.time, [f"{j}_power" for j in d.joint_names],
                                            d.joint_powers, header, name="Joint Powers")
    paths["residual.csv"] = _csv(out / "residual.csv", d.time, ("fx_per_weight", "fy_per_weight", "fz_per_weight",
                                                                 "mx_n_m_per_kg", "my_n_m_per_kg", "mz_n_m_per_kg",
                                                                 "plates_carry_every_foot"),
                                 np.column_stack((d.residual_force(), d.residual_moment(), d.covered)))
    cop = d.cop()
    names = [f"{link}_{q}" for link in d.wrench_links
             for q in ("fx", "fy", "fz", "mx", "my", "mz", "cop_x", "cop_y", "cop_z")]
    values = np.concatenate((d.wrenches, cop), -1).reshape(len(d.time), -1)
    paths["ground_reactions.csv"] = _csv(out / "ground_reactions.csv", d.time, names, values)
    human = all(f"j{side}{joint}_roty" in d.joint_names for side in SIDES for joint in JOINTS)
    if human:
        paths["sagittal.png"] = sagittal_figure(d, out / "sagittal.png", kinetics or {})
    paths["residual.png"] = residual_figure(d, out / "residual.png")
    if loop is not None:
        paths["residual_loop.png"] = loop_figure(loop, out / "residual_loop.png")
    numbers = dict(summary(d), model=model_name, subject=subject, tracking=_tracking(d.tracking), notes=d.notes,
                   plug_in_gait=[a.to_json() for a in agreement], loop=None if loop is None else loop.to_json())
    with replacing(out / "summary.json") as part:
        Path(part).write_text(json.dumps(numbers, indent=2, default=_plain) + "\n")
    paths["summary.json"] = out / "summary.json"
    with replacing(out / "report.md") as part:
        Path(part).write_text(markdown(d, numbers, model_name, subject, agreement, human, loop))
    paths["report.md"] = out / "report.md"
    return paths


def _plain(x):
    """JSON for numpy scalars and arrays."""
    return x.tolist() if isinstance(x, np.ndarray) else float(x) if isinstance(x, np.floating) else int(x)


def _csv(path: Path, time: np.ndarray, names: Sequence[str], values: np.ndarray) -> Path:
    """A comma-separated table: a header line (time, names), then a row per sample (nan where unknown)."""
    with replacing(path) as part:
        np.savetxt(part, np.column_stack((time, values)), delimiter=",", fmt="%.9g", header=",".join(("time", *names)),
                   comments="")
    return path


def _tracking(report: dict) -> dict:
    """What a dynamics report says of the tracking: its error and failures."""
    keys = ("frames", "mnte", "angular_velocity_rmse", "failed_steps", "dropped_targets", "qp_fallbacks")
    return {k: report.get(k) for k in keys}


def _cycle_axis(d: MotionDynamics) -> dict[str, list[tuple[int, int]]] | None:
    """Each side's gait cycles on a plate, or None when a side stands on a plate outside any (plot over time)."""
    cycles = {side: gait_cycles(d, side) for side in SIDES}
    for side in SIDES:
        foot = d.foot(side)
        if foot is not None and d.stance[:, d.wrench_links.index(foot)].any() and not cycles[side]:
            return None
    return cycles if any(cycles.values()) else None


def sagittal_figure(d: MotionDynamics, path: Path, kinetics: dict[tuple[str, str], PlugInGaitKinetics]) -> Path:
    """Hip, knee and ankle sagittal moments and powers per kg (module docstring)."""
    plt = pyplot()
    cycles = _cycle_axis(d)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    for column, joint in enumerate(JOINTS):
        for side in SIDES:
            moment, power = d.sagittal(side, joint)
            pig = kinetics.get((side, joint))
            pig = None if pig is None else pig.per_kg_of(d.mass)  # per kg of the model's mass, as torchik's
            spans = cycles[side] if cycles is not None else [(0, len(d.time))]
            for k, (a, b) in enumerate(spans):
                x = 100.0 * (d.time[a:b] - d.time[a]) / (d.time[b] - d.time[a]) if cycles is not None else d.time[a:b]
                label = f"{side.lower()}" if k == 0 else None
                for row, series, theirs in ((0, moment, None if pig is None else pig.moment),
                                            (1, power, None if pig is None else pig.sagittal_power)):
                    axes[row, column].plot(x, series[a:b], color=SIDE_COLORS[side], lw=1.2, label=label)
                    if theirs is not None:
                        axes[row, column].plot(x, theirs[a:b], color=SIDE_COLORS[side], lw=1.0, ls="--",
                                               label=f"{side.lower()}, Plug-in Gait" if k == 0 else None)
                if cycles is not None:  # the plate stance's end, the foot off
                    on = d.stance[a:b, d.wrench_links.index(d.foot(side) or "")]
                    off = np.flatnonzero(on)
                    if off.size:
                        for ax in axes[:, column]:
                            ax.axvline(x[min(off[-1] + 1, len(x) - 1)], color=SIDE_COLORS[side], lw=0.6, ls=":")
        axes[0, column].set_title({"Hip": "hip", "Knee": "knee", "Ankle": "ankle"}[joint])
    if cycles is None:
        for link, a, b in stance_phases(d):
            side = next((s for s in SIDES if link.startswith(s)), "")
            for ax in axes.ravel():
                ax.axvspan(d.time[a], d.time[min(b, len(d.time) - 1)], color=SIDE_COLORS.get(side, "grey"),
                           alpha=0.12, lw=0)
    axes[0, 0].set_ylabel("moment (N m/kg)\nextensor, plantarflexor +")
    axes[1, 0].set_ylabel("power (W/kg)\ngenerated +")
    for ax in axes[1]:
        ax.set_xlabel("gait cycle (%), from the foot strike; dotted: foot off" if cycles is not None else
                      "time (s); shaded: a foot on a plate")
    for ax in axes.ravel():
        ax.axhline(0.0, color="black", lw=0.5)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("sagittal plane: torchik (solid)" + (", Plug-in Gait (dashed)" if kinetics else ""))
    fig.tight_layout()
    with replacing(path) as part:
        fig.savefig(part, dpi=90, format="png")
    plt.close(fig)
    return path


def residual_figure(d: MotionDynamics, path: Path) -> Path:
    """The base's residual force per weight and moment per kg over time (module docstring)."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    t = d.time
    for ax, values, unit in ((axes[0], d.residual_force(), "force / body weight"),
                             (axes[1], d.residual_moment(), "moment (N m/kg)")):
        for k, axis in enumerate("xyz"):
            ax.plot(t, values[:, k], lw=0.9, label=axis)
        ax.plot(t, np.linalg.norm(values, axis=-1), color="black", lw=1.2, label="norm")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        for link, a, b in stance_phases(d):
            side = next((s for s in SIDES if link.startswith(s)), "")
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color=SIDE_COLORS.get(side, "tab:blue"), alpha=0.15, lw=0)
        for a, b in runs(~d.covered):
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color="grey", alpha=0.25, lw=0)
    axes[0].legend(fontsize=8, ncol=4, loc="upper right")
    axes[0].set_title("base residual: stance on a plate shaded (right green, left red); grey: a foot on the ground "
                      "off the plates", fontsize=9)
    axes[1].set_xlabel("time (s)")
    fig.tight_layout()
    with replacing(path) as part:
        fig.savefig(part, dpi=90, format="png")
    plt.close(fig)
    return path


def loop_figure(loop: ClosedLoop, path: Path, title: str = "") -> Path:
    """The residual force (per body weight given; the plates low-passed as the motion is) over time
    before and after the loop on forces, the frames fitted and compared shaded; `title` above it
    (default: the residuals' rms)."""
    fig = figure((10, 3.2))
    ax = fig.add_subplot(1, 1, 1)
    t, weight = loop.before.time, loop.mass * float(np.linalg.norm(GRAVITY))
    for start, stop in runs(loop.frames):
        ax.axvspan(t[start], t[min(stop, len(t) - 1)], color="tab:blue", alpha=0.12, lw=0)
    for wrench, color, label in ((loop.wrench_before, "grey", "before"), (loop.wrench_after, "black", "after")):
        ax.plot(t, np.linalg.norm(wrench[:, :3], axis=-1) / weight, color=color, lw=1.1, label=label)
    ax.axhline(0.1, color="tab:red", lw=0.7, ls=":", label="10 % of body weight")
    b, a = loop.residual(loop.wrench_before), loop.residual(loop.wrench_after)
    top = max(b.force_max, a.force_max, 0.1)
    if math.isfinite(top):  # off the shaded frames a foot's reaction no plate saw: up to the whole weight
        ax.set_ylim(0.0, 1.3 * top)
    ax.set_title(title or f"base residual force: rms over the shaded frames {100 * b.force_rms:.1f} -> "
                          f"{100 * a.force_rms:.1f} % of body weight; shaded: the plates carry every foot", fontsize=9)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force / body weight")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    with replacing(path) as part:
        fig.savefig(part, dpi=80, format="png")
    return path


def _loop_markdown(loop: ClosedLoop) -> list[str]:
    """report.md's section on the loop on forces."""
    b, a = loop.residual(loop.wrench_before), loop.residual(loop.wrench_after)
    lines = ["## The loop on forces", "",
             f"What the base's residual says the model or the plates lack (`dynamics_fit.py`: segment masses, the "
             f"trunk's centre of mass, each plate's centre of pressure, the plates' lag; fitted on one half of the "
             f"{int(loop.frames.sum())} frames where the plates carry every foot and scored on the other), applied, and "
             f"the forces computed again. Residual over those frames, in the body weight and mass given "
             f"({loop.mass:.1f} kg):", "",
             "| | force rms (% of weight) | force max | moment rms (N m/kg) | moment max |", "|---|---:|---:|---:|---:|",
             f"| before | {100 * b.force_rms:.1f} | {100 * b.force_max:.1f} | {b.moment_rms:.3f} | {b.moment_max:.3f} |",
             f"| after | {100 * a.force_rms:.1f} | {100 * a.force_max:.1f} | {a.moment_rms:.3f} | {a.moment_max:.3f} |", ""]
    if loop.fit is None:
        return lines + [f"Not fitted: {loop.reason}.", ""]
    if loop.fit.effects:
        lines += ["Kept (each significant on held-out halves, the halves agreeing, its size plausible); the joint "
                  "torques and powers of this report are computed with them:", "",
                  "| effect | value | held-out score | residual when added (fitted frames, plates low-passed as the "
                  "motion) |", "|---|---|---:|---|"]
        for e in loop.fit.effects:
            value = ", ".join(f"{v:+.4g} {u}" for v, u in zip(e.value, e.labels))
            if e.relative is not None:
                value += f" ({100 * e.relative:+.1f} %)"
            lines += [f"| {e.name} | {value} | {e.score:.0f} | {100 * e.before.force:.1f} -> {100 * e.after.force:.1f} "
                      f"% of weight |"]
    else:
        lines += ["Nothing kept: no effect explains the residual significantly on held-out frames."]
    if loop.fit.refused:
        lines += ["", "Refused (significant, but implausible or unstable):", ""]
        lines += [f"- {r.name} ({', '.join(f'{v:+.4g}' for v in r.value)}): {r.reason}" for r in loop.fit.refused]
    return lines + ["", "![residual before and after the loop](residual_loop.png)", ""]


def _num(x, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def markdown(d: MotionDynamics, numbers: dict, model_name: str, subject: dict | None,
             agreement: Sequence[Agreement], human: bool, loop: ClosedLoop | None = None) -> str:
    """report.md: the subject, the tracking, the ground reactions, the residual, the sagittal peaks, the
    agreement with Plug-in Gait, the files and the conventions."""
    notes, lines = d.notes, []
    lines += [f"# Dynamics of {notes.get('source')}", ""]
    who = f"{d.mass:.2f} kg"
    if subject:
        who += (f", {subject.get('height_m', float('nan')):.3f} m, from {subject.get('source')} "
                f"(mass: {subject.get('mass_from')})")
    lines += [f"Model {model_name} ({who}); " + (f"the recording mapped by {notes['link_map']!r}; " if notes.get("link_map")
                                                  else "") + f"{len(d.time)} frames, {d.time[-1] - d.time[0]:.2f} s.", ""]
    m = numbers["tracking"].get("mnte") or {}
    lines += [f"Tracking: MNTE median {_num(m.get('median'))}, max {_num(m.get('max'))}; failed steps "
              f"{numbers['tracking'].get('failed_steps')}.", ""]
    if notes.get("at_limits"):
        held = ", ".join(f"{name} {frames}" for name, frames in notes["at_limits"].items())
        lines += [f"Joints held at a limit (frames): {held}. The motion goes beyond the model's range there: the "
                  "tracker bends the neighbouring joints and the pelvis to follow, which changes their torques and "
                  "powers (Human66 has no limits).", ""]
    lines += ["## Ground reactions", ""]
    if not d.wrench_links:
        lines += ["None: computed without the plates, the base's residual is the whole ground reaction.", ""]
    else:
        how = ("about the recording's own origin of the segment (the markers' joint centre), put on the model's link"
               if notes.get("wrench_at") == "segment" else "about the model's link origin")
        lines += [f"On {', '.join(d.wrench_links)}, moments {how}; "
                  + (f"low-passed at {notes['wrench_cutoff_hz']:g} Hz." if notes.get("wrench_cutoff_hz")
                     else "as the plates give them at the frames (not low-passed further)."), ""]
        lines += ["| link | stance on a plate (frames) | time (s) |", "|---|---|---|"]
        lines += [f"| {link} | {a}-{b - 1} | {d.time[a]:.2f}-{d.time[b - 1]:.2f} |" for link, a, b in stance_phases(d)]
        plates = notes.get("plates") or {}
        lost = [c for c in plates.get("contacts", []) if c.get("link") is None]
        if lost:
            lines += ["", f"{len(lost)} contact(s) given to no foot (a plate loaded by no foot, or by two): "
                      + "; ".join(f"plate {c['plate']} frames {c['start_frame']}-{c['stop_frame'] - 1}"
                                  + (f" shared by {', '.join(c['shared'])}" if c.get("shared") else "") for c in lost)]
        lines += [""]
    lines += ["## Residual", ""]
    if loop is not None and loop.fit is not None and loop.fit.effects:
        lines += ["With the corrections the loop on forces kept (its section below gives the residual before them).", ""]
    f, mo = numbers["residual_force_per_weight"], numbers["residual_moment_n_m_per_kg"]
    if f["covered"]:
        lines += [f"Over the {numbers['covered_loaded_frames']} frames where the plates carry every foot on the ground: "
                  f"force rms {100 * f['covered']['rms']:.1f} % of body weight (max {100 * f['covered']['max']:.1f} %), "
                  f"moment rms {mo['covered']['rms']:.3f} N m/kg (max {mo['covered']['max']:.3f}).", ""]
    else:
        lines += ["No frame has the plates carrying every foot on the ground: the residual carries ground reactions "
                  "no plate measured.", ""]
    if f["all"]:
        lines += [f"Over all frames: force rms {100 * f['all']['rms']:.1f} % of body weight, moment rms "
                  f"{mo['all']['rms']:.3f} N m/kg (frames with a foot off the plates included).", ""]
    if numbers["unknown_frames"]:
        lines += [f"{numbers['unknown_frames']} frames have an unknown residual (a plate two feet stood on).", ""]
    lines += ["![residual](residual.png)", ""]
    if loop is not None:
        lines += _loop_markdown(loop)
    if human:
        lines += ["## Sagittal plane", "", "Peaks over each side's stance on a plate (moment N m/kg, extensor or "
                  "plantarflexor positive; power W/kg, generated positive):", "",
                  "| joint | moment max | moment min | power max | power min |", "|---|---:|---:|---:|---:|"]
        lines += [f"| {name} | {p['moment_max_n_m_per_kg']:.2f} | {p['moment_min_n_m_per_kg']:.2f} | "
                  f"{p['power_max_w_per_kg']:.2f} | {p['power_min_w_per_kg']:.2f} |"
                  for name, p in numbers["sagittal_in_stance"].items()]
        lines += ["", "![sagittal](sagittal.png)", ""]
    if agreement:
        lines += ["## Against Plug-in Gait's own outputs in the file", "",
                  "Pearson's r over the frames the foot stands on a plate: torchik's sagittal power (the flexion "
                  "axis' torque times its rate) against Plug-in Gait's sagittal term (its flexion moment times the "
                  "distal segment's relative angular velocity about its lateral axis), and the joints' total powers "
                  "(torchik's over every degree of freedom, Plug-in Gait's `<S><J>Power` z, W/kg).", "",
                  "| side | joint | frames | r sagittal | r total | rms difference (W/kg) | rms Plug-in Gait (W/kg) |",
                  "|---|---|---:|---:|---:|---:|---:|"]
        lines += [f"| {a.side.lower()} | {a.joint.lower()} | {a.frames} | {a.r_sagittal:.3f} | {a.r_total:.3f} | "
                  f"{a.rms_difference:.3f} | {a.rms_plug_in_gait:.3f} |" for a in agreement]
        lines += [""]
    lines += ["## Files", "",
              "`joint_torques.csv`/`.sto` (N m), `joint_powers.csv`/`.sto` (W), `residual.csv` (force per body "
              "weight, moment N m/kg about the base's origin, world axes), `ground_reactions.csv` (force N, moment "
              "N m about the world origin, centre of pressure m), `summary.json`.", "",
              f"Conventions: docs/dynamics.md. Accelerations from the tracked velocity low-passed at "
              f"{notes.get('cutoff_hz', float('nan')):g} Hz (zero phase); a joint's torque is its parent's on its "
              f"child about its axis; power = torque x rate.", ""]
    return "\n".join(lines)


def write_rrd(dynamics: MotionDynamics, model: KinematicModel, links: Sequence[str], path: str | Path,
              urdf: str | Path | None = None) -> Path:
    """A rerun recording of the tracked body (`RrdWriter`'s entities) with, under /subject/0/dynamics:
    each foot's ground reaction as an arrow from its centre of pressure (1 m per body weight), the
    residual force per weight and moment per kg, and the sagittal moments and powers per kg."""
    import rerun as rr

    from .rrd import RrdWriter

    d = dynamics
    with RrdWriter(path, model, links, urdf=urdf) as writer:
        writer.write(d.trajectory)
        assert writer.logger is not None
        rec = writer.logger.rec
        time = rr.TimeColumn("time", duration=d.time)
        cop = d.cop()
        for k, link in enumerate(d.wrench_links):
            on = np.isfinite(cop[:, k]).all(-1)
            side = next((s for s in SIDES if link.startswith(s)), "")
            entity = f"/subject/0/dynamics/ground_reaction/{rr.escape_entity_path_part(link)}"
            rec.log(entity, rr.Arrows3D.from_fields(colors=[_rgb(SIDE_COLORS.get(side, "tab:blue"))], radii=[0.008]),
                    static=True)
            rec.send_columns(entity, [time], rr.Arrows3D.columns(
                origins=cop[on, k], vectors=d.wrenches[on, k, :3] / d.weight).partition(on.astype(np.int64)))
        writer.log_series("dynamics/residual_force_per_weight", d.time, d.residual_force(), ["x", "y", "z"])
        writer.log_series("dynamics/residual_moment_per_kg", d.time, d.residual_moment(), ["x", "y", "z"])
        if all(f"j{side}{joint}_roty" in d.joint_names for side in SIDES for joint in JOINTS):
            for joint in JOINTS:
                for what, k in (("moment", 0), ("power", 1)):
                    values = np.stack([d.sagittal(side, joint)[k] for side in SIDES], -1)
                    writer.log_series(f"dynamics/{joint.lower()}_{what}_per_kg", d.time, values,
                                      [side.lower() for side in SIDES])
        return writer.commit()


def _rgb(name: str) -> tuple[int, int, int]:
    """A matplotlib colour name as 0-255 RGB, for rerun."""
    from matplotlib.colors import to_rgb

    r, g, b = to_rgb(name)
    return round(255 * r), round(255 * g), round(255 * b)

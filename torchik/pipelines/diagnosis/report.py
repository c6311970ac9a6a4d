"""The diagnosis written out: a markdown report with figures, a calibration file, the augmented URDF
and a rerun recording of the residuals before and after.

    DIR/report.md          what was found, its parameters with standard errors, errors before and
                           after each effect, per link and overall, and where the residual sits
    DIR/errors.png         MNTE and angular-velocity RMSE per link, before and after
    DIR/residual.png       the orientation residual's angle over time on the links that carried most
    DIR/calibration.json   the measurement effects (calibration.py; `torchik track --sensor-calibration`)
    DIR/model.urdf         the URDF with the model effects added (only when there are some;
                           `torchik track --urdf`)
    DIR/residuals.rrd      rerun: residual angle and gyro disagreement per link, before and after
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from ...errors import optional
from ..plotting import figure, plain_log_labels
from .analysis import Analysis
from .effect import SIGNIFICANT
from .loop import Diagnosis


def _angle(analysis: Analysis, b: int) -> np.ndarray:
    """[T,L] the orientation residual's angle in degrees (NaN where a sample is missing)."""
    angle = torch.asin(analysis.r[:, b].norm(dim=-1).clamp(max=1.0)) * 180 / math.pi
    return torch.where(analysis.valid[:, b], angle, torch.nan).numpy()


def errors_figure(d: Diagnosis, path: Path, title: str = "") -> Path:
    before, after = d.before, d.after
    x = np.arange(len(d.links))
    fig = figure((10, 5.5))
    axes = fig.subplots(2, 1, sharex=True)
    for ax, name, label in ((axes[0], "mnte", "MNTE (1 - cos)"), (axes[1], "rmse", "angular velocity RMSE (rad/s)")):
        ax.bar(x - 0.2, getattr(before, name), 0.4, label="before", color="tab:red")
        ax.bar(x + 0.2, getattr(after, name), 0.4, label="after", color="tab:blue")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        plain_log_labels(ax)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend()
    axes[0].set_title(title or "tracking error per link, before and after the effects found")
    axes[1].set_xticks(x, d.links, rotation=60, ha="right", fontsize=8)
    # fixed margins for the rotated link names: tight_layout measures every label, a second's work
    fig.subplots_adjust(left=0.09, right=0.99, top=0.94, bottom=0.2, hspace=0.08)
    fig.savefig(path, dpi=90)
    return path


def residual_figure(d: Diagnosis, path: Path, top: int = 4, title: str = "") -> Path:
    (a0, b0), (a1, b1) = d.first, d.last
    before, after = _angle(a0, b0), _angle(a1, b1)
    order = np.argsort(-np.nan_to_num(np.nanmean(before, 0)))[:top]
    height = 1.8 * len(order) + 0.6
    fig = figure((10, height))
    axes = fig.subplots(len(order), 1, sharex=True, squeeze=False)
    t = a0.time.numpy()
    for ax, i in zip(axes[:, 0], order):
        ax.plot(t, before[:, i], color="tab:red", lw=0.8, label="before")
        ax.plot(t, after[:, i], color="tab:blue", lw=0.8, label="after")
        ax.set_ylabel(f"{d.links[i]}\n(deg)", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_title(title or "orientation residual on the links that carried most")
    axes[-1, 0].set_xlabel("time (s)")
    fig.subplots_adjust(left=0.08, right=0.99, top=1 - 0.35 / height, bottom=0.5 / height, hspace=0.1)
    fig.savefig(path, dpi=90)
    return path


def _fmt(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "-"


def markdown(d: Diagnosis, source: str, model_name: str, figures: dict[str, str]) -> str:
    before, after = d.before.overall, d.after.overall
    lines = [f"# Diagnosis of {source}", "", *answer(d), "", f"Model: {model_name}; {len(d.links)} tracked links; "
             f"{len(d.original.time)} frames at {d.original.frame_rate:.1f} Hz.", ""]
    if d.effects:
        lines += ["## Effects found (in the order added)", "",
                  "| # | effect | parameters (± standard error) | score | MNTE before → after "
                  "| RMSE before → after (rad/s) |",
                  "|---|---|---|---|---|---|"]
        for k, step in enumerate(d.steps, 1):
            e = step.effect
            params = "; ".join(f"{name} = {_json(v)} ± {_json(e.stderr.get(name, e.stderr.get(name + '_rad')))}"
                               for name, v in e.params.items() if name not in ("identified", "first_joint", "t0"))
            lines.append(f"| {k} | {e.summary()} | {params} | {e.score:.0f} | {_fmt(step.before.overall['mnte'])} → "
                         f"{_fmt(step.after.overall['mnte'])} | {_fmt(step.before.overall['rmse'])} → "
                         f"{_fmt(step.after.overall['rmse'])} |")
        lines += ["", f"Parameters and standard errors: {fit_source(d)}."]
        notes = [f"- {e.kind} at {e.target}: {e.notes}" for e in d.effects if e.notes]
        if notes:
            lines += ["", "Notes:", *notes]
    else:
        lines += ["## No effect found", "", "No candidate explains the residual significantly better than noise."]
    lines += ["", "## Errors", "", "| | MNTE | angular velocity RMSE (rad/s) | base velocity RMSE (m/s) |",
              "|---|---|---|---|",
              f"| before | {_fmt(before['mnte'])} | {_fmt(before['rmse'])} | {_fmt(before['base_velocity_rmse'])} |",
              f"| after | {_fmt(after['mnte'])} | {_fmt(after['rmse'])} | {_fmt(after['base_velocity_rmse'])} |", ""]
    lines += ["Per link (before → after):", "", "| link | MNTE | RMSE (rad/s) |", "|---|---|---|"]
    for i, link in enumerate(d.links):
        lines.append(f"| {link} | {_fmt(d.before.mnte[i])} → {_fmt(d.after.mnte[i])} | "
                     f"{_fmt(d.before.rmse[i])} → {_fmt(d.after.rmse[i])} |")
    implausible = [e for e in d.rejected if "implausible:" in e.notes]
    if implausible:
        lines += ["", "## Refused as implausible: a sign of another error", ""]
        lines += [f"- {e.summary()} (score {e.score:.0f}): {e.notes}" for e in implausible]
    echoes = [e for e in d.rejected if "echo of" in e.notes]
    if echoes:
        lines += ["", "## Dropped as echoes (kept once, then explained by a later effect)", ""]
        lines += [f"- {e.summary()} (score {e.score:.0f} when added): {e.notes}" for e in echoes]
    if d.negligible:
        lines += ["", "## Significant but negligible (below the size that matters; not added)", "",
                  "Each family has a floor below which an effect changes nothing a researcher reports (a misalignment "
                  "of 1 deg, a gyro bias of 0.2 deg/s, a scale error of 0.5 %, a drift of 0.05 deg/s, a delay of one "
                  "sample; the code says why each); these are real to the data and under it.", ""]
        lines += [f"- {e.summary()} (score {e.score:.0f}): {e.notes.rsplit('significant but negligible: ', 1)[-1]}"
                  for e in d.negligible]
    reverted = [e for e in d.rejected if "implausible:" not in e.notes and "echo of" not in e.notes]
    if reverted:
        lines += ["", "## Significant but not kept", ""]
        lines += [f"- {e.kind} at {e.target} (score {e.score:.0f}): {e.notes}" for e in reverted]
    lines += ["", "## What remains", ""]
    lines.append(f"Why the loop stopped: {d.why_stopped}.")
    if not d.complete:
        rounds = len(d.steps) + sum("reverted" in e.notes for e in d.rejected)
        lines.append(f"It stopped at its limit of effects ({rounds} rounds): run it again with more (--max-effects) "
                     f"to go on.")
    elif d.best_rejected is not None:
        lines.append(f"The best candidate left, {d.best_rejected.summary()}, scores {d.best_rejected.score:.1f} "
                     f"(significant above {SIGNIFICANT:g}, calibrated on its test stretches' scatter"
                     f"{'' if not d.best_rejected.notes else '; ' + d.best_rejected.notes}).")
    if d.noise is not None:
        lines.append(f"What a correct model leaves, estimated on the data: {math.degrees(d.noise.axis_rms):.2f} deg rms "
                     f"along an axis the joints do not follow; a link's residual power at the noise is "
                     f"{d.noise.noise_power:.3g} (median over the links), which accounts for "
                     f"{100 * d.noise.share:.0f} % of the residual left.")
    if d.unobservable:
        lines += ["", "Not identifiable from these data (no fit was possible):", ""]
        groups: dict[tuple[str, str], list[str]] = {}
        for e in d.unobservable:
            groups.setdefault((e.kind, e.notes), []).append(e.target)
        lines += [f"- {kind} at {', '.join(targets)}: {notes}" for (kind, notes), targets in groups.items()]
    hidden = [(link, dirs) for link, dirs in d.unseen.items() if dirs]
    if hidden:
        lines += ["", "Turns of a sensor on its link that the data cannot see (the joints follow them: a sensor turned "
                      "so leaves no residual, and no diagnosis can find it):", ""]
        lines += [f"- {link}: about " + " and ".join(_json(v, 2) for v in dirs) + " in the link frame"
                  + (" (every direction)" if len(dirs) == 3 else "") for link, dirs in hidden]
    pairs = sorted({tuple(sorted((link, c["neighbour"]))) for link, found in d.confounded.items() for c in found})
    if pairs:
        lines += ["", "Turns of two neighbouring sensors that the data tell apart only poorly (they leave nearly the "
                      "same residual: the data see the two sensors' difference, not which one turned; a finding on "
                      "one may be the other's):", ""]
        for a, b in pairs:
            c = next(c for c in d.confounded.get(a, []) if c["neighbour"] == b)
            lines.append(f"- {a} about {_json(c['direction'], 2)} and {b} about {_json(c['neighbour_direction'], 2)}")
    lines += ["", "Where the residual sits (largest first):", "",
              "| link | rms (deg) | mean in link frame (deg) | dominant axis (link) | share | corr. with ω | corr. with α "
              "| corr. with a joint angle | band (Hz) | gyro vs orientation (rad/s) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for row in d.remaining[:8]:
        lines.append(f"| {row['link']} | {row['rms_deg']:.2f} | {_json(row['mean_link_deg'], 2)} | "
                     f"{_json(row['dominant_axis'], 2)} | {row['dominant_share']:.2f} | {row['corr_omega']:.2f} | "
                     f"{row['corr_alpha']:.2f} | {row['corr_joint']:.2f} ({row['joint'] or '-'}) | "
                     f"{row['band_hz'][0]:g}–{row['band_hz'][1]:g} | {row['gyro_rms']:.3f} |")
    if d.limits:
        at_limit = (f"{j['joint']} ({j['side']}, {100 * j['fraction']:.0f} % of the time)" for j in d.limits)
        lines += ["", "Joints at a limit: " + ", ".join(at_limit)]
    lines += [""] + [f"![{name}]({path})" for name, path in figures.items()] + [""]
    return "\n".join(lines)


def fit_source(d: Diagnosis) -> str:
    """Where the kept effects' values and standard errors come from: the joint fit at the end
    (jointfit.py; and whether its step was taken), or each effect's own fit with the others in place."""
    if d.joint is not None:
        return d.joint.note
    measured = [e for e in d.effects if not e.model_effect]
    why = "no measurement effect was kept" if not measured else "no two kept measurement effects share a residual"
    return f"each effect's own fit with the others in place (no joint fit: {why})"


def answer(d: Diagnosis) -> list[str]:
    """The report's first lines: the effects kept, each with its evidence in one sentence; what was
    refused as implausible and the error it points to; why the loop stopped."""
    if d.steps:
        lines = ["**Found:**", ""]
        for step in d.steps:
            e = step.effect
            share = "" if e.fit is None else f", explaining {100 * e.fit.explained:.0f} % of its channel's held-out residual"
            lines.append(f"- {e.summary()}: held-out score {e.score:.0f}{share}; MNTE "
                         f"{_fmt(step.before.overall['mnte'])} → {_fmt(step.after.overall['mnte'])}.")
            for c in e.params.get("confounds", []):  # what the data cannot attribute: said where the finding is
                lines.append(f"  - the data tell its turn about {_json(c['direction'], 2)} from the {c['neighbour']} "
                             f"sensor's about {_json(c['neighbour_direction'], 2)} only poorly: they see the two "
                             f"sensors' difference, not which one turned")
        lines += ["", f"Values and standard errors: {fit_source(d)}."]
    else:
        lines = ["**Found: nothing** the data tell from the noise."]
    if d.negligible:
        lines += ["", f"Also significant but below the size that matters, and not added: {len(d.negligible)} "
                      f"(listed under \"Significant but negligible\")."]
    refused = [e for e in d.rejected if "implausible:" in e.notes]
    if refused:
        lines += ["", "**Refused as implausible** (not adopted; each points to another error):", ""]
        lines += [f"- {e.summary()}: {e.notes.split('implausible: ', 1)[1]}" for e in refused]
    echoes = [e for e in d.rejected if "echo of" in e.notes]
    if echoes:
        lines += ["", "**Rejected as echoes** (kept once, then no longer significant with a later effect in place):",
                  ""]
        lines += [f"- {e.summary()}: rejected as an {e.notes.split('dropped as an ', 1)[1]}" for e in echoes]
    return lines + ["", f"**Why the loop stopped:** {d.why_stopped}."]


def _json(value, digits: int = 4) -> str:
    if value is None:
        return "-"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_json(v, digits) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def write_rrd(d: Diagnosis, path: Path) -> Path:
    """The residual angle (deg) and the gyro's disagreement |e| (rad/s) per link, before and after."""
    import uuid

    rr = optional("rerun", "viz", "the diagnosis' rerun recording (or --no-rrd)")
    rec = rr.RecordingStream("torchik-diagnosis", recording_id=uuid.uuid4())
    rec.save(str(path))
    for when, (analysis, b) in (("before", d.first), ("after", d.last)):
        time = rr.TimeColumn("time", duration=analysis.time.numpy())
        angle = _angle(analysis, b)
        gyro = analysis.e[:, b].norm(dim=-1).numpy()
        for i, link in enumerate(d.links):
            rec.send_columns(f"residual/orientation_deg/{link}/{when}", [time], rr.Scalars.columns(scalars=angle[:, i]))
            rec.send_columns(f"residual/gyro_rad_s/{link}/{when}", [time], rr.Scalars.columns(scalars=gyro[:, i]))
    rec.flush()
    return path


def write(d: Diagnosis, out: str | Path, source: str, model_name: str, rrd: bool = True) -> dict[str, Path]:
    """Write the report of module docstring into `out` (made if missing). Returns the paths written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = dict(errors=errors_figure(d, out / "errors.png"), residual=residual_figure(d, out / "residual.png"))
    calibration = out / "calibration.json"
    calibration.write_text(json.dumps(dict(d.calibration(), source=source, model=model_name), indent=2) + "\n")
    paths["calibration"] = calibration
    if any(e.model_effect for e in d.effects):
        paths["urdf"] = out / "model.urdf"
        paths["urdf"].write_text(d.urdf)
    if rrd:
        paths["rrd"] = write_rrd(d, out / "residuals.rrd")
    summary = dict(source=source, model=model_name, effects=[e.to_json() for e in d.effects],
                   steps=[dict(effect=s.effect.kind, target=s.effect.target, before=s.before.overall, after=s.after.overall)
                          for s in d.steps],
                   before=d.before.to_json(), after=d.after.to_json(),
                   best_rejected=None if d.best_rejected is None else d.best_rejected.to_json(),
                   rejected=[e.to_json() for e in d.rejected], unobservable=[e.to_json() for e in d.unobservable],
                   negligible=[e.to_json() for e in d.negligible], unseen=d.unseen, confounded=d.confounded,
                   joint_fit=None if d.joint is None else d.joint.to_json(), fit_source=fit_source(d),
                   remaining=d.remaining, limits=d.limits, complete=d.complete, stop=d.stop, why_stopped=d.why_stopped,
                   noise=None if d.noise is None else dict(axis_rms_rad=d.noise.axis_rms, power=d.noise.noise_power,
                                                           share=d.noise.share))
    paths["json"] = out / "diagnosis.json"
    paths["json"].write_text(json.dumps(summary, indent=2, default=float) + "\n")
    md = markdown(d, source, model_name, {"errors per link": "errors.png", "residual over time": "residual.png"})
    paths["report"] = out / "report.md"
    paths["report"].write_text(md)
    return paths

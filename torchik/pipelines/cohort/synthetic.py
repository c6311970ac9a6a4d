"""A generated cohort to try `torchik cohort` on (and to test and time it): subjects of
different heights, each walking and running in front of perfect sensors, tracked with Human66
and Human48 generated for them, trials of different lengths.

    write_synthetic_cohort("cohort/")          # 10 subjects x 4 trials, cohort/manifest.toml
    torchik cohort cohort/manifest.toml --out results/
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ...io.recording import save_recording
from ...method.models import TRACKED_LINKS, HumanSubject, load_model
from ...synthetic.scenarios import scenario

MODELS = ("human66", "human48")
GAITS = ("walking", "running")


def synthetic_trials(subjects: int = 10, trials_per_subject: int = 4, durations=(1.0, 1.5, 2.0)) -> list[dict]:
    """The cohort's rows: trial, subject, height (m), mass (kg), model, gait, duration (s), seed.
    Heights spread over 1.50 to 1.95 m; a subject's trials alternate the models, then the gaits."""
    rows = []
    for s, height in enumerate(np.linspace(1.50, 1.95, subjects)):
        for k in range(trials_per_subject):
            rows.append(dict(trial=f"s{s + 1:02d}_t{k + 1}", subject=f"s{s + 1:02d}", height=round(float(height), 3),
                             mass=round(45.0 + 40.0 * (height - 1.5), 1), model=MODELS[k % 2],
                             gait=GAITS[(k // 2) % 2], duration=durations[(s + k) % len(durations)], seed=100 * s + k))
    return rows


def write_synthetic_cohort(folder: str | Path, subjects: int = 10, trials_per_subject: int = 4, rate: float = 50.0,
                           durations=(1.0, 1.5, 2.0), manifest: str = "manifest.toml", transient: float = 0.5) -> Path:
    """Write each trial's recording (`<subject>/<trial>.npz`, with its true joint angles) and a
    manifest (.toml or .csv by `manifest`'s suffix) under `folder`; returns the manifest's path."""
    folder = Path(folder)
    rows = synthetic_trials(subjects, trials_per_subject, durations)
    models: dict[tuple, object] = {}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a trial's tensors are small: threads would only wait for each other
    try:
        for row in rows:
            _write_trial(folder, row, models, rate)
    finally:
        torch.set_num_threads(threads)
    path = folder / manifest
    path.write_text(_toml(rows, transient) if path.suffix == ".toml" else _csv(rows, transient))
    return path


def _write_trial(folder: Path, row: dict, models: dict, rate: float) -> None:
    """Generate one trial's recording with its subject's model (kept in `models`) and save it."""
    key = (row["model"], row["height"], row["mass"])
    if key not in models:
        models[key] = load_model(row["model"], HumanSubject(height=row["height"], mass=row["mass"]))
    recording = scenario(row["gait"], models[key], TRACKED_LINKS[row["model"]], duration=row["duration"], rate=rate,
                         seed=row["seed"])
    row["recording"] = f"{row['subject']}/{row['trial']}.npz"
    (folder / row["subject"]).mkdir(parents=True, exist_ok=True)
    save_recording(recording, folder / row["recording"])


def _toml(rows: list[dict], transient: float) -> str:
    """The TOML form: defaults, one table per subject (its anthropometry), one entry per trial."""
    lines = ["# a generated cohort (torchik.cohort.synthetic)", "[defaults]", f"transient = {transient}", ""]
    for subject in dict.fromkeys(r["subject"] for r in rows):
        first = next(r for r in rows if r["subject"] == subject)
        lines += [f"[subjects.{subject}]", f"height = {first['height']}", f"mass = {first['mass']}", ""]
    for r in rows:
        lines += ["[[trials]]", f'trial = "{r["trial"]}"', f'subject = "{r["subject"]}"',
                  f'recording = "{r["recording"]}"', f'model = "{r["model"]}"', ""]
    return "\n".join(lines)


def _csv(rows: list[dict], transient: float) -> str:
    """The CSV form: every column on every row."""
    lines = ["trial,subject,recording,model,height,mass,transient"]
    lines += [f"{r['trial']},{r['subject']},{r['recording']},{r['model']},{r['height']},{r['mass']},{transient}"
              for r in rows]
    return "\n".join(lines) + "\n"

"""A cohort's manifest: one row per trial, read from CSV or TOML and checked before any work.

Columns (CSV header, or keys of a TOML trial):

| column | meaning |
|---|---|
| `trial` | unique id (letters, digits, `_ . -`): the folder of its results |
| `subject` | subject id |
| `recording` | the recording (.npz, .mvnx, .bvh, .c3d), relative to the manifest |
| `model` | `human66`, `human48`, `icub` or a `.urdf` file (default `human66` when `height` is given) |
| `height`, `mass`, `segments` | anthropometry: a Human66/48 generated for the subject (m, kg, `Segment=m; ...`) |
| `subject_from` | a recording (MVNX, BVH, C3D static trial, .npz) the subject's Human66/48 is built from |
| `map`, `calibration`, `calibration_frame` | a link map (built-in or .toml), a static trial to calibrate on, its frame |
| `scheme`, `gain`, `position_gain`, `orientation_gain`, `backend` | the tracker's options, as `torchik track`'s |
| `transient` | seconds left out of the statistics (default 2) |
| `rrd` | also write a rerun recording of the trial (true/false) |

A TOML manifest may give `[defaults]` for every trial and `[subjects.<id>]` for every trial of a
subject; a trial's own keys come last:

    [defaults]
    model = "human48"
    [subjects.s01]
    height = 1.62
    [[trials]]
    trial = "s01_walk"
    subject = "s01"
    recording = "s01/walk.npz"
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import re
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

from ...errors import InputError, TorchikError
from ...io.maps import calibration_frame, load_map
from ...method.models import MODELS, HumanSubject
from ...method.qp import BACKENDS
from ...method.settings import SCHEMES, TrackerSettings

REQUIRED = ("trial", "subject", "recording")
TRIAL_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


class ManifestError(InputError):
    """A manifest that cannot be read or names something that does not exist."""


@dataclass(frozen=True)
class TrialSpec:
    """One trial, paths absolute. model: a built-in name or a URDF path; height/mass/segments: the
    subject's anthropometry (None: the default subject); map: a built-in name or a .toml path."""

    trial: str
    subject: str
    recording: str
    model: str = "human66"
    height: float | None = None
    mass: float | None = None
    segments: tuple[tuple[str, float], ...] = ()
    subject_from: str | None = None  # a recording the subject's model is built from
    map: str | None = None
    calibration: str | None = None
    calibration_frame: int | str | None = None
    scheme: str = "midpoint"
    position_gain: float = TrackerSettings.position_gain
    orientation_gain: float = TrackerSettings.orientation_gain
    backend: str = "auto"
    transient: float = 2.0
    rrd: bool = False

    @property
    def batch_key(self) -> tuple:
        """Trials with equal keys can share a batch: one topology, one link set, one tracker."""
        return (self.model, self.map, self.scheme, self.position_gain, self.orientation_gain, self.backend)

    @property
    def subject_model(self) -> HumanSubject | None:
        """The subject a human model is generated for (None: the built-in model as it is)."""
        return human_subject(self.height, self.mass, self.segments, self.subject_from)

    def fingerprint(self) -> str:
        """A hash of everything the trial's result depends on: its options and its input files'
        sizes and modification times. A stored result with another fingerprint is stale."""
        files = [Path(p) for p in (self.recording, self.calibration, self.map, self.model, self.subject_from)
                 if p and Path(p).is_file()]
        stats = [(str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files]
        text = json.dumps([asdict(self), stats], sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:16]


def human_subject(height: float | None, mass: float | None, segments=(), subject_from: str | None = None
                  ) -> HumanSubject | None:
    """A HumanSubject from what a manifest gives (the template's height or mass where one is
    missing; the one a recording measures, for subject_from); None when it gives nothing. ModelError
    for values out of range."""
    if subject_from:
        return _measured_subject(subject_from, height, mass)
    if height is None and mass is None and not segments:
        return None
    return HumanSubject(height=height or HumanSubject.height, mass=mass or HumanSubject.mass,
                        segment_lengths=dict(segments))


@functools.lru_cache(maxsize=64)
def _measured_subject(path: str, height: float | None, mass: float | None) -> HumanSubject:
    """The subject a recording measures, read once per process for all of a subject's trials."""
    from ...io import read
    from ...io.subjects import subject_from_recording

    return subject_from_recording(read(path), height, mass).subject


def _float(value) -> float:
    return float(value)


def _bool(value) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text not in ("true", "false", "yes", "no", "1", "0"):
        raise ValueError(f"expected true or false, got {value!r}")
    return text in ("true", "yes", "1")


def _segments(value) -> tuple[tuple[str, float], ...]:
    """'RightUpperArm=0.31; RightForeArm=0.25' (CSV) or a TOML table -> ((name, metres), ...)."""
    if isinstance(value, dict):
        return tuple(sorted((str(k), float(v)) for k, v in value.items()))
    pairs = []
    for item in filter(None, (part.strip() for part in str(value).split(";"))):
        name, sep, metres = item.partition("=")
        if not sep:
            raise ValueError(f"expected Segment=metres; ..., got {item!r}")
        pairs.append((name.strip(), float(metres)))
    return tuple(sorted(pairs))


def _frame(value) -> int | str:
    return calibration_frame(str(value))


def _choice(valid):
    def convert(value) -> str:
        if str(value) not in valid:
            raise ValueError(f"{value!r} is not one of {', '.join(valid)}")
        return str(value)
    return convert


CONVERTERS = {
    "trial": str, "subject": str, "recording": str, "model": str, "height": _float, "mass": _float,
    "segments": _segments, "subject_from": str, "map": str, "calibration": str, "calibration_frame": _frame,
    "scheme": _choice(tuple(SCHEMES)), "gain": _float, "position_gain": _float, "orientation_gain": _float,
    "backend": _choice(("auto", *BACKENDS)), "transient": _float, "rrd": _bool,
}


def read_manifest(path: str | Path) -> list[TrialSpec]:
    """The trials of a CSV or TOML manifest, in its order, checked: known columns, the required
    ones present, values of the right type, unique trial ids, models and maps that exist, and
    the recording and calibration files present. ManifestError naming the row otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"{path}: no such manifest")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        rows = _csv_rows(path)
    elif suffix == ".toml":
        rows = _toml_rows(path)
    else:
        raise ManifestError(f"{path}: a manifest is a .csv or .toml file")
    if not rows:
        raise ManifestError(f"{path}: no trials")
    specs, seen = [], set()
    for where, row in rows:
        try:
            spec = _spec(row, path.parent)
        except (TorchikError, ValueError) as exc:
            raise ManifestError(f"{path}: {where}: {exc}") from None
        if spec.trial in seen:
            raise ManifestError(f"{path}: {where}: trial id {spec.trial!r} is used twice")
        seen.add(spec.trial)
        specs.append(spec)
    return specs


def _csv_rows(path: Path) -> list[tuple[str, dict]]:
    """(where, {column: text}) per data row; empty cells left out, '#' lines skipped."""
    lines = [line for line in path.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    columns = [c.strip() for c in reader.fieldnames or []]
    _check_columns(path, columns, "the header")
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        raise ManifestError(f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
                            f"a manifest needs {', '.join(REQUIRED)}, and model or height")
    rows = []
    for number, raw in enumerate(reader, start=2):
        if None in raw:
            raise ManifestError(f"{path}: row {number}: more cells than columns")
        row = {k.strip(): v.strip() for k, v in raw.items() if v is not None and v.strip()}
        rows.append((f"row {number}", row))
    return rows


def _toml_rows(path: Path) -> list[tuple[str, dict]]:
    """(where, merged keys) per [[trials]] entry: [defaults], then [subjects.<id>], then the trial's own."""
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ManifestError(f"{path}: not valid TOML: {exc}") from None
    unknown = sorted(set(data) - {"defaults", "subjects", "trials"})
    if unknown:
        raise ManifestError(f"{path}: unknown table{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                            f"a manifest has [defaults], [subjects.<id>] and [[trials]]")
    defaults, subjects = data.get("defaults", {}), data.get("subjects", {})
    _check_columns(path, defaults, "[defaults]")
    for name, keys in subjects.items():
        _check_columns(path, keys, f"[subjects.{name}]")
    rows = []
    for i, trial in enumerate(data.get("trials", [])):
        where = f"trials[{i}]" + (f" ({trial['trial']})" if "trial" in trial else "")
        _check_columns(path, trial, where)
        row = {**defaults, **subjects.get(str(trial.get("subject", defaults.get("subject"))), {}), **trial}
        missing = [c for c in REQUIRED if c not in row]
        if missing:
            raise ManifestError(f"{path}: {where}: missing {', '.join(missing)}")
        rows.append((where, row))
    return rows


def _check_columns(path: Path, columns, where: str) -> None:
    unknown = [c for c in columns if c not in CONVERTERS]
    if unknown:
        raise ManifestError(f"{path}: {where}: unknown column{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                            f"valid: {', '.join(CONVERTERS)}")


def _spec(row: dict, folder: Path) -> TrialSpec:
    """A TrialSpec from one row's values (text or TOML values), paths resolved against `folder`."""
    missing = [c for c in REQUIRED if c not in row]
    if missing:
        raise ValueError(f"no {', '.join(missing)}")
    values = {}
    for column, value in row.items():
        try:
            values[column] = CONVERTERS[column](value)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{column}: {exc}") from None
    if not TRIAL_ID.match(values["trial"]):
        raise ValueError(f"trial id {values['trial']!r}: use letters, digits, '_', '.' and '-' (it names a folder)")
    gain = values.pop("gain", TrackerSettings.position_gain)
    values.setdefault("position_gain", gain)
    values.setdefault("orientation_gain", gain)
    values["recording"] = _existing(folder, values["recording"], "recording")
    if "calibration" in values:
        values["calibration"] = _existing(folder, values["calibration"], "calibration")
    if "subject_from" in values:
        if "segments" in values:
            raise ValueError("segments and subject_from both give segment lengths; give one")
        values["subject_from"] = _existing(folder, values["subject_from"], "subject_from")
    if "map" in values:
        values["map"] = _existing(folder, values["map"], "map") if Path(values["map"]).suffix else values["map"]
        load_map(values["map"])  # a map that does not parse fails here, with its own message
    values["model"] = _model(values.get("model", "human66"), folder)
    spec = TrialSpec(**values)
    # HumanSubject checks the ranges (a ModelError here, before any work)
    if spec.subject_model is not None and spec.model not in ("human66", "human48"):
        raise ValueError(f"height, mass, segments and subject_from generate a human model; model {spec.model!r} is not one "
                         f"(use human66 or human48)")
    return spec


def _model(value: str, folder: Path) -> str:
    if value.lower() in MODELS:
        return value.lower()
    if value.lower().endswith(".urdf"):
        return _existing(folder, value, "model")
    raise ValueError(f"unknown model {value!r}; valid: {', '.join(MODELS)} or a .urdf file")


def _existing(folder: Path, name: str, column: str) -> str:
    path = (folder / name).resolve()
    if not path.is_file():
        raise ValueError(f"{column} {name}: no such file (paths are relative to the manifest's folder)")
    return str(path)

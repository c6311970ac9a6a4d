"""OpenSim's table files (`.sto`, `.mot`): a header of `key=value` lines (and, in the older
Storage files, a first line naming the table and free text) ended by `endheader`, a line of
tab-separated column labels starting with `time`, then one line per frame. A cell holds one number,
or several separated by commas (OpenSense's quaternions `w,x,y,z`, a Vec3's `x,y,z`).

`read_table` parses any of them; `write_table` writes what OpenSim's `TimeSeriesTable` and
`Storage` read (the header's `nRows`, `nColumns`, `inDegrees`, `DataType` and `version` lines).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .files import replacing
from .recording import RecordingError, readable_file

ROWS_AT_ONCE = 10_000  # rows formatted together when writing
MISSING_CELLS = ("", "nan", "-nan", "na", "n/a")  # lower-cased: what tables write for a sample not measured


@dataclass(frozen=True)
class OpenSimTable:
    """A parsed table: header (`key=value` lines, keys as written), name (a first line without `=`,
    None when absent), labels (the columns after `time`), time [T] (s), cells [T][C] (text, as
    written) and the line number in the file of each row [T] (for messages)."""

    path: Path
    header: dict[str, str]
    name: str | None
    labels: tuple[str, ...]
    time: np.ndarray
    cells: list[list[str]]
    lines: list[int]

    def header_value(self, key: str) -> str | None:
        """A header value by its key, whatever its case (`DataRate`, `datarate`)."""
        return next((v for k, v in self.header.items() if k.lower() == key.lower()), None)

    def column(self, label: str, width: int) -> np.ndarray:
        """Column `label` as numbers [T,width]: NaN where a cell is missing (empty, nan). A cell
        holding another count of numbers, or text that is not a number, raises RecordingError naming
        the file, line and column."""
        c = self.labels.index(label)
        out = np.full((len(self.time), width), np.nan)
        for t, row in enumerate(self.cells):
            text = row[c].strip()
            if text.lower() in MISSING_CELLS:
                continue
            parts = text.split(",")
            if len(parts) != width:
                raise RecordingError(f"{self.path}: line {self.lines[t]}, column {label!r}: {text!r} holds "
                                     f"{len(parts)} numbers, expected {width}")
            try:
                out[t] = [float(p) for p in parts]
            except ValueError:
                raise RecordingError(f"{self.path}: line {self.lines[t]}, column {label!r}: {text!r} is not "
                                     f"{width} numbers") from None
        return out


def read_table(path: str | Path) -> OpenSimTable:
    """An OpenSim table file. RecordingError naming the file and line for what is malformed: no
    `endheader`, no `time` column, a row with another number of cells, a time that is not a number
    or does not increase."""
    path = readable_file(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not a text file; is this an OpenSim table (.sto, .mot)?") from None
    lines = text.splitlines()
    end = next((i for i, line in enumerate(lines) if line.strip().lower() == "endheader"), None)
    if end is None:
        raise RecordingError(f"{path}: no 'endheader' line; is this an OpenSim table (.sto, .mot)?")
    header: dict[str, str] = {}
    name = None
    for i, line in enumerate(lines[:end]):
        if "=" in line:
            key, value = line.split("=", 1)
            header[key.strip()] = value.strip()
        elif i == 0 and line.strip():
            name = line.strip()
    body = [(k + 1, line) for k, line in enumerate(lines[end + 1:], start=end + 1) if line.strip()]
    if not body:
        raise RecordingError(f"{path}: no column labels after 'endheader'")
    split = lambda line: line.rstrip("\r\n").split("\t") if "\t" in line else line.split()  # noqa: E731
    label_line, labels = body[0][0], [s.strip() for s in split(body[0][1])]
    if not labels or labels[0].lower() != "time":
        raise RecordingError(f"{path}: line {label_line}: the first column must be 'time', got {labels[:1]}")
    duplicates = sorted({x for x in labels if labels.count(x) > 1})
    if duplicates:
        raise RecordingError(f"{path}: line {label_line}: duplicate columns {duplicates}")
    time: list[float] = []
    cells: list[list[str]] = []
    numbers: list[int] = []
    for number, line in body[1:]:
        row = split(line)
        if len(row) < len(labels):  # trailing missing cells that a writer left off: missing, not an error
            row += [""] * (len(labels) - len(row))
        if len(row) != len(labels):
            raise RecordingError(f"{path}: line {number}: {len(row)} cells, {len(labels)} columns")
        try:
            t = float(row[0])
        except ValueError:
            raise RecordingError(f"{path}: line {number}: time {row[0]!r} is not a number") from None
        if not np.isfinite(t) or (time and t <= time[-1]):
            raise RecordingError(f"{path}: line {number}: time {row[0]} does not follow {time[-1] if time else ''} "
                                 "(times must increase)")
        time.append(t)
        cells.append(row[1:])
        numbers.append(number)
    if not time:
        raise RecordingError(f"{path}: no rows after the column labels")
    return OpenSimTable(path, header, name, tuple(labels[1:]), np.asarray(time, dtype=np.float64), cells, numbers)


def write_table(path: str | Path, time: np.ndarray, labels, values: np.ndarray, header: dict[str, str],
                name: str | None = None) -> Path:
    """An OpenSim table at `path`, replacing it whole. time [T] s; labels [C]; values [T,C] (one
    number a cell) or [T,C,k] (k numbers a cell, comma-separated: quaternions, Vec3s); NaN written
    as `nan`. header: `key=value` lines (nRows and nColumns are added); name: a first line (the
    Storage format's table name, as `.mot` files have). Numbers to 10 significant digits."""
    values = np.asarray(values, dtype=np.float64)
    labels = list(labels)
    if values.shape[:2] != (len(time), len(labels)):
        raise ValueError(f"values of shape {list(values.shape)} for {len(time)} rows and {len(labels)} columns")
    cell = values if values.ndim == 3 else values[..., None]
    head = ([name] if name else []) + [f"{k}={v}" for k, v in
                                       dict(header, nRows=len(time), nColumns=len(labels) + 1).items()]
    times = np.asarray(time, dtype=np.float64)
    with replacing(path) as part, open(part, "w") as f:
        f.write("\n".join(head) + "\nendheader\n" + "\t".join(["time", *labels]) + "\n")
        for start in range(0, len(times), ROWS_AT_ONCE):  # text for a block of rows at a time: an hour is 360 000
            block = np.char.mod("%.10g", cell[start:start + ROWS_AT_ONCE])  # [rows,C,k]
            stamps = np.char.mod("%.10g", times[start:start + ROWS_AT_ONCE])
            f.writelines(stamp + "\t" + "\t".join(",".join(c) for c in row) + "\n" for stamp, row in zip(stamps, block))
    return Path(path)

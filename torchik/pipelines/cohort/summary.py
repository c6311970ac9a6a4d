"""The cohort's summary table, rebuilt from the trials' folders: one row per trial of the
manifest, in its order, written as CSV and Parquet (each replaced whole).

A trial with no result, or a result of another spec (its fingerprint differs), has status
`missing`; the others `ok` or `failed` with their error.
"""

from __future__ import annotations

import csv
from pathlib import Path

from ...errors import optional
from ...io.files import replacing
from .manifest import TrialSpec
from .trial import COLUMNS, load_result


def summary_rows(out: Path, specs: list[TrialSpec], fingerprints: list[str]) -> list[dict]:
    """The rows of `specs` from `out/trials/<trial>/result.json` (COLUMNS, None where empty)."""
    rows = []
    for spec, fingerprint in zip(specs, fingerprints):
        stored = load_result(out, spec.trial)
        if stored is not None and stored.get("fingerprint") == fingerprint:
            rows.append({k: stored["row"].get(k) for k in COLUMNS})
        else:
            rows.append(dict(dict.fromkeys(COLUMNS), trial=spec.trial, subject=spec.subject, model=spec.model,
                             status="missing"))
    return rows


def write_summary(out: Path, specs: list[TrialSpec], fingerprints: list[str]) -> list[dict]:
    """Write out/summary.csv and out/summary.parquet from what is on disk; returns the rows."""
    pa = optional("pyarrow", "cohort", "the cohort's summary.parquet")
    import pyarrow.parquet as pq

    rows = summary_rows(out, specs, fingerprints)
    with replacing(out / "summary.csv") as part, open(part, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    types = {k: pa.string() for k in ("trial", "subject", "model", "status", "error")}
    types.update({k: pa.int64() for k in ("frames", "qp_fallbacks", "dropped_targets", "batch", "batch_size",
                                           "padded_frames")})
    schema = pa.schema([(k, types.get(k, pa.float64())) for k in COLUMNS])
    with replacing(out / "summary.parquet") as part:
        pq.write_table(pa.Table.from_pylist(rows, schema=schema), part)
    return rows

"""Outputs written whole or not at all."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def replacing(path: str | Path):
    """Write to the temporary path this yields; it replaces `path` when the block completes. A write
    interrupted (Ctrl-C) or failed leaves the old file or none, never a truncated one."""
    path = Path(path)
    part = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        yield part
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)


def write_json(report: dict, path: str | Path) -> Path:
    """`report` as indented JSON at `path`, replacing it whole."""
    path = Path(path)
    with replacing(path) as part:
        part.write_text(json.dumps(report, indent=2) + "\n")
    return path

"""Every real recording in ../shared/data converts to a valid recording and reads back (skipped when absent)."""

from pathlib import Path

import numpy as np
import pytest

from torchik.io import load_recording, read, save_recording

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
FILES = sorted(p for p in DATA.glob("*/*") if p.suffix.lower() in (".mvnx", ".bvh", ".c3d")) if DATA.is_dir() else []


@pytest.mark.skipif(not FILES, reason="../shared/data absent")
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_shared_file_converts_and_reads_back(path, tmp_path):
    rec = read(str(path))
    assert len(rec.time) > 10 and len(rec.links) >= 19
    back = load_recording(save_recording(rec, tmp_path / "r.npz"))
    assert np.array_equal(back.orientation, rec.orientation, equal_nan=True) and back.links == rec.links

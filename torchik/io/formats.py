"""Any recording torchik reads, by its file's suffix: `read(path)`."""

from __future__ import annotations

from pathlib import Path

from .bvh import read_bvh
from .c3d import read_c3d
from .mvnx import read_mvnx
from .opensense import read_opensense
from .recording import Recording, RecordingError, readable_file
from .recording_file import RecordingFile, load_recording

# .sto: OpenSense quaternion tables (OpenSim tables of other data types are refused by name)
READERS = {".npz": load_recording, ".mvnx": read_mvnx, ".bvh": read_bvh, ".c3d": read_c3d, ".sto": read_opensense}


def read(path: str | Path) -> Recording:
    """A Recording from any supported file (.npz, .mvnx, .bvh, .c3d, .sto), by its suffix."""
    if Path(path).is_dir():
        readable_file(path)  # raises, naming it a folder whatever its suffix
    suffix = Path(path).suffix.lower()
    if suffix not in READERS:
        raise RecordingError(f"{path}: unsupported format {suffix!r}; supported: {', '.join(READERS)}")
    return READERS[suffix](path)


def open_recording(path: str | Path) -> Recording | RecordingFile:
    """A recording to track a chunk at a time: a RecordingFile for a torchik recording (.npz, read as
    its frames are needed; an hour of one does not fit in memory at once), else the Recording the
    file's reader gives (the other formats are read whole)."""
    if Path(path).suffix.lower() == ".npz" and not Path(path).is_dir():
        return RecordingFile(path)
    return read(path)

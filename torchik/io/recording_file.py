"""A recording file (`.npz`, see `recording.py`) read a chunk of frames at a time.

An hour at 100 Hz of 23 links is about 1 GB of float64: more than a run should hold. Opening a
`RecordingFile` reads what is not per frame (time, names, meta) and only the headers of the
per-frame arrays (their dtypes and shapes); `chunks(size)` then reads `size` frames of every
array at a time, each zip member through its own stream (stored or deflated alike; the member's
CRC is checked when its last frame is read, as `np.load` does). Each chunk is a `Recording`
validated as it is made (`first_frame` says where it starts, and messages count frames from
the file's start), so a file is checked with the same messages whether it is read whole
(`load_recording`: one chunk) or in parts.
"""

from __future__ import annotations

import json
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Iterator

import numpy as np

from .recording import REQUIRED, Recording, RecordingError, check_layout, readable_file

PER_FRAME = ("orientation", "angular_velocity", "base_position", "base_linear_velocity", "joint_positions", "position",
             "external_wrench")
BLOCK = 16 << 20  # bytes per read from a member: a chunk's copy is made a block at a time


def load_recording(path: str | Path) -> Recording:
    """Read and validate a recording; RecordingError naming the file and the problem. (The reader of
    `RecordingFile` in one chunk: a long recording can be read a chunk at a time instead.)"""
    return RecordingFile(path).read()


class RecordingFile:
    """A torchik recording file, opened: time [T], links, base_link, joint_names, meta and frames
    (T) as a Recording has them, and `chunks(size)`. Raises RecordingError naming the file for
    anything `load_recording` refuses before the frames are read."""

    def __init__(self, path: str | Path):
        self.path = path = readable_file(path)
        if not zipfile.is_zipfile(path):  # np.load takes any other bytes for a pickle, which it refuses
            raise RecordingError(f"{path}: not a torchik recording (.npz, a zip archive of arrays); "
                                 "is it another format under the wrong suffix?")
        with self._reading(), zipfile.ZipFile(path) as archive:
            self._members = {name.removesuffix(".npy"): name for name in archive.namelist()}
            missing = [k for k in REQUIRED if k not in self._members]
            if missing:
                raise RecordingError(f"{path}: missing {missing}; a recording holds {list(REQUIRED)}")
            whole = {k: self._read_whole(archive, k) for k in ("time", "links", "base_link", "meta", "joint_names")
                     if k in self._members}
            self._headers = {k: _header(archive.open(self._members[k]), k) for k in PER_FRAME if k in self._members}
        try:
            self.meta: dict = json.loads(str(whole["meta"])) if "meta" in whole else {}
        except json.JSONDecodeError as exc:
            raise RecordingError(f"{path}: meta is not valid JSON: {exc}") from exc
        self.time: np.ndarray = whole["time"]
        self.links = tuple(str(x) for x in whole["links"])
        self.base_link = str(whole["base_link"])
        self.joint_names = tuple(str(x) for x in whole["joint_names"]) if "joint_names" in whole else None
        # the arrays as they will be read, without reading them: a shaped view of one element
        shaped = {k: np.broadcast_to(np.zeros((), dtype), shape) for k, (shape, _, dtype) in self._headers.items()}
        check_layout(self.time, self.links, self.base_link, shaped, self.joint_names, self.meta, str(path))

    @property
    def frames(self) -> int:
        return len(self.time)

    def read(self) -> Recording:
        """The whole recording (one chunk)."""
        return next(self.chunks(self.frames))

    def chunks(self, size: int) -> Iterator[Recording]:
        """The recording `size` frames at a time (the last chunk shorter), each a validated Recording
        whose first_frame is its place in the file."""
        if size < 1:
            raise ValueError(f"chunk size must be positive, got {size}")
        with self._reading(), zipfile.ZipFile(self.path) as archive:
            streams = {k: archive.open(self._members[k]) for k in self._headers}
            fortran: dict[str, np.ndarray] = {}  # arrays in Fortran order, read whole
            try:
                for k, stream in streams.items():
                    _header(stream, k)  # past the header, at the first frame
                for start in range(0, self.frames, size):
                    stop = min(start + size, self.frames)
                    arrays = {k: self._rows(streams[k], k, start, stop, fortran) for k in self._headers}
                    yield self._chunk(start, stop, arrays)
            finally:
                for stream in streams.values():
                    stream.close()

    def _chunk(self, start: int, stop: int, arrays: dict[str, np.ndarray]) -> Recording:
        try:
            return Recording(time=self.time[start:stop], links=self.links, base_link=self.base_link,
                             joint_names=self.joint_names, meta=self.meta, first_frame=start, **arrays)
        except RecordingError as exc:
            raise RecordingError(f"{self.path}: {str(exc).removeprefix('recording: ')}") from None

    def _rows(self, stream: IO[bytes], name: str, start: int, stop: int, fortran: dict[str, np.ndarray]) -> np.ndarray:
        """Frames [start, stop) of array `name`, read from `stream` (at frame `start`). An array in
        Fortran order (rare: np.savez keeps a transposed array's layout) has no contiguous frames:
        it is read whole into `fortran` on the first chunk and sliced."""
        shape, fortran_order, dtype = self._headers[name]
        if fortran_order:
            if name not in fortran:
                fortran[name] = _read_into(stream, np.empty(shape[::-1], dtype)).T
            return fortran[name][start:stop]
        return _read_into(stream, np.empty((stop - start, *shape[1:]), dtype))

    def _read_whole(self, archive: zipfile.ZipFile, name: str) -> Any:
        with archive.open(self._members[name]) as f:
            return np.lib.format.read_array(f, allow_pickle=False)

    @contextmanager
    def _reading(self):
        """Zip and format errors of every kind as RecordingError naming the file."""
        try:
            yield
        except RecordingError:
            raise
        except Exception as exc:
            raise RecordingError(f"{self.path}: not a torchik recording (.npz): {type(exc).__name__}: {exc}") from exc


def _header(stream: IO[bytes], name: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """The .npy header of a member: shape, Fortran order, dtype (the stream left at the data)."""
    version = np.lib.format.read_magic(stream)
    if version not in ((1, 0), (2, 0)):
        raise ValueError(f"{name}: .npy format version {version} is not supported")
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran_order, dtype = read(stream)
    if dtype.hasobject:  # np.load's refusal, in its words
        raise ValueError("Object arrays cannot be loaded when allow_pickle=False")
    return shape, fortran_order, dtype


def _read_into(stream: IO[bytes], out: np.ndarray) -> np.ndarray:
    """`out` (contiguous) filled with the stream's next bytes, a block at a time."""
    view = memoryview(out.reshape(-1).view(np.uint8).data) if out.size else memoryview(b"")
    done = 0
    while done < len(view):
        data = stream.read(min(BLOCK, len(view) - done))
        if not data:
            raise EOFError(f"the array ends after {done} of its {len(view)} bytes: the file is truncated")
        view[done:done + len(data)] = data
        done += len(data)
    return out

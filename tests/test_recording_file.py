"""io.recording_file: a recording file read a chunk at a time gives np.load's frames, stored or
deflated, whatever the chunk size; it holds one chunk at a time; each chunk is validated with the
file's frame numbers and messages; load_recording is the same reader in one chunk."""

import tracemalloc
import zipfile

import numpy as np
import pytest
import torch

from torchik.io import Recording, RecordingError, load_recording, save_recording
from torchik.io.recording_file import RecordingFile
from torchik.method import so3

ARRAYS = ("orientation", "angular_velocity", "base_position", "base_linear_velocity", "joint_positions", "position",
          "external_wrench")


def recording(T: int, n: int = 4, seed: int = 0) -> Recording:
    g = np.random.default_rng(seed)
    R = so3.random_rotation((T, n), torch.Generator().manual_seed(seed)).numpy()
    R[g.integers(T), g.integers(n)] = np.nan  # a gap
    return Recording(time=np.arange(T) / 100.0, links=tuple(f"l{i}" for i in range(n)), orientation=R,
                     angular_velocity=g.normal(size=(T, n, 3)), base_link="l0", base_position=g.normal(size=(T, 3)),
                     base_linear_velocity=g.normal(size=(T, 3)), joint_names=("a", "b"),
                     joint_positions=g.normal(size=(T, 2)), position=g.normal(size=(T, n, 3)),
                     external_wrench=g.normal(size=(T, n, 6)), meta={"k": 1})


def write(rec: Recording, path, compressed: bool = False):
    save_recording(rec, path)
    if compressed:  # the same arrays, deflated (as np.savez_compressed writes them)
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
        np.savez_compressed(path.with_suffix(".tmp.npz"), **arrays)
        path.with_suffix(".tmp.npz").replace(path)
    return path


@pytest.mark.parametrize("compressed", [False, True], ids=["stored", "deflated"])
@pytest.mark.parametrize("size", [1, 7, 50, 1000])
def test_chunks_of_any_size_join_into_np_loads_arrays(tmp_path, compressed, size):
    rec = recording(50)
    path = write(rec, tmp_path / "r.npz", compressed)
    chunks = list(RecordingFile(path).chunks(size))
    assert [c.first_frame for c in chunks] == list(range(0, 50, size))
    assert all(len(c.time) == min(size, 50 - c.first_frame) for c in chunks)
    with np.load(path) as data:
        for name in ("time", *ARRAYS):
            assert np.array_equal(np.concatenate([getattr(c, name) for c in chunks]), data[name], equal_nan=True), name
    assert all(c.links == rec.links and c.meta == rec.meta and c.joint_names == rec.joint_names for c in chunks)


def test_load_recording_is_the_reader_in_one_chunk(tmp_path):
    path = write(recording(30), tmp_path / "r.npz")
    whole, (chunk,) = load_recording(path), list(RecordingFile(path).chunks(30))
    for name in ("time", *ARRAYS):
        assert np.array_equal(getattr(whole, name), getattr(chunk, name), equal_nan=True)


def test_reading_holds_one_chunk_not_the_file(tmp_path):
    rec = recording(4000, n=23)
    path = write(rec, tmp_path / "r.npz")
    per_frame = sum(getattr(rec, name)[0].nbytes for name in ARRAYS)  # about 3.9 kB a frame
    reader = RecordingFile(path)
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        frames = sum(len(c.time) for c in reader.chunks(16))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert frames == 4000
    assert peak < 40 * 16 * per_frame < 4000 * per_frame / 5  # a few chunks' worth; the file holds 16 MB


def test_a_bad_rotation_is_named_by_its_frame_in_the_file_whatever_the_chunk(tmp_path):
    rec = recording(40)
    R = rec.orientation.copy()
    R[33, 2] = np.diag([1.0, 1.0, -1.0])  # a reflection
    path = tmp_path / "r.npz"
    np.savez(path, **{**dict(np.load(write(rec, path))), "orientation": R})
    for size in (5, 40):
        with pytest.raises(RecordingError, match=r"r.npz: orientation of 'l2' at frame 33 is not a rotation"):
            list(RecordingFile(path).chunks(size))


def test_a_file_whose_layout_is_wrong_is_refused_before_any_frame_is_read(tmp_path):
    rec = recording(10)
    data = dict(np.load(write(rec, tmp_path / "r.npz")))
    np.savez(tmp_path / "short.npz", **{**data, "base_position": data["base_position"][:9]})
    with pytest.raises(RecordingError, match=r"short.npz: base_position has shape \[9, 3\], expected \[10, 3\]"):
        RecordingFile(tmp_path / "short.npz")
    np.savez(tmp_path / "f32.npz", **{**data, "orientation": data["orientation"].astype(np.float32)})
    with pytest.raises(RecordingError, match="f32.npz: orientation must be a float64 NumPy array, got float32"):
        RecordingFile(tmp_path / "f32.npz")


def test_a_damaged_file_is_refused_naming_it(tmp_path):
    path = write(recording(200), tmp_path / "r.npz")
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("angular_velocity.npy")
    data = path.read_bytes()
    # the last frame's bytes changed, as by a bad copy: the member's CRC, checked as its end is read, differs
    end = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size
    (tmp_path / "bad.npz").write_bytes(data[:end - 16] + bytes(16) + data[end:])
    with pytest.raises(RecordingError, match=r"bad.npz: not a torchik recording \(.npz\): BadZipFile: Bad CRC-32"):
        list(RecordingFile(tmp_path / "bad.npz").chunks(64))
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    with pytest.raises(RecordingError, match="cut.npz: not a torchik recording"):
        list(RecordingFile(tmp_path / "cut.npz").chunks(64))


def test_arrays_in_fortran_order_read_the_same(tmp_path):
    rec = recording(20)
    data = dict(np.load(write(rec, tmp_path / "r.npz")))
    data["base_position"] = np.asfortranarray(data["base_position"])
    data["orientation"] = np.asfortranarray(data["orientation"])
    np.savez(tmp_path / "f.npz", **data)
    chunks = list(RecordingFile(tmp_path / "f.npz").chunks(6))
    assert np.array_equal(np.concatenate([c.orientation for c in chunks]), rec.orientation, equal_nan=True)
    assert np.array_equal(np.concatenate([c.base_position for c in chunks]), rec.base_position)

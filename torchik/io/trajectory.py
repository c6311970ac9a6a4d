"""The estimated trajectory as a file: what `torchik track --out` writes.

The file is written as the run goes (`TrajectoryWriter`): each array's rows are appended, part by
part, to a spool file of its own (unnamed, in the output's folder: it vanishes with the process,
however that ends), and the `.npz` is assembled from them when the run ends, when its number of
frames is known (a run stopped by Ctrl-C has fewer than its recording). Its bytes are those
`np.savez` writes for the whole arrays; memory is one part's.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import IO

import numpy as np

from ..method.kinematics import KinematicModel
from ..method.state import Trajectory
from .files import PartFile

DIAGNOSTICS = ("mnte", "rmse")  # written when the trajectory's diagnostics have them


def save_trajectory(trajectory: Trajectory, model: KinematicModel, path: str | Path) -> Path:
    """The estimated trajectory of subject 0 as .npz: time [T], joint_names, joint_positions [T,n],
    base_position [T,3], base_rotation [T,3,3], velocity [T,6+n], and mnte [T], rmse [T] when the
    diagnostics have them."""
    with TrajectoryWriter(path, model) as writer:
        writer.write(trajectory)
        return writer.commit()


class TrajectoryWriter:
    """`save_trajectory` a part at a time: `write` each part of a run in order, then `commit`
    (leaving the `with` block without it writes nothing)."""

    def __init__(self, path: str | Path, model: KinematicModel):
        self.path = Path(path)
        self.joint_names = np.array(model.joint_names, dtype=str)
        self.frames = 0
        self._spools: dict[str, tuple[IO[bytes], np.dtype, tuple[int, ...]]] = {}  # file, dtype, shape of a row

    def write(self, trajectory: Trajectory, targets=None) -> None:
        """A part of the run (subject 0's samples are written); targets: unused (an output's signature)."""
        host = lambda t: t.detach().cpu().numpy()  # noqa: E731
        arrays = dict(time=host(trajectory.time), joint_positions=host(trajectory.joint_positions[:, 0]),
                      base_position=host(trajectory.base_position[:, 0]),
                      base_rotation=host(trajectory.base_rotation[:, 0]), velocity=host(trajectory.velocity[:, 0]))
        arrays.update({name: host(trajectory.diagnostics[name][:, 0]) for name in DIAGNOSTICS
                       if name in trajectory.diagnostics})
        if not self._spools:
            self._spools = {name: (tempfile.TemporaryFile(dir=self.path.parent), a.dtype, a.shape[1:])
                            for name, a in arrays.items()}
        if arrays.keys() != self._spools.keys():
            raise ValueError(f"a part with {sorted(arrays)}; the earlier ones had {sorted(self._spools)}")
        for name, a in arrays.items():
            spool, dtype, row = self._spools[name]
            if (a.dtype, a.shape[1:]) != (dtype, row):
                raise ValueError(f"{name}: a part of {a.dtype} {list(a.shape)}; the earlier ones were {dtype} [T,{row}]")
            spool.write(np.ascontiguousarray(a).data)
        self.frames += len(arrays["time"])

    def commit(self) -> Path:
        """The .npz of the parts written, moved onto the path; returns it."""
        if not self._spools:
            raise ValueError("no part of the trajectory was written")
        with PartFile(self.path) as out:
            with open(out.part, "wb") as f, zipfile.ZipFile(f, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
                for name in ("time", "joint_names", *(k for k in self._spools if k != "time")):  # np.savez's order
                    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                        self._write_member(member, name)
            out.commit()
        self.close()
        return self.path

    def _write_member(self, member: IO[bytes], name: str) -> None:
        """Array `name` as .npy into a zip member: its header, then its spooled rows."""
        if name == "joint_names":
            np.lib.format.write_array(member, self.joint_names, allow_pickle=False)
            return
        spool, dtype, row = self._spools[name]
        header = dict(descr=np.lib.format.dtype_to_descr(dtype), fortran_order=False, shape=(self.frames, *row))
        np.lib.format.write_array_header_1_0(member, header)
        spool.seek(0)
        shutil.copyfileobj(spool, member, 1 << 20)

    def close(self) -> None:
        """The spool files closed (and so removed)."""
        for spool, _, _ in self._spools.values():
            spool.close()
        self._spools = {}

    def __enter__(self) -> "TrajectoryWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

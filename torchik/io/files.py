"""Outputs written whole or not at all."""

from __future__ import annotations

import glob
import json
import os
import stat
from contextlib import contextmanager
from pathlib import Path

from ..errors import InputError


class PartFile:
    """An output written at a hidden path beside `path` (`part`), which `commit` moves onto `path`;
    `discard` (and leaving the `with` block uncommitted) removes it. A write interrupted (Ctrl-C) or
    failed leaves the old file or none, never a truncated one."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not is_replaceable(self.path):
            # the commit's rename would destroy it (a device node, a FIFO a reader waits on, a link's target)
            raise InputError(f"{self.path} is {file_kind(self.path)}, which an output would replace; "
                             "give a regular file's name")
        _remove_orphans(self.path)
        self.part = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")

    def commit(self) -> Path:
        os.replace(self.part, self.path)
        return self.path

    def discard(self) -> None:
        self.part.unlink(missing_ok=True)

    def __enter__(self) -> "PartFile":
        return self

    def __exit__(self, *exc) -> None:
        self.discard()


def is_replaceable(path: Path) -> bool:
    """True for a path that is absent or a regular file (not a link, FIFO, socket, device or folder)."""
    return not path.is_symlink() and (not path.exists() or path.is_file())


def file_kind(path: Path) -> str:
    """What a path that is not a regular file is, in words ("a FIFO", "a character device", ...)."""
    mode = path.lstat().st_mode
    kinds = ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISDIR, "a folder"))
    return next((name for test, name in kinds if test(mode)), "not a regular file")


@contextmanager
def replacing(path: str | Path):
    """Write to the temporary path this yields; it replaces `path` when the block completes (PartFile)."""
    with PartFile(path) as out:
        yield out.part
        out.commit()


def _remove_orphans(path: Path) -> None:
    """Remove the `.part` files of `path` that processes no longer running left (killed by SIGKILL or
    a power cut, they could not clean up)."""
    for part in path.parent.glob(f".{glob.escape(path.name)}.*.part"):
        pid = part.name[len(path.name) + 2:-len(".part")]
        if pid.isdigit() and not _running(int(pid)):
            part.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # no signal sent: only whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True


def write_json(report: dict, path: str | Path) -> Path:
    """`report` as indented JSON at `path`, replacing it whole."""
    path = Path(path)
    with replacing(path) as part:
        part.write_text(json.dumps(report, indent=2) + "\n")
    return path

"""io/files: outputs are replaced whole, and the .part files a killed process left are removed."""

import os
import subprocess
import sys

import pytest

from torchik.errors import InputError
from torchik.io.files import write_json


def test_a_part_file_of_a_dead_process_is_removed_on_the_next_write_and_a_live_ones_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    orphan = tmp_path / f".report.json.{int(dead.stdout)}.part"  # as a run killed by SIGKILL leaves it
    orphan.write_text("half")
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        busy = tmp_path / f".report.json.{alive.pid}.part"  # another run writing the same output now
        busy.write_text("writing")
        write_json({"a": 1}, tmp_path / "report.json")
        assert not orphan.exists() and busy.exists()
    finally:
        alive.kill()
    assert (tmp_path / "report.json").read_text() == '{\n  "a": 1\n}\n'


@pytest.mark.parametrize("make", ["fifo", "symlink", "folder"])
def test_the_library_never_replaces_what_is_not_a_regular_file(tmp_path, make):
    """Whatever calls write_json (an experiment's --json, a library user), a FIFO, a link or a folder
    at the output path is refused and left as it was; the CLI's check says so earlier."""
    target = tmp_path / "kept.json"
    target.write_text("{}")
    path = tmp_path / "out.json"
    if make == "fifo":
        os.mkfifo(path)
    elif make == "symlink":
        path.symlink_to(target)
    else:
        path.mkdir()
    with pytest.raises(InputError, match="which an output would replace"):
        write_json({"a": 1}, path)
    assert target.read_text() == "{}" and (path.is_symlink() or not path.is_file())
    assert not list(tmp_path.glob(".*.part"))

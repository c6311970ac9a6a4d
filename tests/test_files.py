"""io/files: outputs are replaced whole, and the .part files a killed process left are removed."""

import subprocess
import sys

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

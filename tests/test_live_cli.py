"""`torchik live` and `torchik replay` refuse bad input with one line and exit code 2: bad URLs, a
port in use, an unknown LSL stream, a missing pylsl; their --help shows examples."""

from __future__ import annotations

import socket
import sys

import pytest

from torchik.cli import main


def refused(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err and "\n" not in err
    return err


def test_bad_urls_are_refused_in_one_line(capsys):
    assert "not a stream URL" in refused(capsys, ["live", "--from", "http://x", "--quiet"])
    assert "name the host" in refused(capsys, ["replay", "../shared/data/mvnx/test_mocap.mvnx", "--to", "udp://:9"])


def test_a_port_in_use_is_refused_in_one_line(capsys):
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    try:
        assert "in use" in refused(capsys, ["live", "--from", f"udp://127.0.0.1:{busy.getsockname()[1]}", "--quiet"])
    finally:
        busy.close()


def test_an_unknown_lsl_stream_is_refused_in_one_line(capsys):
    pytest.importorskip("pylsl")
    err = refused(capsys, ["live", "--from", "lsl://no-such-stream-here", "--timeout", "0.2", "--quiet"])
    assert "no-such-stream-here" in err


def test_a_missing_pylsl_is_refused_in_one_line(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pylsl", None)  # import pylsl now raises ImportError
    assert "pip install 'torchik[live]'" in refused(capsys, ["live", "--from", "lsl://mocap", "--quiet"])


@pytest.mark.parametrize("command", ["live", "replay"])
def test_help_shows_examples(capsys, command):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    assert f"torchik {command} " in capsys.readouterr().out.split("examples:")[1]

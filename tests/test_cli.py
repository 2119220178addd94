"""The console command and the demonstration it runs."""

import subprocess
import sys

import pytest

from netsense.cli import build_parser, main


def test_demo_writes_figure_and_summary(tmp_path, capsys):
    assert main(["demo", "--steps", "20", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "freshness index" in out and "converges" in out
    assert out.count("diverges") == 2
    png = tmp_path / "fig2.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = (tmp_path / "fig2.csv").read_text().strip().splitlines()
    assert len(rows) == 22 and rows[0].startswith("k,")


def test_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert "demo" in sub.choices
    for name, p in sub.choices.items():
        assert p.description, name


def test_console_entry_point_runs():
    res = subprocess.run([sys.executable, "-m", "netsense.cli", "--help"],
                         capture_output=True, text=True, check=True)
    assert "demo" in res.stdout


def test_user_error_is_one_line_and_debug_shows_the_traceback(capsys):
    """A user error prints one line and exits 2; ``--debug`` re-raises it with its traceback."""
    from netsense.cli import main

    rc = main(["benchmark", "no_such_scenario-v0", "--seeds", "1", "--out", "x"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "no_such_scenario" in err
    assert "Traceback" not in err
    with pytest.raises(ValueError, match="no_such_scenario"):
        main(["--debug", "benchmark", "no_such_scenario-v0", "--seeds", "1", "--out", "x"])


def test_a_closed_pipe_ends_quietly():
    """``netsense list | head``: the reader is gone before the command writes."""
    p = subprocess.Popen([sys.executable, "-m", "netsense.cli", "list"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # no reader: the command's first write fails with EPIPE
    err = p.stderr.read().decode()
    p.wait(timeout=120)
    assert p.returncode == 1
    assert "Traceback" not in err and "BrokenPipe" not in err

"""The console command and the demonstration it runs."""

import subprocess
import sys

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

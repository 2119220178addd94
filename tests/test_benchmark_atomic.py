"""The benchmark's files appear whole or not at all: a writer that fails mid-file leaves the
previous file (or none) and no temporary ``.*.part`` file (:mod:`netsense.rl.atomic`)."""

import argparse
import csv
import math

import pytest

from netsense.benchmark.headroom import HEADROOM_COLUMNS, write_headroom
from netsense.benchmark.metrics import METRICS
from netsense.benchmark.report import _save, write_csv
from netsense.commands import bench

OLD = "previous content\n"


class _Crash(RuntimeError):
    pass


@pytest.fixture
def crash_after_header(monkeypatch):
    """``csv.writer`` (and so ``csv.DictWriter``) writes its first row, then raises."""
    real = csv.writer

    class Writer:
        def __init__(self, *args, **kwargs):
            self._w, self._rows = real(*args, **kwargs), 0

        def writerow(self, row):
            self._rows += 1
            if self._rows > 1:
                raise _Crash("killed mid-write")
            return self._w.writerow(row)

        def writerows(self, rows):
            for row in rows:
                self.writerow(row)

    monkeypatch.setattr(csv, "writer", Writer)


def _episode_csv(path):
    results = [{"job": {"scenario": "s", "policy": p, "seed": 0},
                "metrics": dict.fromkeys(METRICS, 1.0)} for p in ("never", "freshness")]
    write_csv(results, path)


def _headroom_csv(path):
    row = {c: 1.0 if c.endswith(("reward", "mean", "low", "high", "pct", "episode")) else "x"
           for c in HEADROOM_COLUMNS}
    write_headroom([row, row], path.parent)


def _bench_csv(path):
    args = argparse.Namespace(N=[3, 4], seconds=0.0, horizon=5, no_mpe=True, csv=path)
    bench.run_env(args)


WRITERS = {"episodes.csv": _episode_csv, "headroom.csv": _headroom_csv,
           "bench.csv": _bench_csv}


@pytest.fixture
def fast_bench(monkeypatch):
    monkeypatch.setattr(bench, "bench_netsense", lambda *a, **k: 100.0)


@pytest.mark.parametrize("existed", [True, False])
@pytest.mark.parametrize("name", sorted(WRITERS))
def test_a_writer_killed_mid_file_leaves_the_old_file(tmp_path, fast_bench, crash_after_header,
                                                     name, existed):
    path = tmp_path / name
    if existed:
        path.write_text(OLD)
    with pytest.raises(_Crash):
        WRITERS[name](path)
    if existed:
        assert path.read_text() == OLD
    else:
        assert not path.exists()
    assert not list(tmp_path.glob(".*.part"))


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_a_writer_that_finishes_replaces_the_file(tmp_path, fast_bench, name):
    path = tmp_path / name
    path.write_text(OLD)
    WRITERS[name](path)
    rows = list(csv.reader(path.open(newline="")))
    assert len(rows) == 3 and rows[0][0] in ("scenario", "N")
    assert not list(tmp_path.glob(".*.part"))


def test_figures_are_pngs_under_their_name_and_leave_no_temporary_file(tmp_path):
    plt = pytest.importorskip("matplotlib.pyplot")
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, math.pi])
    _save(fig, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png"]


def test_written_files_have_the_usual_permissions(tmp_path):
    """A file written whole-or-not-at-all gets the mode a plain ``open`` would give
    (``0o666`` less the umask), not ``mkstemp``'s owner-only ``0o600``."""
    import os

    from netsense.rl.atomic import write_atomic

    mask = os.umask(0o022)
    try:
        write_atomic(tmp_path / "a.txt", "x")
        assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(mask)


def test_save_figure_writes_the_suffix_format_whole_or_not_at_all(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from netsense.rl.atomic import save_figure

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png, svg = save_figure(fig, tmp_path / "f.png"), save_figure(fig, tmp_path / "f.svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the format of the suffix,
    assert b"<svg" in svg.read_bytes()[:500]  # not guessed from the temporary's name
    (tmp_path / "g.png").write_text(OLD)

    def crash(*args, **kwargs):
        raise _Crash("killed mid-write")

    monkeypatch.setattr(fig, "savefig", crash)
    with pytest.raises(_Crash):
        save_figure(fig, tmp_path / "g.png")
    assert (tmp_path / "g.png").read_text() == OLD
    assert not list(tmp_path.glob(".*.part"))
    plt.close(fig)

"""The result tables of the README and docs/ are what ``docs/gen/tables.py`` generates from
the committed CSV files (so a table cannot drift from its file), and the generator reads its
specs as documented."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tables():
    spec = importlib.util.spec_from_file_location("_docs_gen_tables", ROOT / "docs/gen/tables.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


tables = _tables()
PAGES = tables.pages()


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_every_table_block_equals_what_its_files_generate(page):
    text = page.read_text()
    assert tables.rewrite(text) == text, (
        f"{page.name}: a table differs from its CSV; run `python docs/gen/tables.py`")


def test_the_results_pages_carry_generated_tables():
    blocks = [m for p in PAGES for m in tables.BLOCK.finditer(p.read_text())]
    assert len(blocks) >= 5
    for m in blocks:  # every block names files that exist
        paths = tables.parse_spec(m.group("spec"))[0]
        assert all((ROOT / p).is_file() for p in paths), paths


def test_a_block_is_generated_from_its_spec(tmp_path):
    (tmp_path / "r.csv").write_text("task,evaluation,iqm,lo,n\na-v0,greedy,-1.25,-2,5\n"
                                    "a-v0,sampled,3,1,5\nb-v0,greedy,0.5,0.25,4\n")
    text = ("intro\n<!-- table: r.csv\nwhere: evaluation=greedy\n| task | `{task}` |\n"
            "| IQM [low] | {iqm:.1f} [{lo:.2f}] |\n| runs | {n} |\n-->\nstale\n"
            "<!-- /table -->\nafter\n")
    out = tables.rewrite(text, root=tmp_path)
    assert out == ("intro\n<!-- table: r.csv\nwhere: evaluation=greedy\n| task | `{task}` |\n"
                   "| IQM [low] | {iqm:.1f} [{lo:.2f}] |\n| runs | {n} |\n-->\n"
                   "| task | IQM [low] | runs |\n|---|---|---|\n"
                   "| `a-v0` | −1.2 [−2.00] | 5 |\n| `b-v0` | 0.5 [0.25] | 4 |\n"
                   "<!-- /table -->\nafter\n")
    assert tables.rewrite(out, root=tmp_path) == out


def test_a_bad_spec_is_refused(tmp_path):
    (tmp_path / "r.csv").write_text("a\n1\n")
    with pytest.raises(ValueError, match="header"):
        tables.render_table("r.csv\n| only one cell |", root=tmp_path)
    with pytest.raises(ValueError, match="no row"):
        tables.render_table("r.csv\nwhere: a=2\n| a | {a} |", root=tmp_path)
    with pytest.raises(KeyError):
        tables.render_table("r.csv\n| b | {b} |", root=tmp_path)


def test_group_merges_rows_into_means_with_their_range(tmp_path):
    (tmp_path / "r.csv").write_text("policy,run,ret\nrule,,-3\nmlp,a,-1\nmlp,b,-2\n")
    out = tables.render_table("r.csv\ngroup: policy\n| policy | {policy} |\n"
                              "| return [min, max] | {ret:.1f} [{ret_min}, {ret_max}] |\n"
                              "| runs | {n} |", root=tmp_path)
    assert out.splitlines()[2:] == ["| rule | −3.0 [−3, −3] | 1 |",
                                    "| mlp | −1.5 [−2, −1] | 2 |"]

"""The documentation site's own code (docs/gen/) and its configuration.

The full check is ``mkdocs build --strict`` (CI runs it); these tests pin the pieces that
translate the repository's text for the site, on hand-written inputs, without MkDocs.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parents[1]
GEN = ROOT / "docs" / "gen"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"_docs_gen_{name}", GEN / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_every_page_is_in_the_nav_and_every_nav_page_exists():
    config = (ROOT / "mkdocs.yml").read_text()
    nav = config[config.index("\nnav:"):]
    listed = set(re.findall(r":\s+([\w./-]+\.md)\s*$", nav, flags=re.M))
    generated = {"scenarios.md", "experiments.md", "figures.md", "changelog.md"}
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    assert pages - listed == set(), "pages missing from mkdocs.yml's nav"
    assert listed - pages - generated == set(), "nav entries with no page"
    for script in re.findall(r"docs/gen/[\w.]+\.py", config):
        assert (ROOT / script).is_file(), script


def test_links_hook_maps_repository_paths_to_site_paths():
    links = _load("links")
    page = SimpleNamespace(file=SimpleNamespace(src_uri="rl.md"))
    text = ("![a](../experiments/results/rl/x/a.png) see [log](../CHANGELOG.md) and "
            "[index](../experiments/README.md#papers) and [env](env.md) and "
            "[code](../netsense/env/registry.py)")
    out = links.on_page_markdown(text, page, None, None)
    assert out == ("![a](experiments/results/rl/x/a.png) see [log](changelog.md) and "
                   "[index](experiments.md#papers) and [env](env.md) and "
                   "[code](../netsense/env/registry.py)")  # left for strict mode to reject
    nested = SimpleNamespace(file=SimpleNamespace(src_uri="reference/netsense/index.md"))
    assert links.on_page_markdown(text, nested, None, None) == text


def test_simple_tables_become_markdown_tables():
    pytest.importorskip("griffe")
    rst = _load("rst_markup")
    text = """Intro.

    =====  ====  ===============
    name   size  meaning
    =====  ====  ===============
    ``a``  M     first line of a
                 long cell
    ``b``  1     x | y
    =====  ====  ===============

=====  =====
key    value
other  thing
=====  =====
After."""
    got = rst.simple_tables_to_markdown(text).splitlines()
    assert got[:2] == ["Intro.", ""]
    assert "    | name | size | meaning |" in got and "    |---|---|---|" in got
    assert "    | ``a`` | M | first line of a long cell |" in got
    assert "    | ``b`` | 1 | x \\| y |" in got
    assert "|  |  |" in got and "| key | value |" in got and "| other | thing |" in got
    assert got[-1] == "After."
    assert not any("====" in line for line in got)


def test_sphinx_roles_resolve_or_warn(caplog):
    griffe = pytest.importorskip("griffe")
    rst = _load("rst_markup")
    pkg = griffe.load("netsense", search_paths=[str(ROOT)])
    graphs = pkg["graphs"]
    assert rst._resolve(pkg, graphs, ".processes").path == "netsense.graphs.processes"
    assert rst._resolve(pkg, graphs, "netsense.graphs.aoi.aoi_stats").path == \
        "netsense.graphs.aoi.aoi_stats"
    assert rst._resolve(pkg, graphs, "no_such_thing") is None

    class Match:  # the role regex's groups for :func:`~netsense.graphs.aoi.aoi_stats`
        def __init__(self, role):
            self.m = rst.ROLE.search(role)

        def group(self, i):
            return self.m.group(i)

    ext = rst.RstMarkup()
    assert ext._link(pkg, graphs, Match(":func:`~netsense.graphs.aoi.aoi_stats`")) == \
        "[`aoi_stats`][netsense.graphs.aoi.aoi_stats]"
    assert ext._link(pkg, graphs, Match(":func:`numpy.linalg.svd`")) == "`numpy.linalg.svd`"
    assert ext._link(pkg, graphs, Match(":class:`ValueError`")) == "`ValueError`"
    with caplog.at_level("WARNING"):
        assert ext._link(pkg, graphs, Match(":func:`netsense.graphs.gone`")) == \
            "`netsense.graphs.gone`"
    assert "names nothing in netsense" in caplog.text

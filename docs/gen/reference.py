"""Build the API reference pages from the package tree (mkdocs-gen-files, at build time).

One page per public module of ``netsense/`` (a package's page is its ``__init__``), each
rendered by mkdocstrings from the numpydoc docstrings, and ``reference/SUMMARY.md`` for
mkdocs-literate-nav, so a new module appears in the site without editing a list. Modules
whose name starts with an underscore are private and left out.
"""

from __future__ import annotations

from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "netsense"

nav = mkdocs_gen_files.Nav()
for path in sorted(PACKAGE.rglob("*.py")):
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
        doc = Path("reference", *parts, "index.md")
    else:
        doc = Path("reference", *parts).with_suffix(".md")
    if any(p.startswith("_") for p in parts):
        continue
    nav[parts] = doc.relative_to("reference").as_posix()
    with mkdocs_gen_files.open(doc, "w") as fh:
        fh.write(f"::: {'.'.join(parts)}\n")
    mkdocs_gen_files.set_edit_path(doc, path.relative_to(ROOT))

with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as fh:
    fh.writelines(nav.build_literate_nav())

"""Bring the experiments and the changelog into the site (mkdocs-gen-files, at build time).

* ``experiments.md``: the index ``experiments/README.md`` (every script, its command, run
  time and outputs), as written;
* ``figures.md``: every PNG under ``experiments/results/``, grouped by purpose and script,
  under the script's docstring summary and command; the images are copied into the site at
  ``experiments/results/...`` (the pages' ``../experiments/results/...`` links are mapped
  there by ``docs/gen/links.py``), so no figure is duplicated in git;
* ``changelog.md``: ``CHANGELOG.md``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "experiments"
RESULTS = EXPERIMENTS / "results"
PURPOSES = {
    "papers": "Reproductions of the papers' figures, tables and claims",
    "bench": "Speed and memory benchmarks",
    "rl": "Reinforcement learning: training, the benchmark, learned communication",
    "studies": "Studies beyond the papers: topologies, age of information, mobility, faults",
}


def summary(script: Path) -> str:
    """The first paragraph of a script's docstring, on one line."""
    doc = ast.get_docstring(ast.parse(script.read_text())) or ""
    return " ".join(doc.split("\n\n")[0].split())


for name in ("README.md",):
    text = (EXPERIMENTS / name).read_text()
    with mkdocs_gen_files.open("experiments.md", "w") as fh:
        fh.write(text)
    mkdocs_gen_files.set_edit_path("experiments.md", f"experiments/{name}")

with mkdocs_gen_files.open("changelog.md", "w") as fh:
    fh.write((ROOT / "CHANGELOG.md").read_text())
mkdocs_gen_files.set_edit_path("changelog.md", "CHANGELOG.md")

for png in sorted(RESULTS.rglob("*.png")):
    rel = png.relative_to(ROOT).as_posix()
    with mkdocs_gen_files.open(rel, "wb") as fh:
        fh.write(png.read_bytes())

lines = ["# Figures", "",
         "Every figure the experiments write, as committed under `experiments/results/`, by "
         "purpose and script (the [index](experiments.md) gives each script's run time and "
         "all its outputs). Each script regenerates its figures at its defaults with the "
         "command shown.", ""]
for purpose, title in PURPOSES.items():
    lines += [f"## {purpose}/: {title}", ""]
    for folder in sorted(p for p in (RESULTS / purpose).iterdir() if p.is_dir()):
        pngs = sorted(folder.rglob("*.png"))
        if not pngs:
            continue
        script = EXPERIMENTS / purpose / f"{folder.name}.py"
        lines += [f"### {purpose}/{folder.name}", ""]
        if script.is_file():
            lines += [summary(script), "", f"`python experiments/{purpose}/{folder.name}.py`", ""]
        else:
            lines += ["Written by a `netsense` command; see the [index](experiments.md).", ""]
        for png in pngs:
            rel = png.relative_to(ROOT).as_posix()
            label = png.relative_to(folder).as_posix()
            lines += [f"![{label}]({rel})", f"*{label}*", ""]
with mkdocs_gen_files.open("figures.md", "w") as fh:
    fh.write("\n".join(lines))

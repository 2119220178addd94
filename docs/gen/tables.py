"""Rewrite the result tables of the README and docs/*.md from the committed CSV files.

A table block names its CSV file(s), an optional row filter and one line per column (the
header, then a ``str.format`` template over the CSV's columns)::

    <!-- table: experiments/results/rl/learners/budget_10m/summary.csv
    where: evaluation=greedy
    | task | `{task}` |
    | learned: IQM [95 % CI] | {iqm:.1f} [{iqm_ci_low:.1f}, {iqm_ci_high:.1f}] |
    -->
    | task | learned: IQM [95 % CI] |
    |---|---|
    | `comm_process_noise-v0` | −99.8 [−100.8, −99.0] |
    <!-- /table -->

Everything between the spec and ``<!-- /table -->`` is generated. Several CSV files (space
separated) give their rows one after the other; ``where: column=a,b`` keeps the rows whose
column is ``a`` or ``b`` (``where: column="a, b"`` the one value ``a, b``; several
``where:`` lines must all hold); ``group: column`` merges
the rows with one value of it into one row of means (``{x_min}``, ``{x_max}`` and the
count ``{n}`` beside each numeric ``{x}``). Numeric fields are
formatted as numbers, with a typographic minus (−) as the rest of the docs write it.

    python docs/gen/tables.py            # rewrite the blocks in place
    python docs/gen/tables.py --check    # exit 1 naming every page whose tables drifted

``tests/test_docs_tables.py`` holds the docs to what this script generates, so a table
cannot drift from its file. Not part of the MkDocs build: the pages carry the tables.
"""

from __future__ import annotations

import argparse
import csv
import re
import string
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"(<!-- table: (?P<spec>.*?)-->\n)(?P<body>.*?)(<!-- /table -->)", re.S)


def pages(root: Path = ROOT) -> list[Path]:
    """The files whose tables this script maintains: the README and every docs page."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


class _Formatter(string.Formatter):
    def format_field(self, value, format_spec):
        if value == "" and format_spec:  # an empty numeric cell (a row without that value)
            return "–"
        out = format(value, format_spec)
        return out.replace("-", "−") if isinstance(value, (int, float)) else out


def parse_spec(spec: str):
    """``(csv paths, filters, [(header, template)], group column or None)`` of one spec."""
    lines = [ln.strip() for ln in spec.strip().splitlines() if ln.strip()]
    paths = lines[0].split()
    filters, columns, group = [], [], None
    for line in lines[1:]:
        if line.startswith("group:"):
            group = line[len("group:"):].strip()
        elif line.startswith("where:"):
            col, _, values = line[len("where:"):].strip().partition("=")
            values = values.strip()
            if len(values) > 1 and values[0] == values[-1] == '"':  # one literal value
                filters.append((col.strip(), {values[1:-1]}))
            else:
                filters.append((col.strip(), {v.strip() for v in values.split(",")}))
        elif line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if len(cells) != 2:
                raise ValueError(f"a column line is '| header | template |', got {line!r}")
            columns.append((cells[0], cells[1]))
        else:
            raise ValueError(f"unknown line in a table spec: {line!r}")
    if not paths or not columns:
        raise ValueError(f"a table spec names a CSV file and at least one column: {spec!r}")
    return paths, filters, columns, group


def _group(rows: list[dict], key: str) -> list[dict]:
    """One row per value of ``key`` (first-seen order): numeric fields become their mean,
    with ``<field>_min`` and ``<field>_max`` beside them and ``n`` the rows grouped."""
    out: dict[str, list[dict]] = {}
    for row in rows:
        out.setdefault(row[key], []).append(row)
    merged = []
    for members in out.values():
        row = dict(members[0], n=len(members))
        for field in members[0]:
            values = [m[field] for m in members]
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                row[field] = sum(values) / len(values)
                row[f"{field}_min"], row[f"{field}_max"] = min(values), max(values)
        merged.append(row)
    return merged


def render_table(spec: str, root: Path = ROOT) -> str:
    """The Markdown table one spec generates, ending in a newline."""
    paths, filters, columns, group = parse_spec(spec)
    rows = []
    for path in paths:
        with (root / path).open(newline="") as fh:
            rows += list(csv.DictReader(fh))
    rows = [r for r in rows if all(r.get(col) in values for col, values in filters)]
    if not rows:
        raise ValueError(f"no row of {paths} passes the filters {filters}")
    rows = [{k: _number(v) for k, v in row.items()} for row in rows]
    if group:
        rows = _group(rows, group)
    fmt = _Formatter()
    out = ["| " + " | ".join(h for h, _ in columns) + " |",
           "|" + "---|" * len(columns)]
    for fields in rows:
        out.append("| " + " | ".join(fmt.format(t, **fields) for _, t in columns) + " |")
    return "\n".join(out) + "\n"


def rewrite(text: str, root: Path = ROOT) -> str:
    """``text`` with every table block regenerated from its CSV files."""
    return BLOCK.sub(lambda m: m.group(1) + render_table(m.group("spec"), root) + m.group(4),
                     text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 if a page's tables differ from their files")
    args = parser.parse_args(argv)
    drifted = []
    for page in pages():
        text = page.read_text()
        new = rewrite(text)
        if new != text:
            drifted.append(page.relative_to(ROOT).as_posix())
            if not args.check:
                page.write_text(new)
    verb = "differ from their files" if args.check else "rewritten"
    print(f"tables {verb}: {', '.join(drifted)}" if drifted else "every table is up to date")
    return 1 if (args.check and drifted) else 0


if __name__ == "__main__":
    sys.exit(main())

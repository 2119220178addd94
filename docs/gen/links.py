"""MkDocs hook: let the pages link repository files the way GitHub shows them.

A page in ``docs/`` shows a figure as ``../experiments/results/<...>.png``, which is right
when the page is read on GitHub; in the site the figures live at
``experiments/results/<...>`` (copied there by ``docs/gen/experiments.py``), so the leading
``../`` is dropped for pages at the top of ``docs/``. ``../CHANGELOG.md`` and
``../experiments/README.md`` map to the generated ``changelog.md`` and ``experiments.md``.
Everything else is left to MkDocs' own link validation (strict mode fails on a link it
cannot resolve).
"""

from __future__ import annotations

import re

_TARGETS = re.compile(r"\]\(\.\./(experiments/results/[^)\s]+|CHANGELOG\.md|experiments/README\.md)"
                      r"([)\s#])")
_PAGES = {"CHANGELOG.md": "changelog.md", "experiments/README.md": "experiments.md"}


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs API)
    if "/" in page.file.src_uri:  # a generated page below the top level: links as written
        return markdown
    return _TARGETS.sub(lambda m: "](" + _PAGES.get(m.group(1), m.group(1)) + m.group(2),
                        markdown)

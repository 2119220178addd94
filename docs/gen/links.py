"""MkDocs hook: let the pages link repository files the way GitHub shows them.

A page in ``docs/`` shows a figure as ``../experiments/results/<...>.png``, which is right
when the page is read on GitHub; in the site the figures live at
``experiments/results/<...>`` (copied there by ``docs/gen/experiments.py``), so the leading
``../`` is dropped for pages at the top of ``docs/``. ``../CHANGELOG.md`` maps to the
generated ``changelog.md`` the same way. Everything else is left to MkDocs' own link
validation (strict mode fails on a link it cannot resolve).
"""

from __future__ import annotations

import re

_TARGETS = re.compile(r"\]\(\.\./(experiments/results/[^)\s]+|CHANGELOG\.md)([)\s])")


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs API)
    if "/" in page.file.src_uri:  # a generated page below the top level: links as written
        return markdown
    return _TARGETS.sub(lambda m: "](" + ("changelog.md" if m.group(1) == "CHANGELOG.md"
                                          else m.group(1)) + m.group(2), markdown)

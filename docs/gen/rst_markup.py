"""Griffe extension: the docstrings' reStructuredText markup rendered as the site's Markdown.

mkdocstrings renders docstrings as Markdown; two reStructuredText constructs of the numpydoc
docstrings are translated when the package is loaded (the source stays as it is):

* **simple tables** (columns framed by ``====  ====`` rules, a header between the first two
  rules, a cell continued on the next line when the first column is blank) become Markdown
  tables;
* **Sphinx roles** become links, as follows.

The numpydoc docstrings cross-reference with Sphinx roles (:func:`netsense.graphs.aoi.aoi_stats`,
:class:`~netsense.engine.core.BatchedCore`, :mod:`.processes`, :meth:`BatchedCore.step`),
which mkdocstrings would print as plain text. After the package is loaded, every role in a
docstring is resolved the way Sphinx reads it (absolute; ``.x`` relative to the module's
package; a bare name in the scope of the object that carries the docstring) and rewritten
as an autorefs link ``[`text`][path]`` (``~`` shows the last component only). A role that
names something outside netsense (numpy, scipy, torch, ...) or a private object the site
does not render becomes plain code; a role that names a netsense object that does not exist
is reported as a warning, which fails ``mkdocs build --strict``.
"""

from __future__ import annotations

import builtins
import re

import griffe

ROLE = re.compile(r":(?:py:)?(func|class|mod|meth|attr|data|obj|exc|const):`(~?)([^`]+)`")
PACKAGE = "netsense"


def _module_of(obj: griffe.Object) -> griffe.Module:
    while not obj.is_module:
        obj = obj.parent
    return obj


def _lookup(pkg: griffe.Module, path: str) -> griffe.Object | None:
    if path == PACKAGE:
        return pkg
    if not path.startswith(PACKAGE + "."):
        return None
    try:
        found = pkg[path[len(PACKAGE) + 1:]]
    except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    try:
        return found.final_target if found.is_alias else found
    except (griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None


def _resolve(pkg: griffe.Module, obj: griffe.Object, name: str) -> griffe.Object | None:
    if name.startswith("."):  # relative to the package of the module
        module = _module_of(obj)
        is_init = module.is_package or module.is_subpackage
        base = module.path if is_init else module.parent.path
        level = len(name) - len(name.lstrip("."))
        base = ".".join(base.split(".")[: len(base.split(".")) - level + 1])
        return _lookup(pkg, f"{base}.{name.lstrip('.')}")
    found = _lookup(pkg, name)
    if found is not None:
        return found
    head, _, rest = name.partition(".")
    scope: griffe.Object | None = obj
    while scope is not None:  # the object's scope (inherited members too), then its parents'
        if scope.is_class and head in scope.all_members:
            member = scope.all_members[head]
            return _lookup(pkg, f"{member.path}.{rest}" if rest else member.path)
        try:
            path = scope.resolve(head)
        except Exception:  # griffe's NameResolutionError, alias errors: not in this scope
            path = None
        if path is not None:
            return _lookup(pkg, f"{path}.{rest}" if rest else path)
        scope = scope.parent
    return None


def _rendered(target: griffe.Object) -> bool:
    return not any(part.startswith("_") for part in target.path.split(".")[1:])


RULE = re.compile(r"^( *)(=+(?: +=+)*) *$")


def _columns(rule: str) -> list[int]:
    """Start offsets of the columns of a ``====  ====`` rule."""
    return [m.start() for m in re.finditer(r"=+", rule)]


def _cells(line: str, starts: list[int]) -> list[str]:
    bounds = [*starts[1:], None]
    return [line[a:b].strip() if b is not None else line[a:].strip()
            for a, b in zip(starts, bounds, strict=True)]


def _markdown_table(rows: list[list[str]], header: list[str] | None) -> list[str]:
    def line(cells):
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"
    head = header or [""] * len(rows[0])
    return [line(head), "|" + "---|" * len(head), *(line(r) for r in rows)]


def simple_tables_to_markdown(text: str) -> str:
    """Every reStructuredText simple table of ``text`` as a Markdown table."""
    lines, out, i = text.split("\n"), [], 0
    while i < len(lines):
        m = RULE.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent, rule = m.group(1), lines[i]
        rules = [i]
        j = i + 1
        while j < len(lines) and len(rules) < 3:
            if lines[j].strip() == "" and len(rules) == 1:
                break
            if RULE.match(lines[j]) and lines[j].rstrip() == rule.rstrip():
                rules.append(j)
                if j + 1 >= len(lines) or not lines[j + 1].strip():
                    break
            j += 1
        if len(rules) < 2:
            out.append(lines[i])
            i += 1
            continue
        starts = [len(indent) + s for s in _columns(rule.strip())]
        header = None
        body_from = rules[0] + 1
        if len(rules) == 3:
            header = _cells(lines[rules[0] + 1], starts)
            body_from = rules[1] + 1
        rows: list[list[str]] = []
        for line in lines[body_from:rules[-1]]:
            if not line.strip():
                continue
            cells = _cells(line, starts)
            if rows and not cells[0]:
                rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells, strict=True)]
            else:
                rows.append(cells)
        out += ["", *(indent + r for r in _markdown_table(rows, header)), ""]
        i = rules[-1] + 1
    return "\n".join(out)


class RstMarkup(griffe.Extension):
    """Translate simple tables and Sphinx roles in every docstring of the package."""

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        if pkg.name != PACKAGE:
            return
        self._walk(pkg, pkg, set())

    def _walk(self, pkg: griffe.Module, obj: griffe.Object, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None:
            text = simple_tables_to_markdown(obj.docstring.value)
            obj.docstring.value = ROLE.sub(lambda m: self._link(pkg, obj, m), text)
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(pkg, member, seen)

    def _link(self, pkg: griffe.Module, obj: griffe.Object, m: re.Match) -> str:
        short, name = m.group(2), "".join(m.group(3).split())  # a role may wrap a line
        name = re.sub(r"\(\)$", "", name)
        shown = name.rsplit(".", 1)[-1] if short else name.lstrip(".")
        target = _resolve(pkg, obj, name)
        if target is None:
            root = name.lstrip(".").split(".")[0]
            if name.startswith(".") or root == PACKAGE or _mentions_netsense(root):
                griffe.logger.warning(f"{obj.relative_filepath}:{obj.lineno}: "
                                      f"cross-reference {m.group(0)} names nothing in {PACKAGE}")
            return f"`{shown}`"
        if not _rendered(target):
            return f"`{shown}`"
        return f"[`{shown}`][{target.path}]"


OUTSIDE = {
    "numpy", "np", "scipy", "torch", "torchrl", "tensordict", "gymnasium", "pettingzoo",
    "numba", "networkx", "matplotlib", "ray", "stable_baselines3", "sb3_contrib", "supersuit",
    "vmas", "mpe2", "opendssdirect", "tqdm", "rliable", "sklearn", "concurrent",
    "multiprocessing", "threading", "os", "sys", "pickle", "json", "dataclasses", "typing",
    "collections", "functools", "itertools", "pathlib", "argparse", "logging", "warnings",
    "random", "math", "tomllib", "tomli", "csv", "io", "subprocess", "time", "abc",
    "contextlib", "importlib", "inspect", "copy", "enum", "hashlib",
}


def _mentions_netsense(root: str) -> bool:
    """A name that is neither imported nor defined where it is used: a netsense name unless
    it is a builtin (``ValueError``) or a known outside package (``numpy``, ``scipy``, ...)."""
    return not hasattr(builtins, root) and root not in OUTSIDE

#!/usr/bin/env python3
"""Rewrite Sphinx markup in dynid's docstrings into what mkdocstrings renders.

    python .ci/docstrings.py            # rewrite the package's docstrings in place
    python .ci/docstrings.py --check    # list what would change; exit 1 if anything would

Inside docstrings only (module, class and function docstrings found with `ast`; code and
other strings are left alone):

* a Sphinx role - :func:`~dynid.a.b`, :meth:`x.y`, :class:`Name`, :mod:`dynid.a`,
  :attr:, :data:, :obj:, :exc:, :ref:, :math: - becomes a plain code span: `b` for a
  `~`-shortened target, the full dotted target otherwise, the title of `title <target>`;
* a literal double-backtick span ``x`` becomes `x`.

mkdocstrings (numpy style) shows single backticks as code; Sphinx roles and double
backticks come out as raw text in the API reference (tests/project/test_docs.py fails on them).
The script is idempotent: run it again after merging branches that add docstrings.
"""
from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIRS = ("src/dynid", "dynamics", "analysis", "reports", "templates")

ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|attr|data|obj|exc|ref|math|const|term):`([^`]+)`")
DOUBLE = re.compile(r"(?<!`)``([^`]+?)``(?!`)")


def _role_text(match: re.Match) -> str:
    target = match.group(1).strip()
    titled = re.fullmatch(r"(.+?)\s*<([^>]+)>", target, flags=re.S)
    if titled:
        return f"`{titled.group(1).strip()}`"
    target = target.lstrip("!")
    if target.startswith("~"):
        target = target[1:].rsplit(".", 1)[-1]
    return f"`{target}`"


def convert_text(text: str) -> str:
    """Docstring source text with roles and double backticks rewritten."""
    text = ROLE.sub(_role_text, text)
    return DOUBLE.sub(lambda m: f"`{m.group(1)}`", text)


def _docstring_nodes(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                yield body[0].value
        # attribute docstrings (a string right after an assignment), which griffe also renders
        body = getattr(node, "body", None)
        if isinstance(body, list):
            for prev, cur in zip(body, body[1:]):
                if isinstance(prev, (ast.Assign, ast.AnnAssign)) and isinstance(cur, ast.Expr) \
                        and isinstance(cur.value, ast.Constant) and isinstance(cur.value.value, str):
                    yield cur.value


def convert_source(source: str) -> str:
    """Python source with every docstring's markup rewritten (the rest byte for byte)."""
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line.encode("utf-8")))
    raw = source.encode("utf-8")
    spans = []
    for node in _docstring_nodes(tree):
        start = offsets[node.lineno - 1] + node.col_offset
        end = offsets[node.end_lineno - 1] + node.end_col_offset
        spans.append((start, end))
    for start, end in sorted(set(spans), reverse=True):
        old = raw[start:end].decode("utf-8")
        new = convert_text(old)
        if new != old:
            raw = raw[:start] + new.encode("utf-8") + raw[end:]
    return raw.decode("utf-8")


def python_files(root: Path):
    for folder in PACKAGE_DIRS:
        yield from sorted((root / folder).rglob("*.py"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--check", action="store_true", help="list the files that would change; exit 1 if any")
    parser.add_argument("paths", nargs="*", type=Path, help="files (default: the whole package)")
    args = parser.parse_args(argv)
    changed = []
    for path in args.paths or python_files(ROOT):
        old = path.read_text(encoding="utf-8")
        new = convert_source(old)
        if new != old:
            changed.append(path)
            if not args.check:
                path.write_text(new, encoding="utf-8")
    for path in changed:
        print(("would rewrite " if args.check else "rewrote ") + str(path))
    return 1 if (args.check and changed) else 0


if __name__ == "__main__":
    sys.exit(main())

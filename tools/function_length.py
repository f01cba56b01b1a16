"""Fails for any function longer than 80 lines unless a `# long:` comment says why (run by `make lint`).

    .venv/bin/python tools/function_length.py python/sabre [--limit 80]

A function's length runs from its `def` line to its last line (decorators not counted, nested functions
counted in their parent too). A long function passes when the line right above its `def` (or above its
first decorator), or the first comment inside its body, starts with `# long:` followed by the reason.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from pathlib import Path

MARK = "# long:"


def _has_reason(comment: str) -> bool:
    return comment.startswith(MARK) and bool(comment[len(MARK) :].strip())


def exempt(lines: list[str], node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Whether the comment above the def, or the body's first comment, gives a `# long:` reason."""
    top = min([node.lineno] + [d.lineno for d in node.decorator_list])
    if top >= 2 and _has_reason(lines[top - 2].strip()):
        return True
    for line in lines[node.body[0].lineno - 1 : node.end_lineno]:
        stripped = line.strip()
        if stripped.startswith("#"):
            return _has_reason(stripped)
    return False


def long_functions(path: Path, limit: int) -> Iterator[tuple[int, str, int]]:
    """(line, qualified name, length) of every function in the file longer than ``limit`` without a reason."""
    text = path.read_text()
    lines = text.splitlines()

    def visit(node: ast.AST, prefix: str) -> Iterator[tuple[int, str, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                length = (child.end_lineno or child.lineno) - child.lineno + 1
                if length > limit and not exempt(lines, child):
                    yield child.lineno, name, length
                yield from visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                yield from visit(child, f"{prefix}{child.name}.")
            else:
                yield from visit(child, prefix)

    yield from visit(ast.parse(text, filename=str(path)), "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", type=Path, help="files or folders (searched for *.py)")
    parser.add_argument("--limit", type=int, default=80, help="longest allowed function, in lines")
    args = parser.parse_args(argv)
    files = sorted({f for p in args.paths for f in ([p] if p.is_file() else p.rglob("*.py"))})
    found = [(f, *hit) for f in files for hit in long_functions(f, args.limit)]
    for f, line, name, length in found:
        print(f"{f}:{line}: {name} is {length} lines (limit {args.limit}); shorten it or say why with `{MARK} ...`")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())

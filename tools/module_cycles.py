"""Fails when modules import each other in a circle, in a Rust crate or a Python package (run by `make lint`).

    python3 tools/module_cycles.py src python/sabre

Each argument is a Rust crate's source folder (it holds lib.rs or main.rs) or a Python package (it holds
__init__.py). A module is a file; an arrow A -> B says that A names something of B. Every strongly connected
component of more than one file is reported as a circle, with the lines that make its arrows; a file that names
itself is no circle. The exit status is 1 when there is a circle, 2 for a bad argument, else 0.

Rust. The files are those the crate compiles from its root through `mod x;` (x.rs or x/mod.rs, or a `#[path]`);
items under `#[cfg(test)]` are left out, and with them the files only they declare (a `tests.rs` child). An
arrow comes from a `use` or `pub use` of `crate::`, `super::`, `self::` or a child module, and from such a path
in code (`super::x::f()`, `crate::a::B`). A path leads to the deepest module file it names: `crate::a::b::C` to
a/b.rs when that module exists, else to a.rs or a/mod.rs. `super::` counts from the file's own module (or from
the inline `mod` block around it). Re-exports are arrows like any other: a module that takes a name from its
parent's mod.rs points at that mod.rs, and the mod.rs that re-exports a child's names points at the child.
Comments, strings and `mod x;` declarations make no arrows.

Python. An arrow for every import of a module of the package: at module level, inside a function (a lazy
import still couples), and under `if TYPE_CHECKING:` (the type checker reads it, and it ties the modules'
design together just the same). `from p import x` leads to module p.x when there is one, else to p (a
package's __init__.py); `import a.b.c` to the deepest of a.b.c, a.b, a that exists. Imports by a computed
name (importlib.import_module(name)) are not read.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Graph:
    """Files (shown by path) and arrows between them, each arrow with the places that make it."""

    files: set[str] = field(default_factory=set)
    arrows: dict[str, dict[str, list[str]]] = field(default_factory=dict)

    def add(self, source: str, target: str, why: str) -> None:
        reasons = self.arrows.setdefault(source, {}).setdefault(target, []) if source != target else []
        if source != target and why not in reasons:
            reasons.append(why)


# ---------------------------------------------------------------- Rust


RAW_STRING = re.compile(r'b?r(#*)"')


def _literal_end(text: str, i: int) -> int:
    """End of the comment, string or character literal that starts at `i`; `i` when none does."""
    n = len(text)
    if text.startswith("//", i):
        end = text.find("\n", i)
        return n if end < 0 else end
    if text.startswith("/*", i):
        depth, j = 1, i + 2
        while j < n and depth:
            step = 1 if text[j : j + 2] not in ("/*", "*/") else 2
            depth += {"/*": 1, "*/": -1}.get(text[j : j + 2], 0)
            j += step
        return j
    if (raw := RAW_STRING.match(text, i)) and not (i and (text[i - 1].isalnum() or text[i - 1] == "_")):
        end = text.find('"' + raw.group(1), raw.end())
        return n if end < 0 else end + 1 + len(raw.group(1))
    if text[i] == '"':
        j = i + 1
        while j < n and text[j] != '"':
            j += 2 if text[j] == "\\" else 1
        return j + 1
    if text[i] == "'" and i + 2 < n:
        # a character literal ('a', '\n', '\'', '\u{1F600}'); otherwise a lifetime or a label ('a), kept
        if text[i + 1] == "\\":
            return text.find("'", i + 2 + (text[i + 2] == "'")) + 1
        if text[i + 2] == "'":
            return i + 3
    return i


def strip_rust(text: str) -> str:
    """The source with comments, string and character literals blanked out (offsets and lines kept)."""
    out = list(text)
    i = 0
    while i < len(text):
        end = _literal_end(text, i)
        if end <= i:
            i += 1
            continue
        for k in range(i, min(end, len(text))):
            if out[k] != "\n":
                out[k] = " "
        i = end
    return "".join(out)


def _item_end(text: str, start: int) -> int:
    """End of the item that starts at `start`: after its `;` or its closing `}` at depth 0."""
    depth, i = 0, start
    while i < len(text):
        c = text[i]
        if c in "([":
            depth += 1
        elif c in ")]":
            depth -= 1
        elif depth == 0 and c == ";":
            return i + 1
        elif depth == 0 and c == "{":
            return _matching_brace(text, i) + 1
        i += 1
    return len(text)


def _matching_brace(text: str, open_at: int) -> int:
    depth = 0
    for i in range(open_at, len(text)):
        if text[i] == "{":
            depth += 1
        elif text[i] == "}":
            depth -= 1
            if depth == 0:
                return i
    return len(text) - 1


ATTRIBUTE = re.compile(r"#\s*\[")
CFG_TEST = re.compile(r"#\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]")


def drop_test_items(text: str) -> str:
    """The stripped source with every item under `#[cfg(test)]` blanked out."""
    while match := CFG_TEST.search(text):
        i = match.end()
        # the item's further attributes, then the item
        while attribute := ATTRIBUTE.match(text, i + len(text[i:]) - len(text[i:].lstrip())):
            depth, i = 0, attribute.end() - 1
            while i < len(text):
                depth += {"[": 1, "]": -1}.get(text[i], 0)
                i += 1
                if depth == 0:
                    break
        end = _item_end(text, i)
        text = text[: match.start()] + re.sub(r"[^\n]", " ", text[match.start() : end]) + text[end:]
    return text


@dataclass
class RustFile:
    path: Path
    module: tuple[str, ...]
    code: str  # stripped, test items removed
    # inline `mod x { ... }` blocks: (start, end, module path)
    blocks: list[tuple[int, int, tuple[str, ...]]] = field(default_factory=list)

    def module_at(self, offset: int) -> tuple[str, ...]:
        inner = [b for b in self.blocks if b[0] <= offset < b[1]]
        return max(inner, key=lambda b: len(b[2]))[2] if inner else self.module

    def line(self, offset: int) -> int:
        return self.code.count("\n", 0, offset) + 1


MOD = re.compile(r"(?<![\w:])(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+(r#)?(\w+)\s*([;{])")
PATH_ATTRIBUTE = re.compile(r'#\s*\[\s*path\s*=\s*"([^"]+)"\s*\]\s*(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+(\w+)\s*;')


def read_crate(root: Path) -> tuple[dict[tuple[str, ...], Path], list[RustFile]]:
    """The crate's module tree (module path -> file, inline modules under their file) and its files."""
    modules: dict[tuple[str, ...], Path] = {}
    files: list[RustFile] = []
    entries = [root / name for name in ("lib.rs", "main.rs") if (root / name).is_file()]
    queue: list[tuple[Path, tuple[str, ...], Path]] = [(p, (), root) for p in entries]
    while queue:
        path, module, directory = queue.pop()
        if path in (f.path for f in files) or not path.is_file():
            continue
        raw = path.read_text()
        if re.match(r"\s*#!\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]", strip_rust(raw)):
            continue
        code = drop_test_items(strip_rust(raw))
        rust = RustFile(path, module, code)
        files.append(rust)
        modules[module] = path
        paths = {name: value for value, name in PATH_ATTRIBUTE.findall(raw)}
        # the folder each inline block's children live in, by the block's start
        block_dirs: list[tuple[int, int, tuple[str, ...], Path]] = []
        for match in MOD.finditer(code):
            name = match.group(2)
            outer = [b for b in block_dirs if b[0] <= match.start() < b[1]]
            parent_module, parent_dir = (outer[-1][2], outer[-1][3]) if outer else (module, directory)
            child = (*parent_module, name)
            if match.group(3) == "{":
                end = _matching_brace(code, match.end() - 1)
                rust.blocks.append((match.start(), end, child))
                block_dirs.append((match.start(), end, child, parent_dir / name))
                modules[child] = path
                continue
            if name in paths and not outer:
                target = path.parent / paths[name]
                queue.append((target, child, target.parent))
                continue
            for candidate in (parent_dir / f"{name}.rs", parent_dir / name / "mod.rs"):
                if candidate.is_file():
                    queue.append((candidate, child, parent_dir / name))
                    break
    return modules, files


def use_paths(tree: str) -> Iterator[list[str]]:
    """The leaf paths of a use tree (`a::{b, c::{d, self}}` -> a::b, a::c::d, a::c), as segment lists."""

    def expand(prefix: list[str], text: str) -> Iterator[list[str]]:
        brace = text.find("{")
        head = [s for s in (text if brace < 0 else text[:brace]).split("::") if s]
        if brace < 0:
            yield prefix + (head[:-1] if head[-1:] == ["self"] else head)
            return
        inner = text[brace + 1 : text.rfind("}")]
        depth, start = 0, 0
        for i, c in enumerate(inner + ","):
            depth += {"{": 1, "}": -1}.get(c, 0)
            if c == "," and depth == 0:
                if part := inner[start:i]:
                    yield from expand(prefix + head, part)
                start = i + 1

    # aliases (`x as y`) name nothing further; `::*` names the module before it
    yield from expand([], re.sub(r"\s+", "", re.sub(r"\bas\s+\w+", "", tree)).replace("::*", ""))


USE = re.compile(r"(?<![\w:])(?:pub(?:\s*\([^)]*\))?\s+)?use\s+")
CODE_PATH = re.compile(r"(?<![\w:])(?<!in )(?:r#)?([A-Za-z_]\w*)((?:\s*::\s*(?:r#)?[A-Za-z_]\w*)+)")


def resolve_rust(segments: list[str], here: tuple[str, ...], modules: dict[tuple[str, ...], Path]) -> tuple[str, ...] | None:
    """The deepest module a path names, seen from module `here`; None for another crate or a plain name."""
    if not segments:
        return None
    first, rest = segments[0], segments[1:]
    if first == "crate":
        base: tuple[str, ...] = ()
    elif first in ("super", "self"):
        base = here
        while segments and segments[0] in ("super", "self"):
            if segments[0] == "super":
                if not base:
                    return None
                base = base[:-1]
            segments = segments[1:]
        rest = segments
    elif (*here, first) in modules:
        base, rest = (*here, first), rest
    else:
        return None
    for segment in rest:
        if (*base, segment) in modules:
            base = (*base, segment)
        else:
            break
    return base


def rust_graph(root: Path, graph: Graph) -> None:
    modules, files = read_crate(root)
    display = {m: str(p) for m, p in modules.items()}
    for rust in files:
        graph.files.add(str(rust.path))
        code = rust.code
        spans: list[tuple[int, int]] = []
        for match in USE.finditer(code):
            end = code.find(";", match.end())
            spans.append((match.start(), end))
            here = rust.module_at(match.start())
            written = " ".join(code[match.start() : end].split())
            why = f"{rust.line(match.start())}: {written if len(written) <= 100 else written[:99] + '…'}"
            for segments in use_paths(code[match.end() : end]):
                target = resolve_rust(segments, here, modules)
                if target is not None:
                    graph.add(str(rust.path), display[target], why)
        for match in CODE_PATH.finditer(code):
            if any(a <= match.start() < b for a, b in spans):
                continue
            segments = [match.group(1)] + re.findall(r"\w+", match.group(2))
            target = resolve_rust(segments, rust.module_at(match.start()), modules)
            if target is not None:
                graph.add(str(rust.path), display[target], f"{rust.line(match.start())}: {'::'.join(segments)}")


# ---------------------------------------------------------------- Python


def python_modules(root: Path) -> dict[str, Path]:
    """The package's modules by dotted name: its .py files, and the stubs (.pyi) and compiled extensions
    (.so, .pyd) of modules without a .py file."""
    package = root.resolve().name
    modules: dict[str, Path] = {}
    for path in sorted(root.rglob("*"), key=lambda p: (p.suffix != ".py", p.suffix != ".pyi", str(p))):
        if path.suffix not in (".py", ".pyi", ".so", ".pyd") or not path.is_file():
            continue
        parts = (package, *path.relative_to(root).parts[:-1], path.name.split(".")[0])
        modules.setdefault(".".join(parts[:-1] if parts[-1] == "__init__" else parts), path)
    return modules


def python_graph(root: Path, graph: Graph) -> None:
    modules = python_modules(root)
    package = root.resolve().name

    def deepest(name: str) -> str | None:
        parts = name.split(".")
        for k in range(len(parts), 0, -1):
            if ".".join(parts[:k]) in modules:
                return ".".join(parts[:k])
        return None

    for name, path in modules.items():
        graph.files.add(str(path))
        if path.suffix not in (".py", ".pyi"):
            continue
        home = name if path.stem == "__init__" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = home.split(".")
                    base = ".".join(up[: len(up) - node.level + 1] + ([node.module] if node.module else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            for target in targets:
                found = deepest(target) if target.split(".")[0] == package else None
                if found is not None:
                    graph.add(str(path), str(modules[found]), f"{node.lineno}: {ast.unparse(node)}")


# ---------------------------------------------------------------- circles


def circles(graph: Graph) -> list[list[str]]:
    """Strongly connected components of more than one file (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph.files):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.arrows.get(start, {}))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for succ in successors:
                if succ not in index:
                    index[succ] = low[succ] = len(index)
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, iter(sorted(graph.arrows.get(succ, {})))))
                    break
                if succ in on_stack:
                    low[node] = min(low[node], index[succ])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return sorted(found)


def report(graph: Graph, found: list[list[str]]) -> str:
    arrows = sum(len(t) for t in graph.arrows.values())
    lines = [f"{len(graph.files)} files, {arrows} arrows, {len(found)} circle{'' if len(found) == 1 else 's'}"]
    for k, component in enumerate(found, 1):
        lines.append(f"circle {k}: {len(component)} files: {', '.join(component)}")
        members = set(component)
        for source in component:
            for target, why in sorted(graph.arrows.get(source, {}).items()):
                if target in members:
                    lines.append(f"  {source} -> {target}  ({'; '.join(why[:3])}{'; …' if len(why) > 3 else ''})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("roots", nargs="+", type=Path, help="Rust source folders and Python packages")
    args = parser.parse_args(argv)
    graph = Graph()
    for root in args.roots:
        if (root / "lib.rs").is_file() or (root / "main.rs").is_file():
            rust_graph(root, graph)
        elif (root / "__init__.py").is_file():
            python_graph(root, graph)
        else:
            print(f"{root}: neither a Rust crate's source folder (lib.rs, main.rs) nor a Python package", file=sys.stderr)
            return 2
    found = circles(graph)
    print(report(graph, found))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())

"""`_core.pyi` describes the compiled module: same classes, same public methods and attributes."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import sabre
from sabre import _core

STUB = Path(sabre.__file__).with_name("_core.pyi")


def _stub_names() -> dict[str, set[str]]:
    tree = ast.parse(STUB.read_text())
    out: dict[str, set[str]] = {"": set()}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")}
        elif isinstance(node, ast.FunctionDef):
            out[""].add(node.name)
    return out


def test_stub_matches_the_compiled_module():
    stub = _stub_names()
    classes = {name for name, obj in vars(_core).items() if inspect.isclass(obj) and not name.startswith("_")}
    functions = {name for name, obj in vars(_core).items() if callable(obj) and not inspect.isclass(obj) and not name.startswith("_")}
    assert classes == set(stub) - {""}
    assert functions == stub[""]
    for name in classes:
        members = {m for m in dir(getattr(_core, name)) if not m.startswith("_")}
        assert members == stub[name], name


def test_package_exports_and_typing_marker():
    assert Path(sabre.__file__).with_name("py.typed").exists()
    for name in sabre.__all__:
        assert hasattr(sabre, name), name
    assert not any(name.startswith("_") and name != "__version__" for name in sabre.__all__)

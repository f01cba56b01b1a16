"""tools/module_cycles.py: circles found in small Rust and Python trees written here, none in a clean tree, none in
the repository."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "module_cycles.py"


def run(*roots: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(TOOL), *map(str, roots)], capture_output=True, text=True, check=False)


def write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def circle_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("circle ")]


def test_a_rust_circle_through_use_and_through_a_path_in_code_is_found_and_test_code_is_not_counted(tmp_path: Path) -> None:
    src = write(
        tmp_path / "src",
        {
            "lib.rs": "pub mod a;\npub mod b;\npub mod c;\npub mod d;\n#[cfg(test)]\nmod tests;\n",
            "a.rs": "use crate::b::{self, B};\npub struct A;\n",
            "b.rs": "pub struct B;\npub fn make() -> super::a::A {\n    super::a::A\n}\n",
            # c -> d only in a test module, a comment and a string: no arrow back from d's `use super::c`.
            "c.rs": (
                'pub struct C;\n// crate::d::D\npub const NAME: &str = "super::d::D";\n'
                "#[cfg(test)]\nmod tests {\n    use crate::d::D;\n}\n"
            ),
            "d.rs": "use super::c::C;\npub struct D(C);\n",
            # a file only the tests compile: its arrow to c would close a circle with nothing, but must not count at all
            "tests.rs": "use crate::a::A;\n",
        },
    )
    done = run(src)
    assert done.returncode == 1, done.stdout
    assert circle_lines(done.stdout) == [f"circle 1: 2 files: {src / 'a.rs'}, {src / 'b.rs'}"], done.stdout
    assert f"{src / 'b.rs'} -> {src / 'a.rs'}  (2: super::a::A; 3: super::a::A)" in done.stdout
    assert done.stdout.startswith("5 files, 3 arrows, 1 circle\n"), done.stdout


def test_a_child_that_takes_a_name_from_the_mod_rs_that_re_exports_it_closes_a_circle(tmp_path: Path) -> None:
    src = write(
        tmp_path / "src",
        {
            "lib.rs": "pub mod m;\n",
            "m/mod.rs": "mod child;\npub use child::X;\npub const G: f64 = 9.81;\n",
            "m/child.rs": "pub struct X;\npub fn g() -> f64 {\n    super::G\n}\n",
        },
    )
    done = run(src)
    assert done.returncode == 1
    assert circle_lines(done.stdout) == [f"circle 1: 2 files: {src / 'm' / 'child.rs'}, {src / 'm' / 'mod.rs'}"]
    # the same names one level down, the constant in a sibling of the child, is no circle
    write(
        src,
        {
            "m/mod.rs": "mod child;\nmod constants;\npub use child::X;\npub use constants::G;\n",
            "m/constants.rs": "pub const G: f64 = 9.81;\n",
        },
    )
    write(src, {"m/child.rs": "pub struct X;\npub fn g() -> f64 {\n    super::constants::G\n}\n"})
    assert run(src).returncode == 0


def test_a_python_circle_through_a_type_checking_import_and_a_lazy_import_is_found(tmp_path: Path) -> None:
    package = write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "a.py": "from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from .b import B\n",
            "b.py": "class B:\n    def f(self):\n        from pkg import a\n\n        return a\n",
            "c.py": "from . import a\n",
        },
    )
    done = run(package)
    assert done.returncode == 1
    assert circle_lines(done.stdout) == [f"circle 1: 2 files: {package / 'a.py'}, {package / 'b.py'}"], done.stdout
    assert f"{package / 'a.py'} -> {package / 'b.py'}  (4: from .b import B)" in done.stdout


def test_trees_whose_arrows_run_one_way_pass(tmp_path: Path) -> None:
    src = write(
        tmp_path / "src",
        {
            "lib.rs": "pub mod low;\npub mod high;\npub use high::H;\n",
            "low.rs": "pub struct L;\n",
            "high.rs": "use crate::low::L;\npub struct H(L);\nfn f() -> crate::low::L {\n    L\n}\n",
        },
    )
    package = write(
        tmp_path / "pkg",
        {"__init__.py": "from .high import H\n", "low.py": "class L: ...\n", "high.py": "from .low import L\n\nH = L\n"},
    )
    done = run(src, package)
    assert done.returncode == 0, done.stdout
    assert done.stdout.startswith("6 files, 4 arrows, 0 circles"), done.stdout


def test_an_argument_that_is_neither_a_crate_nor_a_package_is_refused(tmp_path: Path) -> None:
    done = run(tmp_path)
    assert done.returncode == 2 and "neither" in done.stderr


def test_the_repository_has_no_module_circle() -> None:
    done = run(ROOT / "src", ROOT / "python" / "sabre")
    assert done.returncode == 0, done.stdout

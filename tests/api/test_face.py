"""The package's face: `import sabre` loads none of its top floors, every public name resolves on first use
to the object its module defines, `dir` lists them, and each deprecated name warns and is its replacement."""

from __future__ import annotations

import ast
import importlib
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import sabre
import sabre.paper

INIT = Path(sabre.__file__)

# The floors above the library modules, and the optional packages behind the extras: none is the face's.
TOP_FLOORS = ("sabre.closed_loop", "sabre.experiments", "sabre.viz", "sabre.mujoco", "sabre.ros", "sabre.paper", "sabre.cli")
EXTRAS = ("mujoco", "rclpy", "matplotlib", "viser", "ray", "tqdm")


def _modules_after(code: str) -> set[str]:
    """The modules loaded once ``code`` (after ``import sabre``) ran in a fresh interpreter."""
    script = f"import json, sys\nimport sabre\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    path = os.pathsep.join([str(INIT.parents[1]), os.environ.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": path}
    )
    return set(json.loads(out.stdout.splitlines()[-1]))


def _loaded(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def test_import_sabre_loads_no_top_floor_and_no_extra():
    modules = _modules_after("")
    assert "sabre" in modules
    assert _loaded(modules, TOP_FLOORS + EXTRAS) == []


def test_the_core_classes_load_no_top_floor():
    """The controller, its inner loop and the plant are library modules: reaching them loads no closed loop,
    experiment, viewer, MuJoCo or ROS 2."""
    modules = _modules_after(
        "sabre.Scene, sabre.RolloutModel, sabre.Plant, sabre.PlantInterface, sabre.Controller, sabre.tasks.OpenObject, "
        "sabre.costs.Cost, sabre.SafetyFilter, sabre.LowLevelController, sabre.SabreError"
    )
    assert {"sabre.scene", "sabre.sim", "sabre.planner", "sabre.safety", "sabre.inner_loop"} <= modules
    assert _loaded(modules, TOP_FLOORS + EXTRAS) == []


def test_a_submodule_resolves_as_an_attribute_as_it_did_when_import_sabre_loaded_them_all():
    modules = _modules_after(
        "assert sabre.errors.SabreError is sabre.SabreError\n"
        "assert sabre.experiments.runner.__name__ == 'sabre.experiments.runner'\n"
        "assert not hasattr(sabre, 'no_such_module')"
    )
    assert "sabre.experiments" in modules


def _type_checking_imports() -> dict[str, tuple[str, str]]:
    """name -> (module, attribute) of every import in the ``if TYPE_CHECKING:`` blocks of sabre/__init__.py."""
    tree = ast.parse(INIT.read_text())
    blocks = [n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING"]
    found: dict[str, tuple[str, str]] = {}
    for node in (statement for block in blocks for statement in block.body):
        assert isinstance(node, ast.ImportFrom), ast.unparse(node)
        module = "sabre" + "." * (node.level > 0) + (node.module or "")
        for alias in node.names:
            found[alias.asname or alias.name] = (module.rstrip("."), alias.name)
    return found


def _defined(module: str, attribute: str) -> object:
    """What ``from <module> import <attribute>`` gives, without going through sabre's own attributes."""
    if module == "sabre":
        return importlib.import_module(f"sabre.{attribute}")
    imported = importlib.import_module(module)
    if hasattr(imported, attribute):
        return getattr(imported, attribute)
    return importlib.import_module(f"{module}.{attribute}")


# Each deprecated name: what it now is, and what its warning must name.
DEPRECATED = {
    "paper_start_state": (lambda: sabre.paper.paper_start_state, "sabre.paper.paper_start_state"),
    "scenarios": (lambda: sabre.paper.scenarios, "sabre.paper.scenarios"),
    "likelihood_weights": (lambda: sabre.paper.likelihood_weights, "sabre.paper.likelihood_weights"),
    "tau_ext_from_wrench": (lambda: importlib.import_module("sabre.estimation").tau_ext_from_wrench, "wrist_sensor_link"),
    "LowPass": (lambda: importlib.import_module("sabre.estimation").LowPass, "tau_ext_cutoff"),
}


def test_every_public_name_resolves_without_a_warning_to_what_type_checkers_see():
    typed = _type_checking_imports()
    assert set(typed) == set(sabre.__all__) | set(DEPRECATED)
    assert len(sabre.__all__) == len(set(sabre.__all__))
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=r"sabre\.", category=DeprecationWarning)
        for name in sabre.__all__:
            assert getattr(sabre, name) is _defined(*typed[name]), name


def test_dir_lists_every_public_name_and_no_deprecated_one():
    listed = dir(sabre)
    assert set(sabre.__all__) <= set(listed)
    assert not set(DEPRECATED) & set(listed)
    assert not set(DEPRECATED) & set(sabre.__all__)


@pytest.mark.parametrize("name", sorted(DEPRECATED))
def test_a_deprecated_name_warns_naming_its_replacement_and_is_the_same_object(name):
    replacement, named = DEPRECATED[name]
    for _ in range(2):  # not cached: every access warns
        with pytest.warns(DeprecationWarning, match=f"sabre.{name} is deprecated") as record:
            value = getattr(sabre, name)
        assert value is replacement()
        (warning,) = record
        assert named in str(warning.message)
        assert warning.filename == __file__  # the line that used the name


def test_from_sabre_import_a_deprecated_name_warns_too():
    with pytest.warns(DeprecationWarning, match="use sabre.paper.scenarios"):
        from sabre import scenarios
    assert scenarios is sabre.paper.scenarios


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Planner'"):
        _ = sabre.Planner
    assert not hasattr(sabre, "a.b")
    assert not hasattr(sabre, "__wrapped__")


def test_the_paper_module_re_exports_from_where_each_helper_lives():
    from sabre import closed_loop, planner
    from sabre.experiments import scenarios

    assert sabre.paper.__all__ == ["paper_start_state", "scenarios", "likelihood_weights"]
    assert sabre.paper.paper_start_state is closed_loop.paper_start_state
    assert sabre.paper.scenarios is scenarios
    assert sabre.paper.likelihood_weights is planner.likelihood_weights

"""The compiled module's surface: `_core.pyi` describes it (same classes, methods and attributes),
and the Python wrappers take every default that crosses into it from its config objects."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

import sabre
from sabre import _core

STUB = Path(sabre.__file__).with_name("_core.pyi")


def _stub_names() -> dict[str, set[str]]:
    tree = ast.parse(STUB.read_text())
    out: dict[str, set[str]] = {"": set()}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            methods = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
            attributes = {n.target.id for n in node.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)}
            out[node.name] = {name for name in methods | attributes if not name.startswith("_")}
        elif isinstance(node, ast.FunctionDef):
            out[""].add(node.name)
    return out


def test_stub_matches_the_compiled_module():
    stub = _stub_names()
    classes = {name for name, obj in vars(_core).items() if inspect.isclass(obj) and not name.startswith("_")}
    functions = {
        name for name, obj in vars(_core).items() if callable(obj) and not inspect.isclass(obj) and not name.startswith("_")
    }
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


# Modules whose signatures and dataclass fields hold the defaults of configs that cross into Rust.
WRAPPERS = ("sim.py", "safety.py", "planner.py", "episode.py", "closed_loop.py", "guides.py")
CONFIGS = (
    _core.RolloutConfig,
    _core.PlantConfig,
    _core.LowLevelConfig,
    _core.MppiConfig,
    _core.ServoGuideConfig,
    _core.SafetyConfig,
    _core.EnergyTankConfig,
)
# Every setting a config object carries, plus the wrappers' names for two of them.
CORE_SETTINGS = {name for config in CONFIGS for name in dir(config()) if not name.startswith("_")} | {
    "tank_initial",
    "passivity_alpha",
}


def _literal_defaults(path: Path) -> list[str]:
    """Core settings given a number as default (function parameters, dataclass fields) in one module."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            args = node.args
            positional = args.posonlyargs + args.args
            pairs = list(zip(positional[len(positional) - len(args.defaults) :], args.defaults))
            pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None]
            found += [f"{path.name}:{node.name}({a.arg})" for a, d in pairs if a.arg in CORE_SETTINGS and _is_number(d)]
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name) and item.value is not None:
                    if item.target.id in CORE_SETTINGS and _is_number(item.value):
                        found.append(f"{path.name}:{node.name}.{item.target.id}")
    return found


def _is_number(node: ast.expr) -> bool:
    if isinstance(node, ast.UnaryOp):
        node = node.operand
    if isinstance(node, ast.Tuple):
        return any(_is_number(e) for e in node.elts)
    return isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool)


@pytest.mark.parametrize("module", WRAPPERS)
def test_wrapper_defaults_are_not_written_as_numbers(module):
    assert _literal_defaults(STUB.with_name(module)) == []


def test_python_defaults_reach_the_core_unchanged():
    safety = sabre.SafetyConfig()._core_config()
    core = _core.SafetyConfig()
    for name in (
        "gamma",
        "penalty",
        "margin",
        "enabled",
        "base_box",
        "tank_floor",
        "max_obstacles",
        "max_iterations",
        "tolerance",
        "screening",
    ):
        assert getattr(safety, name) == getattr(core, name), name
    # Table I: Σ = 0.5 on the three base inputs, 1.0 on the seven arm joints.
    assert sabre.ControllerConfig().sigma_for(10) == [0.5, 0.5, 0.5] + [1.0] * 7
    assert sabre.EnergyTank().initial == _core.EnergyTankConfig().initial
    assert sabre.EnergyTank().floor == sabre.SafetyConfig().tank_floor


def test_config_objects_start_from_the_core_defaults_and_keep_what_is_set():
    first, second = _core.RolloutConfig(), _core.RolloutConfig()
    first.dt = 0.02
    assert (first.dt, second.dt) == (0.02, _core.RolloutConfig().dt)
    config = _core.MppiConfig()
    assert config.sigma is None
    config.sigma = [0.1, 0.2]
    assert config.sigma == [0.1, 0.2]

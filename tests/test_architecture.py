"""The arrows of ARCHITECTURE.md, checked on the source: what may import what."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The algorithm core is pure: no sockets, threads, processes, wall clocks, files or link libraries.
IMPURE = {"socket", "threading", "multiprocessing", "subprocess", "time", "asyncio", "select",
          "serial", "pymavlink", "mavsdk", "can", "dronecan", "smbus2", "os", "io", "pathlib", "tempfile"}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def _modules(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("path", _modules("companion"), ids=lambda p: str(p.relative_to(ROOT)))
def test_companion_never_imports_sitl_scripts_or_replay(path: Path):
    bad = {name for name in _imports(path) if name.split(".")[0] in ("sitl", "scripts", "replay")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


# The one exception: the field model reads its coefficient file once, when a model is built.
ALLOWED = {"companion/nav/field.py": {"os", "pathlib"}}


@pytest.mark.parametrize("path", _modules("companion/nav"), ids=lambda p: str(p.relative_to(ROOT)))
def test_navigation_core_is_pure(path: Path):
    allowed = ALLOWED.get(str(path.relative_to(ROOT)), set())
    bad = {name for name in _imports(path)
           if (name.split(".")[0] in IMPURE - allowed) or name.startswith("companion.io")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}: the algorithm core must stay pure"


@pytest.mark.parametrize("path", _modules("sitl"), ids=lambda p: str(p.relative_to(ROOT)))
def test_simulator_never_imports_companion_io(path: Path):
    bad = {name for name in _imports(path) if name.startswith(("companion.io", "companion.app", "scripts"))}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_world_models_are_pure():
    for path in _modules("sitl/world"):
        bad = {name for name in _imports(path) if name.split(".")[0] in IMPURE - {"os", "pathlib"}}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize("path", _modules("replay"), ids=lambda p: str(p.relative_to(ROOT)))
def test_replay_evaluation_never_imports_sitl_or_scripts(path: Path):
    """The log evaluation reads logs with companion's sources and judges with companion.nav only."""
    bad = {name for name in _imports(path) if name.split(".")[0] in ("sitl", "scripts")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize("path", [ROOT / "scripts" / "replay.py"] + _modules("replay"),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_replay_modules_stay_under_500_lines(path: Path):
    """Rooms a person can hold (issue 11): the replay package and its entry point."""
    lines = path.read_text(encoding="utf-8").count("\n")
    assert lines <= 500, f"{path.relative_to(ROOT)} has {lines} lines"


def test_replay_package_has_no_import_circle():
    """Issue 11: the replay modules import one way (any import, also inside a function)."""
    modules = {".".join(p.relative_to(ROOT).with_suffix("").parts): p for p in _modules("replay")}
    modules = {name.removesuffix(".__init__"): p for name, p in modules.items()}
    graph = {name: {m for m in _imports(p) if m in modules and m != name} for name, p in modules.items()}
    state: dict[str, int] = {}

    def visit(name: str, path: list[str]) -> None:
        state[name] = 1
        for nxt in sorted(graph.get(name, ())):
            assert state.get(nxt) != 1, "import circle: " + " -> ".join(path + [name, nxt])
            if nxt not in state:
                visit(nxt, path + [name])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])

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
def test_companion_never_imports_sitl_or_scripts(path: Path):
    bad = {name for name in _imports(path) if name.split(".")[0] in ("sitl", "scripts", "fcmpc_fly")}
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
    bad = {name for name in _imports(path) if name.startswith(("companion.io", "companion.app", "scripts",
                                                                 "fcmpc_fly"))}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize("path", _modules("fcmpc_fly"), ids=lambda p: str(p.relative_to(ROOT)))
def test_fly_library_never_imports_scripts_or_the_companion_process(path: Path):
    """fcmpc_fly runs the companion as a process and reads its records; scripts/ are entry points."""
    bad = {name for name in _imports(path) if name.split(".")[0] == "scripts" or name == "companion.app"}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_world_models_are_pure():
    for path in _modules("sitl/world"):
        bad = {name for name in _imports(path) if name.split(".")[0] in IMPURE - {"os", "pathlib"}}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"

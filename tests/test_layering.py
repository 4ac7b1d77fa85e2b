"""The numerical cores are pure: no rclpy, no clocks (ARCHITECTURE.md, layer 'core')."""

from __future__ import annotations

import ast
import subprocess
import sys

from conftest import ROOT

CORE_DIRS = [ROOT / "src" / "sappc_controller" / "core", ROOT / "src" / "spacecraft_sim" / "core"]
CORE_MODULES = sorted(
    ".".join(p.relative_to(ROOT / "src").with_suffix("").parts)
    for d in CORE_DIRS
    for p in d.glob("*.py")
)


def test_core_modules_exist() -> None:
    assert "sappc_controller.core.sappc" in CORE_MODULES and "spacecraft_sim.core.dynamics" in CORE_MODULES


def test_importing_every_core_module_does_not_import_rclpy() -> None:
    code = "import sys\n" + "".join(f"import {m}\n" for m in CORE_MODULES) + "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout


def _imported_names(path) -> set[str]:  # type: ignore[no-untyped-def]
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_core_sources_import_only_numpy_scipy_and_the_cores() -> None:
    allowed = {"__future__", "numpy", "scipy", "dataclasses", "typing", "abc", "enum", "math", "collections", "sappc_controller", "spacecraft_sim"}
    for d in CORE_DIRS:
        for p in d.glob("*.py"):
            extra = _imported_names(p) - allowed
            assert not extra, f"{p.relative_to(ROOT)} imports {sorted(extra)}"


def test_core_sources_read_no_clock() -> None:
    for d in CORE_DIRS:
        for p in d.glob("*.py"):
            names = _imported_names(p)
            assert not names & {"time", "datetime"}, f"{p.relative_to(ROOT)} imports a clock module"

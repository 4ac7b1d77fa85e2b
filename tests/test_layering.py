"""The layering of the house (docs/architecture.md), enforced on every import in ``src/``.

Rooms stand on floors; a module may import its own room and rooms on lower floors only, never a
room beside it or above it.  On top of that:

- the ground (``gnc_common``) and the numerical cores import no ROS and read no clock;
- the controller (flight software) and the topic contract never import the simulator, and the
  simulator never imports the controller;
- ``rclpy`` is imported only by the node modules, the contract's node runtime and ``sappc.graph``.

Imports are read from the source (every ``import`` statement, also those inside functions), so a
lazy import cannot hide a wrong-way arrow.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

SRC = ROOT / "src"
PROJECT = ("gnc_common", "sappc_controller", "sappc_estimator", "sappc_momentum", "sappc_modes", "spacecraft_sim", "sappc_msgs_py", "sappc")

#: Room (a module prefix; the longest match wins) -> floor.
FLOORS: dict[str, int] = {
    "gnc_common": 0,
    "sappc_controller.core": 1,
    "sappc_estimator.core": 1,
    "sappc_momentum.core": 1,
    "sappc_modes.core": 1,
    "spacecraft_sim.core": 1,
    "sappc_msgs_py": 1,
    "sappc_controller": 2,
    "sappc_estimator": 2,
    "sappc_momentum": 2,
    "sappc_modes": 2,
    "spacecraft_sim": 2,
    "sappc.files": 2,  # the bundled data files and the default output directories: the scenario loader finds its files there
    "sappc.controllers": 2,  # the controllers' names: the scenario's and the command line's choices (which import no scenario)
    "sappc.scenario": 3,
    "sappc.evaluation": 4,
    "sappc.offline": 5,
    "sappc.bag": 5,
    "sappc.analysis": 6,
    "sappc.montecarlo": 7,
    "sappc.graph": 7,
    "sappc.cli": 8,
    "sappc.__main__": 9,
    "sappc": 9,
}
#: Pairs of packages that must never meet, whatever their floors.
#: The flight software (controller, estimator) never meets the simulator, nor the controller the
#: estimator (each takes the contract's topics only).
NEVER = {("sappc_controller", "spacecraft_sim"), ("spacecraft_sim", "sappc_controller"), ("sappc_msgs_py", "spacecraft_sim"),
         ("sappc_estimator", "spacecraft_sim"), ("spacecraft_sim", "sappc_estimator"), ("sappc_estimator", "sappc_controller"),
         ("sappc_controller", "sappc_estimator"), ("sappc_momentum", "spacecraft_sim"), ("spacecraft_sim", "sappc_momentum"),
         ("sappc_momentum", "sappc_controller"), ("sappc_momentum", "sappc_estimator"),
         ("sappc_modes", "spacecraft_sim"), ("spacecraft_sim", "sappc_modes"), ("sappc_modes", "sappc_controller"),
         ("sappc_modes", "sappc_estimator"), ("sappc_modes", "sappc_momentum")}
#: The modules that may import rclpy: nodes, the contract's node runtime (and its QoS), the graph tools.
# sappc_msgs_py.wire: rclpy's deserializer for what its codecs do not take (imported in the function
# that uses it, so the offline bag writer, which imports the layouts, loads no rclpy: tested below)
ROS_MODULES = ("sappc_msgs_py.runtime", "sappc_msgs_py.contract", "sappc_msgs_py.wire", "sappc_controller.node", "sappc_estimator.node", "sappc_momentum.node", "sappc_modes.node", "spacecraft_sim.plant_node",
               "spacecraft_sim.reference", "spacecraft_sim.disturbance", "sappc.graph")
PURE_ROOMS = ("gnc_common", "sappc_controller.core", "sappc_estimator.core", "sappc_momentum.core", "sappc_modes.core", "spacecraft_sim.core")
CLOCK_MODULES = {"time", "datetime"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PROJECT for p in (SRC / pkg).rglob("*.py")}


def _imports(name: str, path: Path) -> set[str]:
    """Every module that ``path`` imports, relative imports resolved."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.add(module)
            found.update(f"{module}.{a.name}" for a in node.names if f"{module}.{a.name}" in MODULES)
    return found


def _room(module: str) -> str | None:
    matches = [r for r in FLOORS if module == r or module.startswith(r + ".")]
    return max(matches, key=len) if matches else None


def _in(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


MODULES = _modules()
IMPORTS = {name: _imports(name, path) for name, path in MODULES.items()}


def test_every_source_module_is_in_a_room() -> None:
    assert "sappc_controller.core.sappc" in MODULES and "gnc_common.attitude" in MODULES
    assert [m for m in MODULES if _room(m) is None] == []


def test_nothing_imports_sideways_or_upward() -> None:
    wrong = []
    for name, imported in IMPORTS.items():
        room = _room(name)
        for target in imported:
            target_room = _room(target)
            if target_room is None or target_room == room:
                continue
            if FLOORS[target_room] >= FLOORS[room]:  # type: ignore[index]  # every module has a room (test above)
                wrong.append(f"{name} ({room}, floor {FLOORS[room]}) imports {target} ({target_room}, floor {FLOORS[target_room]})")  # type: ignore[index]
    assert wrong == []


def test_the_controller_and_the_contract_never_import_the_simulator() -> None:
    wrong = [f"{name} imports {target}" for name, imported in IMPORTS.items() for target in imported
             for a, b in NEVER if _in(name, a) and _in(target, b)]
    assert wrong == []


def test_ground_and_cores_import_no_ros_no_tools_and_no_clock() -> None:
    wrong = []
    for name, imported in IMPORTS.items():
        if not any(_in(name, r) for r in PURE_ROOMS):
            continue
        for target in imported:
            top = target.split(".")[0]
            if top in CLOCK_MODULES or top in ("rclpy", "sappc", "sappc_msgs_py") or top.endswith("_msgs"):
                wrong.append(f"{name} imports {target}")
    assert wrong == []


def test_only_nodes_and_the_graph_tools_import_rclpy() -> None:
    wrong = [name for name, imported in IMPORTS.items()
             if any(t.split(".")[0] == "rclpy" for t in imported) and not any(_in(name, m) for m in ROS_MODULES)]
    assert wrong == []


@pytest.mark.parametrize("room", [*PURE_ROOMS, "sappc.offline", "sappc.montecarlo", "sappc.bag", "sappc.analysis"])
def test_importing_a_room_does_not_load_rclpy(room: str) -> None:
    modules = sorted(m for m in MODULES if _in(m, room))
    code = "import sys\n" + "".join(f"import {m}\n" for m in modules) + \
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_checker_sees_a_wrong_way_import(tmp_path: Path) -> None:
    """The rules above fail on a planted violation (a controller module importing the simulator)."""
    planted = tmp_path / "src" / "sappc_controller" / "core" / "bad.py"
    planted.parent.mkdir(parents=True)
    planted.write_text("from spacecraft_sim.core import dynamics\nimport time\n")
    imported = _imports("sappc_controller.core.bad", planted)
    assert "spacecraft_sim.core.dynamics" in imported or "spacecraft_sim.core" in imported
    assert any(_in("sappc_controller.core.bad", a) and _in(t, b) for t in imported for a, b in NEVER)
    assert FLOORS[_room("spacecraft_sim.core.dynamics")] >= FLOORS[_room("sappc_controller.core.bad")]  # type: ignore[index]


def test_every_module_with_compiled_functions_is_in_the_cache_digest() -> None:
    """The numba cache directory is named by a digest of the kernel modules' sources
    (``gnc_common.compiled.KERNEL_MODULES``): a module with ``@jit`` functions missing from that list
    could run a stale cached kernel after an edit."""
    from gnc_common.compiled import KERNEL_MODULES

    uses_jit = {name for name, path in MODULES.items()
                if any(isinstance(d, ast.Name) and d.id in ("jit", "jit_parallel") or
                       isinstance(d, ast.Call) and isinstance(d.func, ast.Name) and d.func.id in ("jit", "jit_parallel")
                       for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.FunctionDef)
                       for d in node.decorator_list)}
    assert uses_jit and uses_jit <= set(KERNEL_MODULES), sorted(uses_jit - set(KERNEL_MODULES))

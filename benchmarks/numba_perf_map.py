"""Run ``sappc`` with numba's compiled kernels named for ``perf`` (a profiling aid, not a timing).

    perf record -F 4000 -o perf.data -- .venv/bin/python benchmarks/numba_perf_map.py montecarlo \\
        config/scenarios/paper_tracking_flight.yaml --runs 500 --out /tmp/mc
    perf report -i perf.data --no-children --sort pid,sym

numba loads its kernels' machine code from its cache into anonymous memory, which ``perf`` shows
as bare addresses.  ``perf`` reads ``/tmp/perf-PID.map`` (one ``START SIZE NAME`` line a function)
for such code; this script writes that file in every process of the command (the campaign's
workers included: they are forked with the patches in place) after the loops' kernels are loaded
(the start's probe, the first block of the per-run loop or of the lanes).  Each function's address
comes from numba's own symbol table (``get_pointer_to_function``), its size from ``nm`` on the
object code numba loaded, which this script keeps (numba drops it once loaded).  It patches
numba's private ``CPUCodeLibrary._set_compiled_object``: a measurement aid for numba 0.68, not
product code.  The maps are left in ``/tmp`` (``perf report`` needs them); remove them after.

Used for docs/performance.md, "The covariance's sums side by side; issue 50's rows on the final
code" (where a flight worker's time goes).
"""

from __future__ import annotations

import functools
import gc
import importlib.abc
import importlib.machinery
import os
import subprocess
import sys
import tempfile
from types import ModuleType
from typing import Any


def _keep_object_code(codegen: ModuleType) -> None:
    """Keep each library's object code as numba hands it over (``_stash``)."""
    original = codegen.CPUCodeLibrary._set_compiled_object

    def keep(self: Any, value: bytes) -> None:
        self._stash = value
        original(self, value)

    codegen.CPUCodeLibrary._set_compiled_object = keep


def write_perf_map() -> int:
    """Write ``/tmp/perf-<pid>.map`` for every function of every kernel this process has loaded;
    return how many."""
    from numba.core.dispatcher import Dispatcher

    libraries = {id(cres.library): cres.library for obj in gc.get_objects() if isinstance(obj, Dispatcher)  # type: ignore[attr-defined]
                 for cres in obj.overloads.values()}
    lines = []
    for library in libraries.values():
        code = getattr(library, "_stash", None)
        if code is None:
            continue
        with tempfile.NamedTemporaryFile(suffix=".o", delete=False) as f:
            f.write(code)
        try:
            table = subprocess.run(["nm", "-S", "--defined-only", f.name], capture_output=True, text=True, check=True).stdout
        finally:
            os.unlink(f.name)
        for row in table.splitlines():
            parts = row.split()
            if len(parts) == 4 and parts[2] in "tTwW":  # functions (the weak ones are the inlined kernels' copies)
                try:
                    address = library.get_pointer_to_function(parts[3])
                except Exception:  # a symbol the engine did not keep
                    continue
                if address:
                    lines.append(f"{address:x} {int(parts[1], 16):x} {parts[3]}\n")
    with open(f"/tmp/perf-{os.getpid()}.map", "w") as out:
        out.writelines(lines)
    return len(lines)


def _after(module: ModuleType, name: str, once: bool) -> None:
    """Write the map after ``module.name`` returns (after its first call only, with ``once``)."""
    function = getattr(module, name)
    calls: list[int] = []

    @functools.wraps(function)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        try:
            return function(*args, **kwargs)
        finally:
            if not (once and calls):
                calls.append(1)
                write_perf_map()

    setattr(module, name, wrapped)


def _on_compiled_loop(module: ModuleType) -> None:
    _after(module, "load_before_fork", once=False)
    _after(module, "_loop", once=True)
    _after(module, "_loop_lanes", once=True)


_HOOKS = {"numba.core.codegen": _keep_object_code, "sappc.offline.compiled_loop": _on_compiled_loop}


class _PatchOnImport(importlib.abc.MetaPathFinder):
    """Patch the modules of :data:`_HOOKS` as they are imported: importing numba here, before
    ``sappc`` starts, would keep ``sappc montecarlo`` from forking its figure worker."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name not in _HOOKS:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return None
        execute = spec.loader.exec_module

        def exec_module(module: ModuleType) -> None:
            execute(module)
            _HOOKS[name](module)

        spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


if __name__ == "__main__":
    sys.meta_path.insert(0, _PatchOnImport())
    from sappc import cli

    sys.exit(cli.main(sys.argv[1:]))

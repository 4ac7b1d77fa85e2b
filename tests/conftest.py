"""Shared test helpers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"
#: The ``sappc`` command, run with the test interpreter.
SAPPC = [sys.executable, "-m", "sappc"]


def shm_files() -> set[str]:
    """Fast DDS shared-memory files in /dev/shm (a finished run must leave none of its own)."""
    return {p.name for p in Path("/dev/shm").glob("fastrtps_*")} | {p.name for p in Path("/dev/shm").glob("fast_datasharing*")}


def abandoned_shm(names: set[str]) -> list[str]:
    """The Fast DDS shared-memory segments among ``names`` (from :func:`shm_files`) that no live
    process holds: a process that stops cleanly removes its segments, one that dies leaves them
    with their lock file (``<segment>_el``) free.  Unlike comparing :func:`shm_files` before and
    after, this does not depend on what other runs on the machine (other sessions' tests) hold."""
    import fcntl
    import os

    out = []
    for name in sorted(n for n in names if n.endswith("_el")):
        try:
            fd = os.open(f"/dev/shm/{name}", os.O_RDWR)
        except FileNotFoundError:
            continue  # removed meanwhile
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            out.append(name)
        except OSError:
            pass  # held by a live process
        finally:
            os.close(fd)
    return out


@pytest.fixture(scope="session")
def tracking_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    """Experiment 1 through ``sappc run`` (60 s lockstep, recorded): (run dir, its JSON, /dev/shm before)."""
    out = tmp_path_factory.mktemp("graph") / "run"
    before = shm_files()
    proc = subprocess.run([*SAPPC, "run", str(SCENARIOS / "paper_tracking.yaml"), "--out", str(out), "--json", str(out.parent / "m.json")],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, json.loads((out.parent / "m.json").read_text()), before


def random_unit_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniformly distributed unit quaternions (x, y, z, w), shape (n, 4)."""
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261122)


@pytest.fixture
def ros_context(tmp_path, monkeypatch):  # type: ignore[no-untyped-def]
    """rclpy initialised on a domain of its own (claimed with a lock file, LOCALHOST discovery,
    the project's Fast DDS profile, logs under tmp_path); shut down afterwards."""
    import rclpy

    from sappc.graph.launch import claim_domain_id, isolated_environment

    with claim_domain_id() as domain:
        for key, value in isolated_environment(domain, tmp_path / "roslog", base={}).items():
            monkeypatch.setenv(key, value)
        context = rclpy.context.Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            yield context
        finally:
            rclpy.try_shutdown(context=context)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the numerical core once before any test when the cache is cold (after an edit of a
    kernel; ``./sappcw`` compiles it when it builds the venv): no test then sees the one-line
    compile notice or pays the compile inside its own time limits."""
    from sappc.offline.compiled_loop import ensure_compiled

    ensure_compiled()

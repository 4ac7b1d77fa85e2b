"""Shared test helpers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import MutableMapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from shm_watch import ShmWatch

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"
#: The ``sappc`` command, run with the test interpreter.
SAPPC = [sys.executable, "-m", "sappc"]


def run_watched(cmd: list[str], *, timeout_s: float = 600, **kwargs: Any) -> tuple[subprocess.CompletedProcess[str], ShmWatch]:
    """``subprocess.run(cmd)`` (text output captured, in the repository root) with a
    :class:`~shm_watch.ShmWatch` on the process and its descendants: (the finished process, the watch)."""
    with ShmWatch() as watch:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=kwargs.pop("cwd", ROOT), **kwargs)
        watch.add(proc.pid)
        try:
            stdout, stderr = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            stdout, stderr = proc.communicate()
            raise
    return subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr), watch


def cli_commands(parser: Any, prefix: str = "") -> dict[str, Any]:
    """Every (sub)command of an ``argparse`` parser by its name (``scenarios copy`` for a nested one)."""
    import argparse

    out: dict[str, Any] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[f"{prefix}{name}"] = sub
                out.update(cli_commands(sub, f"{prefix}{name} "))
    return out


def cut_short(raw: dict[str, Any], duration_s: float) -> dict[str, Any]:
    """The scenario mapping ``raw``, changed in place to last ``duration_s``, without its
    ``metrics.requirements``: a run cut short cannot show what the whole run promises (it ends before
    its settling time or steady window, and an unknown metric fails a requirement); the
    loss-of-control rule still judges it (:mod:`sappc.evaluation.requirements`)."""
    raw["duration_s"] = duration_s
    (raw.get("metrics") or {}).pop("requirements", None)
    return raw


@pytest.fixture(scope="session")
def tracking_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    """Experiment 1 through ``sappc run`` (60 s lockstep, recorded): (run dir, its JSON, the
    shared-memory watch of its processes)."""
    out = tmp_path_factory.mktemp("graph") / "run"
    proc, watch = run_watched([*SAPPC, "run", str(SCENARIOS / "paper_tracking.yaml"), "--out", str(out), "--json", str(out.parent / "m.json")])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, json.loads((out.parent / "m.json").read_text()), watch


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


def keep_off_the_users_domain(environ: MutableMapping[str, str]) -> int | None:
    """Make the suite's ROS work keep off the domain of the user's other ROS work.

    ``ROS_DOMAIN_ID`` in the environment is the user's (a robot, a simulator running beside the
    tests): it is removed from ``environ``, so the ``sappc run`` and nodes the tests start claim a
    domain of their own instead of joining it, and it is taken out of the ids they claim from
    (:data:`~sappc.graph.launch.DOMAIN_IDS_ENV`, inherited by every process the tests start).
    Returns the user's domain (``None`` when none was set).
    """
    from sappc.graph.launch import DOMAIN_IDS_ENV, domain_ids, format_domain_ids, requested_domain_id

    text = environ.pop("ROS_DOMAIN_ID", "").strip()
    if not text:
        return None
    user = requested_domain_id(None, {"ROS_DOMAIN_ID": text})[0]
    assert user is not None
    ids = [i for i in domain_ids(environ) if i != user]
    if not ids:
        raise pytest.UsageError(f"{DOMAIN_IDS_ENV} leaves the suite no domain id but ROS_DOMAIN_ID={user}, which is yours")
    environ[DOMAIN_IDS_ENV] = format_domain_ids(ids)
    return user


def pytest_configure(config: pytest.Config) -> None:
    """Before any test: keep the suite off the user's ROS domain (:func:`keep_off_the_users_domain`)."""
    keep_off_the_users_domain(os.environ)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the numerical core once before any test when the cache is cold (after an edit of a
    kernel; ``./sappcw`` compiles it when it builds the venv): no test then sees the one-line
    compile notice or pays the compile inside its own time limits."""
    from sappc.offline.compiled_loop import WARM_UP_GROUPS, ensure_compiled

    ensure_compiled(groups=WARM_UP_GROUPS, in_subprocess=True)  # the nodes' kernels too (ROS tests' time limits); in parallel

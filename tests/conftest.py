"""Shared test helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"


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

    from sappc.graph import claim_domain_id, isolated_environment

    with claim_domain_id() as domain:
        for key, value in isolated_environment(domain, tmp_path / "roslog", base={}).items():
            monkeypatch.setenv(key, value)
        context = rclpy.context.Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            yield context
        finally:
            rclpy.try_shutdown(context=context)

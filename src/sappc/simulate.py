"""Run a scenario offline: build the cores from the scenario, run the closed loop, compute metrics."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from spacecraft_sim.core.dynamics import RigidBody, initial_state

from .closed_loop import History, HistoryRecorder, both, run_closed_loop, step_times
from .metrics import MetricsAccumulator
from .scenario import ControllerKind, Scenario

__all__ = ["SimulationResult", "metrics_accumulator", "simulate"]


@dataclass(frozen=True)
class SimulationResult:
    """A finished offline run: its history, metrics and the parameters that produced it."""

    scenario: Scenario
    controller: ControllerKind
    history: History
    metrics: dict[str, Any]

    def report(self) -> dict[str, Any]:
        """JSON-ready summary: metrics, controller, and every parameter used."""
        config = self.scenario.controller_config(self.controller)
        return {
            "scenario": self.scenario.name,
            "controller": self.controller.value,
            "metrics": self.metrics,
            "parameters": {
                "scenario": self.scenario.raw,
                "controller": _jsonable(dataclasses.asdict(config)),
            },
        }


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def simulate(scenario: Scenario, controller: ControllerKind | str | None = None) -> SimulationResult:
    """Run ``scenario`` with ``controller`` (default: the scenario's) and compute its metrics.

    ``metrics["wall_time_s"]`` is the wall time of the closed loop (reference
    generation and model set-up included, file output excluded).
    """
    kind = scenario.resolve_controller(controller)
    start = time.perf_counter()
    ctrl = scenario.build_controller(kind)
    plant = RigidBody(scenario.inertia_kg_m2)
    t = step_times(scenario.duration_s, scenario.control_period_s)
    recorder = HistoryRecorder(t, 1)
    metrics = metrics_accumulator(scenario, t, 1)
    run_closed_loop(
        plant,
        ctrl,
        scenario.reference.sample(t),
        scenario.disturbance,
        initial_state(scenario.q_BN0, scenario.omega_BN_B0_rad_s),
        scenario.control_period_s,
        substeps=scenario.rk4_substeps,
        observer=both(recorder, metrics),
    )
    wall = time.perf_counter() - start
    history = recorder.history()
    result = metrics.run_metrics(0)
    result["wall_time_s"] = wall
    return SimulationResult(scenario=scenario, controller=kind, history=history, metrics=result)


def metrics_accumulator(scenario: Scenario, t: np.ndarray, n_runs: int) -> MetricsAccumulator:
    """A :class:`MetricsAccumulator` with the scenario's metric settings and fault windows."""
    ms = scenario.metrics
    return MetricsAccumulator(
        t,
        n_runs,
        steady_from_s=ms.steady_from_s,
        settle_threshold=ms.settle_threshold,
        t2_s=ms.t2_s,
        fault_windows=scenario.disturbance.events(),
    )

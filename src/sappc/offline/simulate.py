"""Run a scenario offline: build the cores from the scenario, run the closed loop, compute metrics."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from collections.abc import Callable
from typing import Any

import numpy as np

from sappc_controller.core.base import AttitudeController
from spacecraft_sim.core.disturbance import DisturbanceModel
from spacecraft_sim.core.dynamics import RigidBody, initial_state
from gnc_common.validation import ConfigError

from sappc.evaluation.history import History, HistoryRecorder, Observer, both
from sappc.offline.closed_loop import run_closed_loop, step_times
from sappc.evaluation.metrics import MetricsAccumulator
from sappc.scenario import ControllerKind, Scenario

__all__ = ["SimulationResult", "metrics_accumulator", "run_scenario", "simulate"]


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


def run_scenario(
    scenario: Scenario,
    *,
    controller: ControllerKind | str | None = None,
    controller_config: Any = None,
    controller_options: dict[str, Any] | None = None,
    q_BN0: np.ndarray | None = None,
    omega_BN_B0_rad_s: np.ndarray | None = None,
    inertia_kg_m2: np.ndarray | None = None,
    disturbance: DisturbanceModel | None = None,
    measure: Callable[[int, np.ndarray], np.ndarray] | None = None,
    observer: Observer | None = None,
    history: HistoryRecorder | None = None,
) -> tuple[MetricsAccumulator, AttitudeController]:
    """Run the scenario's closed loop, for one run or a batch: the one place that assembles it.

    Every argument overrides the scenario's own value; the batch size is that of ``q_BN0``
    (shape (N, 4)) or 1.  Used by :func:`simulate` (one run, the scenario as written) and by
    Monte Carlo campaigns (dispersed initial states, inertias, disturbances, gains, sensors).

    With ``history`` (a recorder of every sample) the metrics are computed from the stored
    history in one block after the run; without, the accumulator observes sample by sample (no
    history kept: campaigns).  Both give the same metrics, bit for bit
    (``tests/test_bag_tools.py``); one block costs a fraction of 6000 single-sample updates.

    Returns
    -------
    metrics : MetricsAccumulator
        Filled with every sample of every run.
    controller : AttitudeController
        The controller after the run (e.g. for its RPF's clamped/flat components).
    """
    if scenario.faults:
        raise ConfigError(
            f"scenario {scenario.name!r} has faults: they are injected by relaying topics on the ROS 2 graph; "
            "run it with `sappc run` (the offline runner has only disturbance torques)"
        )
    q0 = np.atleast_2d(scenario.q_BN0 if q_BN0 is None else q_BN0)
    x0 = initial_state(q0, scenario.omega_BN_B0_rad_s if omega_BN_B0_rad_s is None else omega_BN_B0_rad_s)
    ctrl = scenario.build_controller(controller, config=controller_config, **(controller_options or {}))
    t = step_times(scenario.duration_s, scenario.control_period_s)
    metrics = metrics_accumulator(scenario, t, x0.shape[0])
    observers: list[Observer] = [metrics if history is None else history] + ([] if observer is None else [observer])
    run_closed_loop(
        RigidBody(scenario.inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2),
        ctrl,
        scenario.reference.sample(t),
        scenario.disturbance if disturbance is None else disturbance,
        x0,
        scenario.control_period_s,
        substeps=scenario.rk4_substeps,
        observer=both(*observers),
        measure=measure,
    )
    if history is not None:
        metrics.add_history(history.history())
    return metrics, ctrl


def simulate(scenario: Scenario, controller: ControllerKind | str | None = None) -> SimulationResult:
    """Run ``scenario`` with ``controller`` (default: the scenario's) and compute its metrics.

    ``metrics["wall_time_s"]`` is the wall time of the closed loop (reference
    generation and model set-up included, file output excluded).
    """
    kind = scenario.resolve_controller(controller)
    start = time.perf_counter()
    recorder = HistoryRecorder(step_times(scenario.duration_s, scenario.control_period_s), 1)
    metrics, _ = run_scenario(scenario, controller=kind, history=recorder)
    result = metrics.run_metrics(0)
    result["wall_time_s"] = time.perf_counter() - start
    return SimulationResult(scenario=scenario, controller=kind, history=recorder.history(), metrics=result)


def metrics_accumulator(scenario: Scenario, t: np.ndarray, n_runs: int) -> MetricsAccumulator:
    """A :class:`MetricsAccumulator` with the scenario's metric settings and fault windows."""
    ms = scenario.metrics
    return MetricsAccumulator(
        t,
        n_runs,
        steady_from_s=ms.steady_from_s,
        settle_threshold=ms.settle_threshold,
        t2_s=ms.t2_s,
        fault_windows=scenario.event_windows(),
    )

"""The memory a run's sample takes (issue 47): :func:`sappc.scenario.scenario_bytes_per_sample`, what
:func:`~sappc.scenario.check_run_fits_in_memory` refuses a long run by, is what the offline loop
allocates.

At the end of the compiled loop, a run's peak (``benchmarks/bench_memory.py --breakdown``), the
arrays alive are the loop's inputs and its record; their bytes grow with the run's duration by the
estimate a sample, for every kind of scenario (the paper's, wheels, sensors and the MEKF, a fault, an
orbit with rods and a magnetometer, a random disturbance, a noise fault)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sappc.files import scenario_path
from sappc.offline import compiled_loop
from sappc.scenario import RUN_BYTES_PER_SAMPLE, read_scenario_mapping, scenario_bytes_per_sample, scenario_from_mapping

#: Two durations [s]: the difference of their arrays' bytes over the difference of their samples is
#: the bytes a sample (the arrays of fixed size cancel).
DURATIONS_S = (20.0, 40.0)


def _nbytes(obj: Any) -> int:
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if hasattr(obj, "_fields"):
        return sum(_nbytes(getattr(obj, f)) for f in obj._fields)
    return 0


def _loop_bytes(raw: dict[str, Any]) -> tuple[int, int, int]:
    """The bytes of the loop's inputs and its record for one run of ``raw``, its samples, and the
    scenario's estimate a sample."""
    scenario = scenario_from_mapping(raw)
    inp = compiled_loop.prepare(scenario)
    rec = compiled_loop._record(inp, 1, 1)
    return sum(_nbytes(getattr(inp, m)) for m in ("grid", *inp.MODELS)) + _nbytes(rec), inp.t.size, scenario_bytes_per_sample(scenario)


def _with(name: str, **changes: Any) -> dict[str, Any]:
    raw = read_scenario_mapping(scenario_path(name))
    raw.update(changes)
    return raw


@pytest.mark.parametrize("raw", [
    _with("paper_tracking"),
    _with("paper_tracking_wheels"),
    _with("paper_tracking_flight"),
    _with("paper_fault"),
    _with("paper_tracking_orbit"),
    _with("paper_tracking", disturbances=[{"kind": "paper_periodic", "omega_p_rad_s": 0.01},
                                          {"kind": "random", "sigma_Nm": [1e-3, 1e-3, 1e-3], "hold_s": 0.01, "seed": 1}],
          faults=[{"kind": "sensor_noise", "start_s": 1.0, "end_s": 2.0, "attitude_std_rad": 1e-4, "rate_std_rad_s": 1e-5, "seed": 3}]),
], ids=["paper", "wheels", "flight", "fault", "orbit", "random_and_noise_fault"])
def test_the_estimate_a_sample_is_what_the_loop_allocates(raw: dict[str, Any]) -> None:
    (b0, t0, est), (b1, t1, _) = (_loop_bytes({**raw, "duration_s": d}) for d in DURATIONS_S)
    measured = (b1 - b0) / (t1 - t0)
    assert measured <= est <= measured + 1.0, (measured, est)  # the magnetometer's draws rounded up to a byte


def test_the_paper_scenario_costs_the_base_estimate() -> None:
    assert scenario_bytes_per_sample(scenario_from_mapping(_with("paper_tracking"))) == RUN_BYTES_PER_SAMPLE == 521

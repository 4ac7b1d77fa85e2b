"""A run whose first valid input arrives after t = 0 (issue 25, 2.1 and 2.2), offline.

The rule (docs/how-to/faults.md, "A run starts at the first valid sample"; :mod:`sappc.offline.compiled_loop`): a controller
cannot know the initial error before it has a state, so its run starts at its **first valid
sample**: the performance function's time origin is that sample's time, and its start constants
(each component's sign and, with ``rpf.rho_e0`` left out, its initial magnitude) come from that
sample's error.  Before it, there is no answer to hold: every sample is answered with zero torque
by the watchdog, and the controller has no performance function and no band (its diagnostics
rows are NaN, and the metrics count such a sample as outside the constraint).

The offline loop is checked against the controller core driven sample by sample as the node drives
it (:meth:`AttitudeController.step` on each valid sample, the first one starting the run): the
same torques and rows, bit for bit (the same compiled kernel on the same host).  The graph against
the offline loop for these cases is ``tests/tools/graph/test_faults_graph.py``.
"""

from __future__ import annotations

import re

import copy

import numpy as np
import pytest
import yaml

from sappc.offline import compiled_loop
from sappc.offline.simulate import simulate
from sappc.scenario import scenario_from_mapping
from sappc_controller.core.kernels import O_BL, O_BU, O_CMD, O_EPS, O_QBR, O_RHO, O_TORQUE, O_V, O_Z
from spacecraft_sim.core.faults import faults_from_list
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_WATCHDOG_ZERO

from conftest import SCENARIOS

BASE = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
#: The outage's end [s] and the first valid sample's index (at dt = 0.01 s).
OUTAGE_END_S, FIRST_VALID = 0.5, 50
#: A measured rate far beyond the default plausibility bound (10 rad/s), which the law would turn
#: into a saturated torque.
IMPLAUSIBLE_RATE_RAD_S = 1.0e3

#: Outages at t = 0 on each input path: the state (attitude and rate: a dropout), the rate alone
#: (an implausible value: the sensor bias), the reference (attitude, rate and acceleration).
OUTAGES = {
    "state": {"kind": "sensor_dropout", "start_s": 0.0, "end_s": OUTAGE_END_S},
    "rate": {"kind": "sensor_bias", "start_s": 0.0, "end_s": OUTAGE_END_S, "rate_bias_rad_s": [IMPLAUSIBLE_RATE_RAD_S, 0.0, 0.0]},
    "reference": {"kind": "reference_dropout", "start_s": 0.0, "end_s": OUTAGE_END_S},
}


def _raw(fault: dict | None, duration_s: float = 2.0, rho_e0: float | None = 0.4) -> dict:  # type: ignore[type-arg]
    raw = copy.deepcopy(BASE)
    raw["duration_s"] = duration_s
    raw["faults"] = [fault] if fault is not None else []
    if rho_e0 is None:
        raw["controllers"]["sappc"]["rpf"]["rho_e0"] = None  # each component's initial magnitude: that of the first valid sample
        raw["controllers"]["sappc"]["rpf"]["l"] = 0.2  # feasible for every component's start (the Monte Carlo's l)
    return raw


@pytest.mark.parametrize("rho_e0", [0.4, None])
@pytest.mark.parametrize("path", list(OUTAGES))
def test_the_controller_starts_at_its_first_valid_sample_as_the_core_driven_like_the_node(path: str, rho_e0: float | None) -> None:
    scenario = scenario_from_mapping(_raw(OUTAGES[path], rho_e0=rho_e0))
    inp = compiled_loop.prepare(scenario)
    run = compiled_loop.run_single(inp, 0, 1)
    status, out, x = run.status[0], run.out[0], run.x[0]
    np.testing.assert_array_equal(status[:FIRST_VALID], ANSWER_WATCHDOG_ZERO)  # nothing to hold before the first state
    np.testing.assert_array_equal(status[FIRST_VALID:], ANSWER_COMMANDED)
    np.testing.assert_array_equal(out[:FIRST_VALID, O_TORQUE, :3], 0.0)
    np.testing.assert_array_equal(out[:FIRST_VALID, O_CMD, :3], 0.0)
    for row in (O_RHO, O_BL, O_BU, O_EPS, O_Z, O_V):  # no performance function yet
        assert np.isnan(out[:FIRST_VALID, row, :3]).all(), row
    # the core, stepped on each valid sample with what the controller receives there (no noise, so
    # the true state; the rate bias's window is closed from the first valid sample on)
    ctrl = scenario.build_controller()
    for k in range(FIRST_VALID, inp.t.size):
        got = ctrl.step(int(inp.grid.t_ns[k]) / 1e9, inp.grid.dt, x[k, :4], x[k, 4:], inp.grid.ref_q[k], inp.grid.ref_w[k], inp.grid.ref_wd[k])
        assert np.array_equal(got.torque_cmd_B, out[k, O_CMD, :3]) and np.array_equal(got.rho, out[k, O_RHO, :3]), k
        assert np.array_equal(got.band_lower, out[k, O_BL, :3]) and np.array_equal(got.eps, out[k, O_EPS, :3]), k
    assert ctrl.t0 == int(inp.grid.t_ns[FIRST_VALID]) / 1e9  # the stamp's seconds, as the node
    # the RPF starts at its first sample: rho_e0 (given, or the first error's magnitude) on each axis
    q_ev = out[FIRST_VALID, O_QBR, :3]  # the true error, here what the controller saw
    want = np.abs(q_ev) if rho_e0 is None else np.full(3, rho_e0)
    np.testing.assert_allclose(np.abs(out[FIRST_VALID, O_RHO, :3]), want, rtol=0, atol=1e-15)


def test_the_start_is_the_first_valid_sample_in_every_run_of_a_batch_and_run_k_is_the_run_alone() -> None:
    """Run 1 of a batch with a dropout on [0, 0.3) s and the others on [0, 0.5) s (dispersed
    faults): each run's controller starts at its own first valid sample; run k alone equals run k."""
    scenario = scenario_from_mapping(_raw(OUTAGES["state"]))
    short = faults_from_list([{"kind": "sensor_dropout", "start_s": 0.0, "end_s": 0.3}])
    q0 = np.tile(scenario.q_BN0, (3, 1))
    inp = compiled_loop.prepare(scenario, q_BN0=q0, faults=[scenario.faults, short, scenario.faults])
    batch = compiled_loop.run_batch(inp, 1)
    first = [int(np.argmax(batch.status[n] == ANSWER_COMMANDED)) for n in range(3)]
    assert first == [FIRST_VALID, 30, FIRST_VALID]
    for n in range(3):
        alone = compiled_loop.run_single(inp, n, 1)
        np.testing.assert_array_equal(alone.out[0], batch.out[n])
        assert abs(batch.out[n, first[n], O_RHO, 1]) == 0.4  # the RPF's start value, at its own first sample


def test_the_probe_of_inputs_made_block_by_block_finds_starts_after_its_first_block(monkeypatch: pytest.MonkeyPatch) -> None:
    """A campaign's inputs are made block by block, and the start's probe (probe_batch_kernel, every
    run of the batch on one thread) takes a first block of PROBE_FIRST_SAMPLES samples alone, then
    goes on in the usual blocks: runs whose first valid samples (30, 50) lie beyond it start there
    as with the whole run's inputs, and their records are the same bits; the probe's first block
    made was that short one."""
    assert FIRST_VALID > 30 > compiled_loop.PROBE_FIRST_SAMPLES
    scenario = scenario_from_mapping(_raw(OUTAGES["state"]))
    short = faults_from_list([{"kind": "sensor_dropout", "start_s": 0.0, "end_s": 0.3}])
    q0 = np.tile(scenario.q_BN0, (3, 1))
    kw = dict(q_BN0=q0, faults=[scenario.faults, short, scenario.faults])
    made_blocks: list[tuple[int, int]] = []
    real_made = compiled_loop.CompiledInputs._made
    monkeypatch.setattr(compiled_loop.CompiledInputs, "_made", lambda self, k_lo, k_hi, carry: made_blocks.append((k_lo, k_hi)) or real_made(self, k_lo, k_hi, carry))
    made = compiled_loop.prepare(scenario, whole=False, **kw)
    assert made_blocks[0] == (0, compiled_loop.PROBE_FIRST_SAMPLES) and made_blocks[1][0] == compiled_loop.PROBE_FIRST_SAMPLES
    whole = compiled_loop.prepare(scenario, **kw)
    assert np.array_equal(made.controller.coef, whole.controller.coef)
    a, b = compiled_loop.run_batch(whole, 1), compiled_loop.run_batch(made, 1)
    assert [int(np.argmax(b.status[n] == ANSWER_COMMANDED)) for n in range(3)] == [FIRST_VALID, 30, FIRST_VALID]
    for name in a.record._fields:
        assert np.array_equal(getattr(a.record, name), getattr(b.record, name), equal_nan=True), name


def test_a_run_whose_controller_never_commands_has_the_metrics_of_an_error_never_in_a_band() -> None:
    """Sensor dropout from 0 s to the end: every sample answered with zero by the watchdog, zero
    torque, nothing saturated, no performance function (no ``rpf_error_at_t2``), every sample outside
    the constraint (there is none), so the error never returned into it."""
    result = simulate(scenario_from_mapping(_raw({"kind": "sensor_dropout", "start_s": 0.0}, duration_s=25.0)))
    m, samples = result.metrics, 2501
    assert result.controller_summary["watchdog_zero"] == samples and result.controller_summary["commanded"] == 0
    # the relay's "no data" is no rejected input (issue 46): the samples are answered, nothing is counted rejected
    assert result.controller_summary["held"] == 0 and result.controller_summary["rejected_inputs"] == 0
    assert m["max_abs_torque_Nm"] == 0.0 and m["saturation_fraction"] == 0.0
    assert m["time_outside_constraint_s"] == samples * BASE["control_period_s"]
    assert m["returned_to_constraint"] is False and m["left_constraint_after_fault"] is True and m["returned_at_s"] is None
    assert m["rpf_error_at_t2"] is None and m["settling_time_s"] is None


def test_warm_up_names_an_unknown_group_and_a_warm_cache_compiles_nothing(monkeypatch, capsys) -> None:
    """``warm_up`` refuses a group it does not have, naming it and the groups it has; with every
    group's entry kernels in the cache (the suite's set-up compiled them), ``ensure_compiled``
    neither prints nor compiles."""
    from sappc.offline import compiled_loop

    with pytest.raises(ValueError, match=re.escape(f"among {compiled_loop.WARM_UP_GROUPS}, got ['bogus']")):
        compiled_loop.warm_up("bogus")
    assert compiled_loop.cache_is_warm(compiled_loop.WARM_UP_GROUPS)
    monkeypatch.setattr(compiled_loop, "_checked", set())
    monkeypatch.setattr(compiled_loop, "warm_up", lambda *a, **k: pytest.fail("compiled on a warm cache"))
    compiled_loop.ensure_compiled(groups=compiled_loop.WARM_UP_GROUPS)
    assert capsys.readouterr().err == ""

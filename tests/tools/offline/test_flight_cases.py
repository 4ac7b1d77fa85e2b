"""The flight-like cases the estimator must survive (issue 26), each a scenario of its own that
extends ``paper_tracking_flight.yaml``: a 20 s star-tracker outage, a gyro bias step, a burst of
tracker outliers, a start 10 deg off.  Each test checks the behaviour that makes the case survivable
(what a broken filter would not do), then that the run still meets the paper's criteria."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SCENARIOS
from sappc.evaluation.estimation import attitude_errors
from sappc.offline.simulate import SimulationResult, simulate
from sappc.scenario import load_scenario
from sappc.evaluation.requirements import failed_requirements
from sappc.scenario import read_scenario_mapping, scenario_from_mapping
from sappc_estimator.core.mekf import MON_ERROR, STATUS_INITIALISED, STATUS_PROPAGATED, STATUS_REINITIALISED, STATUS_REJECTED, STATUS_UPDATED

#: The paper's Monte Carlo criteria (Sec. V.D), which every case must still meet.
RPF_ERROR_AT_T2_MAX, STEADY_MEAN_MAX = 1e-4, 5e-5
#: How many sigmas an estimation error may reach in these single runs: the attitude errors are
#: Gaussian with the filter's own sigma when it is consistent (tests/estimator), and a 60 s run
#: at 100 Hz holds ~6000 correlated samples per axis, whose largest is ~3.5 sigma; 4.5 sigma is
#: reached with probability ~1e-5 per independent sample (a few hundred independent ones here).
SIGMAS = 4.5


@pytest.fixture(scope="module")
def runs() -> dict[str, SimulationResult]:
    names = ("paper_tracking_flight", "flight_tracker_outage", "flight_gyro_bias_step", "flight_tracker_outliers",
             "flight_initial_estimate_error", "flight_gyro_bias_step_x", "flight_gyro_bias_step_y", "flight_gyro_bias_step_z",
             "flight_prior_90deg")
    return {n: simulate(load_scenario(SCENARIOS / f"{n}.yaml")) for n in names}


def _errors(r: SimulationResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, attitude error (T, 3) [rad], attitude sigma (T, 3) [rad]) of a run."""
    h = r.history
    assert h.estimate is not None
    e = h.estimate
    a = attitude_errors(e.q_BN[:, 0], h.q_BN[:, 0])
    sigma = np.sqrt(np.diagonal(e.covariance[:, 0], axis1=1, axis2=2))[:, :3]
    return h.t, a, sigma


def _meets_the_paper(r: SimulationResult) -> None:
    assert r.metrics["rpf_error_at_t2"] < RPF_ERROR_AT_T2_MAX and r.metrics["steady_mean_abs_qev"] < STEADY_MEAN_MAX
    assert r.metrics["overshoot"] == 0.0 and r.metrics["finite"]


def test_a_20_s_tracker_outage_is_ridden_on_the_gyro_and_re_acquired(runs: dict[str, SimulationResult]) -> None:
    r = runs["flight_tracker_outage"]
    t, a, sigma = _errors(r)
    assert r.history.estimate is not None
    status = r.history.estimate.status[:, 0]
    during = (t > 30.0) & (t < 50.0)
    assert np.all(status[during] == STATUS_PROPAGATED)  # no tracker sample in the outage: gyro only
    k30, k50 = int(np.argmax(t >= 30.0)), int(np.argmax(t >= 50.0))
    assert np.all(np.diff(sigma[k30 + 1:k50], axis=0) > 0.0)  # the uncertainty grows all along
    assert np.all(sigma[k50 - 1] > 2.0 * sigma[k30])
    assert status[k50] == STATUS_UPDATED  # re-acquired at once: the first fresh sample passes the gate
    # and the uncertainty shrinks back: within a second to under half across the boresight; about
    # the boresight (the tracker's 7.3e-5 rad) each sample weighs little, so it shrinks, slowly
    assert np.all(sigma[k50 + 100, :2] < 0.5 * sigma[k50 - 1, :2]) and sigma[k50 + 100, 2] < sigma[k50 - 1, 2]
    assert np.all(np.abs(a[t >= 5.0]) <= SIGMAS * sigma[t >= 5.0])  # the filter knows how wrong it is
    assert r.metrics["estimator_gate_rejections"] == 0 and r.metrics["estimator_reinitialisations"] == 0
    _meets_the_paper(r)


def test_a_gyro_bias_step_is_followed_without_losing_the_attitude(runs: dict[str, SimulationResult]) -> None:
    """The bias jumps by (5, -5, 5)e-6 rad/s at 30 s, which the filter's bias model (a 8.1e-10
    rad/s/sqrt(s) random walk) does not expect: the estimate follows through the tracker's updates
    (measured: three quarters of the step by 100 s), the attitude error stays far below the
    controller's tolerance, and the filter neither re-initialises nor lets a non-finite value out."""
    r = runs["flight_gyro_bias_step"]
    t, a, _ = _errors(r)
    e = r.history.estimate
    assert e is not None
    step = np.array([5e-6, -5e-6, 5e-6])
    bias_then = e.gyro_bias[int(np.argmax(t >= 30.0)), 0]
    moved = (e.gyro_bias[-1, 0] - bias_then) / step  # the share of the step the estimate followed by 60 s
    assert np.all(moved > 0.25), moved
    assert np.all(np.isfinite(e.q_BN[:, 0])) and r.metrics["estimator_reinitialisations"] == 0
    assert np.abs(a[t >= 30.0]).max() < 1e-4  # 0.0057 deg: far below the controller's tolerance of 1e-3 in q
    _meets_the_paper(r)


def test_a_burst_of_tracker_outliers_is_gated_and_leaves_the_estimate_alone(runs: dict[str, SimulationResult]) -> None:
    r, nominal = runs["flight_tracker_outliers"], runs["paper_tracking_flight"]
    t, a, sigma = _errors(r)
    e, e0 = r.history.estimate, nominal.history.estimate
    assert e is not None and e0 is not None
    burst = (t >= 30.0) & (t < 31.0)
    rejected = np.flatnonzero(e.status[:, 0] == STATUS_REJECTED)
    assert r.metrics["estimator_gate_rejections"] == 10 and np.all(burst[rejected])  # the 10 tracker samples of the burst
    assert r.metrics["estimator_reinitialisations"] == 0  # 10 in a row < 20
    # until the burst the run is the nominal one; during it the estimate is the gyro's propagation,
    # unmoved by samples 100 to 500 sigma away, so the error stays what the filter expects
    before = t < 30.0
    np.testing.assert_array_equal(e.q_BN[before, 0], e0.q_BN[before, 0])
    assert np.all(np.abs(a[burst]) <= SIGMAS * sigma[burst])
    assert np.all(np.abs(a[t >= 5.0]) <= SIGMAS * sigma[t >= 5.0])
    _meets_the_paper(r)


def test_a_start_10_deg_off_is_corrected_by_the_first_tracker_sample(runs: dict[str, SimulationResult]) -> None:
    r, nominal = runs["flight_initial_estimate_error"], runs["paper_tracking_flight"]
    scenario = load_scenario(SCENARIOS / "flight_initial_estimate_error.yaml")
    assert scenario.estimator is not None and scenario.estimator.initial_q_BN is not None
    prior = np.asarray(scenario.estimator.initial_q_BN) / np.linalg.norm(scenario.estimator.initial_q_BN)
    assert np.degrees(np.linalg.norm(attitude_errors(prior, r.history.q_BN[0, 0]))) == pytest.approx(10.0, abs=1e-5)
    t, a, sigma = _errors(r)
    e = r.history.estimate
    assert e is not None and e.status[0, 0] == STATUS_UPDATED  # the prior, then the first tracker sample
    tracker = np.asarray(scenario.sensors.star_tracker.noise_rad if scenario.sensors and scenario.sensors.star_tracker else 0.0)
    assert np.all(np.abs(a[0]) <= SIGMAS * tracker)  # 10 deg gone at the first sample, down to the tracker's noise
    assert np.all(np.abs(a[t >= 5.0]) <= SIGMAS * sigma[t >= 5.0])
    # from then on the run is the nominal one to within the estimates' own spread
    assert r.metrics["steady_max_abs_qev"] == pytest.approx(nominal.metrics["steady_max_abs_qev"], rel=0.05)
    assert STATUS_INITIALISED not in e.status[1:, 0]
    _meets_the_paper(r)


def test_the_estimator_figures_show_the_estimate_against_the_truth_with_3_sigma(runs: dict[str, SimulationResult], tmp_path,
                                                                               monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``estimator.png`` (attitude and bias errors with the filter's +-3 sigma), ``estimator_nis.png``
    and, comparing two runs, ``compare_estimator.png``: every axes draws data in its view."""
    from figure_checks import assert_every_axes_shows_data, capture_figures

    from sappc.analysis.plots import plot_compare, plot_estimator

    saved = capture_figures(monkeypatch)
    r = runs["flight_tracker_outliers"]
    paths = plot_estimator(r.history, tmp_path, title="outliers", fault_windows=[(30.0, 31.0)])
    assert [p.name for p in paths] == ["estimator.png", "estimator_nis.png"]
    compared = plot_compare([("nominal", runs["paper_tracking_flight"].history), ("outliers", r.history)], tmp_path, title="flight")
    assert "compare_estimator.png" in [p.name for p in compared]
    assert_every_axes_shows_data(saved)
    assert len(saved[0].axes) == 6  # attitude and bias errors, three axes each


# ----------------------------------------------------------------------------- issue 33

#: The bias steps of flight_gyro_bias_step_{x,y,z}.yaml: 2e-5 rad/s about one body axis at 41 s.
STEP_RAD_S, STEP_AT_S = 2e-5, 41.0
#: What the issue asks of the filter after such a step: the monitor flags it within 5 s, the bias
#: error is below 20 % of the step within 20 s, the closed loop's max |q_ev| is back below 4e-5
#: within 30 s.
FLAG_WITHIN_S, LEARNED_WITHIN_S, LEARNED_SHARE, BACK_WITHIN_S, QEV_BOUND = 5.0, 20.0, 0.2, 30.0, 4e-5


@pytest.mark.parametrize("axis", [0, 1, 2], ids=["x", "y", "z"])
def test_a_bias_step_is_flagged_and_learned_without_a_reinitialisation(runs: dict[str, SimulationResult], axis: int) -> None:
    """A 2e-5 rad/s bias step (twice the filter's prior bias sigma, 25 000 times its bias walk over
    a step) at 41 s: the health monitor's window leaves its error band within 5 s, the recovery
    (the bias covariance inflated) lets the filter learn the new bias to within 20 % in 20 s, with
    no gate rejection and no re-initialisation, and the attitude stays in the controller's tolerance
    (max |q_ev| below 4e-5 from 30 s after the step).  The errors are against the faulted truth."""
    r = runs[f"flight_gyro_bias_step_{'xyz'[axis]}"]
    h, e = r.history, r.history.estimate
    assert e is not None and e.monitor_level is not None and e.gyro_bias_true is not None
    t = h.t
    flagged = t[(t >= STEP_AT_S) & (e.monitor_level[:, 0] == MON_ERROR)]
    assert flagged.size and flagged[0] - STEP_AT_S <= FLAG_WITHIN_S, flagged[:1]
    assert not np.any(e.monitor_level[t < STEP_AT_S, 0] == MON_ERROR)  # not before the step
    db = np.abs(e.gyro_bias_true[:, 0] - e.gyro_bias[:, 0]).max(axis=1)
    learned = t >= STEP_AT_S + LEARNED_WITHIN_S
    assert np.all(db[learned] < LEARNED_SHARE * STEP_RAD_S), db[learned].max()
    assert r.metrics["estimator_gate_rejections"] == 0 and r.metrics["estimator_reinitialisations"] == 0
    assert r.metrics["estimator_recoveries"] >= 1 and r.metrics["estimate_withheld_samples"] == 0
    q_ev = np.abs(h.q_BR[:, 0, :3]).max(axis=1)
    assert q_ev[t >= STEP_AT_S + BACK_WITHIN_S].max() < QEV_BOUND
    assert r.metrics["final_abs_bias_estimation_error_rad_s"] == pytest.approx(db[-1], rel=1e-12)
    _meets_the_paper(r)


def test_the_gyro_bias_truth_includes_the_sensor_bias_fault(runs: dict[str, SimulationResult]) -> None:
    """The truth the estimation metrics use (``truth/gyro_bias``, the record's true bias) is the
    gyro's own bias walk plus every active ``sensor_bias`` fault's rate bias: the walk depends only
    on the sensor draws (the same seed), so the step run's truth is the nominal run's plus the step
    from 41 s on, to the last bit of the sum."""
    nominal, stepped = runs["paper_tracking_flight"], runs["flight_gyro_bias_step_y"]
    assert nominal.history.estimate is not None and stepped.history.estimate is not None
    b0, b1 = nominal.history.estimate.gyro_bias_true[:, 0], stepped.history.estimate.gyro_bias_true[:, 0]  # type: ignore[index]
    t = nominal.history.t
    step = np.where((t >= STEP_AT_S)[:, None], np.array([0.0, STEP_RAD_S, 0.0]), 0.0)
    np.testing.assert_array_equal(b1[: t.size], b0 + step)


def test_an_inconsistent_filter_fails_a_scenario_that_bounds_it(runs: dict[str, SimulationResult]) -> None:
    """``metrics.requirements.filter_inconsistent_fraction_max``: the share of samples at which the
    health monitor says ERROR; the bias step's run has some (its window around the step), the
    nominal run none, so a bound of 0 fails the one and passes the other, through the scenario's
    own requirement check."""
    raw = read_scenario_mapping(SCENARIOS / "flight_gyro_bias_step_z.yaml")
    raw["metrics"]["requirements"] = {"filter_inconsistent_fraction_max": 0.0}
    scenario = scenario_from_mapping(raw)
    assert scenario.metrics.requirements == {"filter_inconsistent_fraction_max": 0.0}
    stepped, nominal = runs["flight_gyro_bias_step_z"].metrics, runs["paper_tracking_flight"].metrics
    assert stepped["filter_inconsistent_fraction"] > 0.0 and nominal["filter_inconsistent_fraction"] == 0.0
    failed = failed_requirements(stepped, scenario.metrics.requirements)
    assert failed and failed[0].startswith("filter_inconsistent_fraction = ")
    assert failed_requirements(nominal, scenario.metrics.requirements) == []


def test_a_prior_90_deg_off_commands_no_torque_until_the_filter_accepts_a_tracker_sample(runs: dict[str, SimulationResult]) -> None:
    """The prior is 90 deg off with a 0.2 rad sigma: the tracker's samples fail the gate until the
    20th re-initialises the attitude from the tracker (1.9 s), which the next accepted one confirms.
    Until then the filter withholds its estimate: the controller, fed "no data" before any valid
    state, commands zero torque (counted in its summary as its watchdog's zero answers), instead
    of steering by an attitude 90 deg wrong; the run still settles by 25 s."""
    r = runs["flight_prior_90deg"]
    h, e = r.history, r.history.estimate
    assert e is not None
    status = e.status[:, 0]
    first_accepted = int(np.argmax(status == STATUS_UPDATED))
    assert h.t[first_accepted] == pytest.approx(2.0)
    assert np.all(h.torque_B[:first_accepted, 0] == 0.0)
    assert np.all(np.isnan(e.q_BN[:first_accepted, 0])) and np.all(np.isfinite(e.q_BN[first_accepted:, 0]))
    assert r.metrics["estimate_withheld_samples"] == first_accepted == r.controller_summary["watchdog_zero"]
    assert r.metrics["estimator_reinitialisations"] == 1 and r.metrics["estimator_gate_rejections"] == 19
    assert r.metrics["settling_time_s"] is not None and r.metrics["settling_time_s"] <= 25.0
    assert r.metrics["overshoot"] == 0.0


def test_a_sensor_fault_window_ending_between_tracker_epochs_uses_no_sample_twice() -> None:
    """An attitude bias of the measured quaternion from 1.0 s to 1.05 s: it ends between the
    tracker's epochs 1.0 and 1.1, so at 1.05 s the held quaternion of epoch 1.0 reappears without
    the bias.  A tracker sample is new by its epoch (``state/attitude_epoch``), never by its value:
    the filter updates once per tracker epoch (0.1 .. 3.0 s: 30), not again at 1.05 s (today's
    exact-comparison rule took the changed value for a new sample and used epoch 1.0's twice)."""
    raw = read_scenario_mapping(SCENARIOS / "paper_tracking_flight.yaml")
    raw["duration_s"] = 3.0
    raw["faults"] = [{"kind": "sensor_bias", "attitude_bias_rad": [2e-5, -1e-5, 3e-5], "start_s": 1.0, "end_s": 1.05}]
    r = simulate(scenario_from_mapping(raw))
    e = r.history.estimate
    assert e is not None
    t, status = r.history.t, e.status[:, 0]
    assert status[int(np.argmin(np.abs(t - 1.05)))] == STATUS_PROPAGATED  # epoch 1.0's sample again: not compared
    compared = t[np.isin(status, (STATUS_UPDATED, STATUS_REJECTED, STATUS_REINITIALISED))]
    np.testing.assert_allclose(compared, 0.1 * np.arange(1, 31), atol=1e-9)  # once per epoch after the first
    assert r.metrics["estimator_updates"] == 30

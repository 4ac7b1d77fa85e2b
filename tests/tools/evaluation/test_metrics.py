"""The run metrics (:mod:`sappc.evaluation.metrics`) against their definitions.

Every metric of every run equals an independent numpy model of the module docstring's
definitions (:func:`oracle`), on synthetic histories built so that each definition is exercised:
three runs with different data on each axis, one run that goes non-finite, a fault window,
saturation, band exits and returns, uniform and jittered time grids, and blocks of uneven sizes.
Then the boundaries stated in the docstring, each by its own test: the settling time (the first
sample after which ``max_i |q_ev,i|`` stays below the threshold: a sample *at* the threshold is
not settled), the steady window (``t >= steady_from_s``, the sample at ``steady_from_s`` and one
that ``k * dt`` rounds just below it included, the one before excluded), the sample nearest
``t2_s`` (``None`` when the run ends more than half a step before it).

Tolerances: maxima, counts, selected samples and times are exact (they are selections, no
arithmetic); the time-mean of ``|q_ev,i|`` is a running sum divided by a count, compared at 1e-14
relative (numpy's pairwise sum in the model adds in another order: a few ulps).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from sappc.evaluation.history import History
from sappc.evaluation.metrics import LOSS_OF_CONTROL_FACTOR, MetricsAccumulator

#: Relative tolerance of the steady-state time-mean (summation order only, see module docstring).
SUM_RTOL = 1e-14
#: The module's rounding allowance of ``k * dt`` [s] (stated in its ``_TIME_TOL_S``).
TIME_TOL_S = 1e-9


def _history(t: np.ndarray, q_ev: np.ndarray, *, torque: np.ndarray | None = None, rho: np.ndarray | None = None,
             saturated: np.ndarray | None = None, band: tuple[np.ndarray, np.ndarray] | None = None) -> History:
    """A History of T samples and N runs from the error's vector part ``q_ev`` (T, N, 3)."""
    T, N, _ = q_ev.shape
    q_BR = np.concatenate((q_ev, np.sqrt(np.clip(1.0 - np.sum(q_ev**2, axis=2, keepdims=True), 0.0, None))), axis=2)
    q_BN = q_BR.copy()
    zeros = np.zeros((T, N, 3))
    lower, upper = band if band is not None else (np.full((T, N, 3), -1.0), np.full((T, N, 3), 1.0))
    return History(t=np.asarray(t, dtype=float), q_BN=q_BN, omega_BN_B=zeros.copy(), q_BR=q_BR,
                   torque_B=zeros.copy() if torque is None else torque, torque_cmd_B=zeros.copy(),
                   saturated=np.zeros((T, N, 3), dtype=bool) if saturated is None else saturated, disturbance_B=zeros.copy(),
                   rho=zeros.copy() if rho is None else rho, band_lower=lower, band_upper=upper, eps=zeros.copy(), z=zeros.copy(),
                   V=zeros.copy())


def _accumulator(t: np.ndarray, n: int, **settings: Any) -> MetricsAccumulator:
    opts: dict[str, Any] = {"steady_from_s": 1.0, "settle_threshold": 0.1, "t2_s": 1.0, "fault_windows": []}
    opts.update(settings)
    return MetricsAccumulator(t, n, **opts)


def _switching_counts(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis of the torques ``u`` (K, 3) in time order: changes of ``sign(u)`` in {-1, 0, +1}
    between consecutive samples, and reversals of the non-zero signs (zeros dropped)."""
    s = np.sign(u)
    changes = np.count_nonzero(np.diff(s, axis=0), axis=0)
    reversals = np.array([np.count_nonzero(np.diff(s[s[:, i] != 0, i])) for i in range(3)])
    return changes, reversals


def oracle(h: History, *, steady_from_s: float, settle_threshold: float, t2_s: float, fault_windows: list[tuple[float, float]]) -> list[dict[str, Any]]:
    """The module docstring's definitions, written again with numpy, run by run."""
    t = h.t
    T = t.size
    dt = t[1] - t[0] if T > 1 else 0.0
    intervals = np.diff(t)
    uniform = not np.any(np.abs(intervals - dt) > TIME_TOL_S)
    hold = np.append(intervals, np.median(intervals)) if intervals.size else np.zeros(1)
    steady = t >= steady_from_s - TIME_TOL_S
    k2 = int(np.argmin(np.abs(t - t2_s)))
    has_t2 = abs(t[k2] - t2_s) <= 0.5 * dt + TIME_TOL_S
    fault = min((s for s, _ in fault_windows), default=None)
    out = []
    for n in range(h.q_BR.shape[1]):
        finite = np.all(np.isfinite(h.q_BN[:, n]), axis=1) & np.all(np.isfinite(h.omega_BN_B[:, n]), axis=1) & np.all(
            np.isfinite(h.torque_B[:, n]), axis=1)
        live = np.logical_and.accumulate(finite)  # the samples before the run failed
        e = h.q_BR[:, n, :3]
        big = np.abs(e).max(axis=1)
        unsettled = np.flatnonzero(live & (big >= settle_threshold))
        if unsettled.size == 0:
            settling: float | None = 0.0
        elif unsettled[-1] == T - 1:
            settling = None
        else:
            settling = float(t[unsettled[-1] + 1])
        use = live & steady
        outside = live & ~np.all((e >= h.band_lower[:, n]) & (e <= h.band_upper[:, n]), axis=1)  # a NaN band: outside
        sign0 = np.where(e[0] >= 0.0, 1.0, -1.0)
        changes, reversals = _switching_counts(h.torque_B[use, n])
        span = t[steady][-1] - t[steady][0] if steady.sum() >= 2 else None
        m: dict[str, Any] = {
            "settling_time_s": settling,
            "steady_max_abs_qev": float(np.max(np.where(use, big, 0.0))) if steady.any() else None,
            "steady_mean_abs_qev": float((np.sum(np.abs(e[use]), axis=0) / steady.sum()).max()) if steady.any() else None,
            "rpf_error_at_t2": float(np.abs(e[k2] - h.rho[k2, n]).max()) if has_t2 and live[k2] and np.isfinite(h.rho[k2, n]).all() else None,
            "overshoot": float(max(0.0, np.max(-sign0 * e[live]))) if live.any() else 0.0,
            "max_abs_torque_Nm": float(np.abs(h.torque_B[live, n]).max()) if live.any() else 0.0,
            "torque_sign_changes_per_s": None if span is None else float(changes.max() / span),
            "torque_reversals_per_s": None if span is None else float(reversals.max() / span),
            "saturation_fraction": float(np.sum(live & h.saturated[:, n].any(axis=1)) / T),
            "time_outside_constraint_s": float(outside.sum() * dt) if uniform else float(np.sum(hold[outside])),
            "returned_to_constraint": None,
            "left_constraint_after_fault": None,
            "returned_at_s": None,
            "finite": bool(live[-1]),
            "control_lost_at_s": None,
        }
        beyond = steady & ~(big <= LOSS_OF_CONTROL_FACTOR * settle_threshold)  # judged from the steady window; NaN is beyond
        if live[-1] and beyond[-1]:
            within = np.flatnonzero(~beyond)
            m["control_lost_at_s"] = float(t[within[-1] + 1]) if within.size else float(t[0])
        if fault is not None:
            last_out = int(np.flatnonzero(outside)[-1]) if outside.any() else -1
            left = bool(np.any(outside & (t >= fault - TIME_TOL_S)))
            returned = last_out < T - 1
            m.update(left_constraint_after_fault=left, returned_to_constraint=returned,
                     returned_at_s=float(t[last_out + 1]) if left and returned else None)
        out.append(m)
    return out


def _check(got: dict[str, Any], want: dict[str, Any]) -> None:
    assert got.keys() == want.keys()
    for key, value in want.items():
        if key == "steady_mean_abs_qev" and value is not None:
            assert got[key] == pytest.approx(value, rel=SUM_RTOL, abs=0.0), key
        else:
            assert got[key] == value, (key, got[key], value)


def _rich_history(t: np.ndarray) -> History:
    """Three runs, 3 axes, all different: decaying errors of both signs with late bumps, a run that
    goes non-finite, torques, saturation, a band that the error leaves and re-enters."""
    rng = np.random.default_rng(20261124)
    T = t.size
    decay = np.exp(-3.0 * (t - t[0]))[:, None, None]
    q_ev = decay * np.array([[0.30, -0.20, 0.05], [-0.25, 0.15, 0.40], [0.10, 0.35, -0.30]])[None] + 0.004 * rng.standard_normal((T, 3, 3))
    q_ev[T // 2, 1, 2] = 0.2  # run 1 is unsettled again half-way
    q_ev[-1, 0, 1] = 0.15  # run 0 ends unsettled: it never settles
    q_ev[-4:, 0, 2] = 0.31  # and its last four samples beyond the loss bound (10 x 0.03): it lost control
    q_ev[-12, 1, 0] = 0.35  # run 1 beyond the loss bound at one steady sample, and back: not lost
    q_ev[-11, 1, 2] = 0.3  # then exactly at the bound: within
    torque = 0.1 * rng.standard_normal((T, 3, 3))
    torque[np.abs(torque) < 0.06] = 0.0  # a minimum-output deadband: the torque switches on, off and over
    torque[:, 1, 1] = 0.05  # one axis never switches
    torque[5, 0, 0], torque[9, 1, 2], torque[3, 2, 1] = -0.7, 0.8, 0.9  # each run's largest torque on another axis
    saturated = rng.random((T, 3, 3)) < 0.05
    # a band of its own per axis and run, not symmetric about zero
    lower = -(0.05 + 0.1 * decay) * np.array([[1.0, 0.6, 1.3], [0.8, 1.1, 0.5], [1.2, 0.7, 0.9]])[None]
    upper = (0.04 + 0.1 * decay) * np.array([[0.7, 1.2, 0.9], [1.1, 0.6, 1.4], [0.5, 1.0, 1.3]])[None]
    rho = 0.02 * rng.standard_normal((T, 3, 3))
    h = _history(t, q_ev, torque=torque, rho=rho, saturated=saturated, band=(lower, upper))
    h.omega_BN_B[T - 7, 2, 1] = np.inf  # run 2 fails 7 samples before the end
    return h


SETTINGS: dict[str, Any] = {"steady_from_s": 1.2, "settle_threshold": 0.03, "t2_s": 0.75, "fault_windows": [(1.0, 1.1), (0.9, 2.0)]}


@pytest.mark.parametrize("grid", ["uniform", "jittered"])
def test_every_metric_of_every_run_equals_the_definitions(grid: str) -> None:
    t = 2.0 + np.arange(41) * 0.05  # a run (a bag) need not start at 0
    if grid == "jittered":  # real-time stamps: hold intervals of their own
        t = t + np.random.default_rng(3).uniform(-0.004, 0.004, t.size) * (np.arange(t.size) > 0)
    h = _rich_history(t)
    settings = {"steady_from_s": 3.2, "settle_threshold": 0.03, "t2_s": 2.75, "fault_windows": [(3.0, 3.1), (2.9, 4.0)]}
    acc = _accumulator(t, 3, **settings)
    acc.add_history(h)
    want = oracle(h, **settings)  # type: ignore[arg-type]
    assert [w["finite"] for w in want] == [True, True, False]
    assert want[0]["settling_time_s"] is None and want[1]["settling_time_s"] is not None  # both cases exercised
    assert any(w["left_constraint_after_fault"] for w in want) and any(w["returned_at_s"] for w in want)
    assert [w["control_lost_at_s"] for w in want] == [t[-4], None, None]  # lost; back within the bound; non-finite
    for n in range(3):
        _check(acc.run_metrics(n), want[n])


def test_blocks_of_any_size_give_the_same_metrics_as_the_whole_history() -> None:
    """``update`` on blocks (the campaign's sub-batches, the node's samples) equals ``add_history``
    bit for bit; the runs' accumulators concatenated equal one accumulator of all runs."""
    t = np.asarray(np.arange(41) * 0.05, dtype=np.float64)
    h = _rich_history(t)
    rng = np.random.default_rng(7)
    h.wheel_speed_rad_s = 300.0 * rng.standard_normal((t.size, 3, 4))  # reaction wheels: 4 per run
    h.wheel_torque_Nm = 0.1 * rng.standard_normal((t.size, 3, 4))
    h.wheel_speed_rad_s[30, 2, 1] = np.nan  # a failed run's non-finite record is left out
    whole = _accumulator(t, 3, **SETTINGS)
    whole.add_history(h)
    blocks = _accumulator(t, 3, **SETTINGS)
    x = np.asarray(np.concatenate((h.q_BN, h.omega_BN_B), axis=2), dtype=np.float64)
    assert t[24] >= SETTINGS["steady_from_s"] > t[23]  # block (24, 25) is the window's first sample alone
    for k0, k1 in ((0, 1), (1, 7), (7, 8), (8, 24), (24, 25), (25, 41)):
        blocks.update(k0, t[k0:k1], x[k0:k1], h.torque_B[k0:k1], h.q_BR[k0:k1], h.rho[k0:k1], h.saturated[k0:k1],
                      h.band_lower[k0:k1], h.band_upper[k0:k1])
        blocks.update_wheels(h.wheel_speed_rad_s[k0:k1], h.wheel_torque_Nm[k0:k1])
    for n in range(3):
        assert whole.run_metrics(n)["max_abs_wheel_speed_rad_s"] == np.nanmax(np.abs(h.wheel_speed_rad_s[:, n]))
        assert whole.run_metrics(n)["max_abs_wheel_torque_Nm"] == np.max(np.abs(h.wheel_torque_Nm[:, n]))
    parts = []
    for n in range(3):
        part = _accumulator(t, 1, **SETTINGS)
        fields: dict[str, Any] = {f: h.t if f == "t" else None if getattr(h, f) is None else getattr(h, f)[:, n : n + 1]
                                  for f in History.__dataclass_fields__}
        part.add_history(History(**fields))
        parts.append(part)
    joined = MetricsAccumulator.concatenate(parts)
    for n in range(3):
        assert blocks.run_metrics(n) == whole.run_metrics(n) == joined.run_metrics(n)
    for key, value in whole.criteria_arrays().items():
        np.testing.assert_array_equal(blocks.criteria_arrays()[key], value, err_msg=key)
        np.testing.assert_array_equal(joined.criteria_arrays()[key], value, err_msg=key)
    short = []
    for k1 in (5, 10):  # fed different samples, none in the steady window
        part = _accumulator(t, 1, **SETTINGS)
        part.update(0, t[:k1], x[:k1, :1], h.torque_B[:k1, :1], h.q_BR[:k1, :1], h.rho[:k1, :1], h.saturated[:k1, :1],
                    h.band_lower[:k1, :1], h.band_upper[:k1, :1])
        short.append(part)
    for mixed in ([parts[0], short[0]], short):
        with pytest.raises(ValueError, match="different samples"):
            MetricsAccumulator.concatenate(mixed)


def test_criteria_arrays_are_the_per_axis_criteria_of_every_run() -> None:
    t = np.arange(41) * 0.05
    h = _rich_history(t)
    acc = _accumulator(t, 3, **SETTINGS)
    acc.add_history(h)
    want = oracle(h, **SETTINGS)
    c = acc.criteria_arrays()
    e = np.abs(h.q_BR[..., :3])
    steady = t >= SETTINGS["steady_from_s"] - TIME_TOL_S
    np.testing.assert_allclose(c["steady_mean_abs_qev_per_axis"][:2], e[steady, :2].sum(axis=0) / steady.sum(), rtol=SUM_RTOL, atol=0)
    np.testing.assert_array_equal(c["steady_mean_abs_qev"], c["steady_mean_abs_qev_per_axis"].max(axis=1))
    k2 = int(round(SETTINGS["t2_s"] / 0.05))
    np.testing.assert_array_equal(c["rpf_error_at_t2_per_axis"], np.abs(h.q_BR[k2, :, :3] - h.rho[k2]))
    np.testing.assert_array_equal(c["rpf_error_at_t2"], [w["rpf_error_at_t2"] for w in want])
    np.testing.assert_array_equal(c["steady_max_abs_qev"], [w["steady_max_abs_qev"] for w in want])
    np.testing.assert_array_equal(c["max_abs_torque_Nm"], [w["max_abs_torque_Nm"] for w in want])
    np.testing.assert_array_equal(c["settling_time_s"], [np.nan if w["settling_time_s"] is None else w["settling_time_s"] for w in want])
    np.testing.assert_array_equal(c["finite"], [True, True, False])


def _one_axis(values: list[float], t: np.ndarray | None = None) -> History:
    """One run whose largest error component is ``values`` (on axis 1; the others 10x smaller)."""
    v = np.asarray(values, dtype=float)
    q_ev = np.stack((0.1 * v, v, -0.1 * v), axis=1)[:, None, :]
    return _history(np.arange(v.size) * 0.1 if t is None else t, q_ev)


def test_settling_time_is_the_first_sample_after_the_last_one_at_or_above_the_threshold() -> None:
    """``settling_time_s``: the first sample time after which ``max_i |q_ev,i|`` stays *below* the
    threshold until the end; a sample exactly at the threshold is not settled; ``0`` if it always
    was below, ``None`` if the last sample is not."""
    def settling(values: list[float]) -> float | None:
        h = _one_axis(values)
        acc = _accumulator(h.t, 1, settle_threshold=0.25)
        acc.add_history(h)
        result: float | None = acc.run_metrics(0)["settling_time_s"]
        return result

    assert settling([0.9, 0.5, 0.1, 0.3, 0.1, 0.0]) == 0.4  # the last unsettled sample is k = 3 (t = 0.3 s)
    assert settling([0.9, 0.5, 0.1, 0.25, 0.1, 0.0]) == 0.4  # at the threshold: not settled
    assert settling([0.9, 0.5, 0.1, 0.2499, 0.1, 0.0]) == 0.2  # just below: settled from k = 2
    assert settling([0.3, 0.2, 0.0, 0.1]) == 0.1  # only the first sample unsettled: settled from the second
    assert settling([0.1, 0.2, 0.0, 0.1]) == 0.0  # always below
    assert settling([0.1, 0.0, 0.0, 0.25]) is None  # the last sample is at the threshold: never settled
    assert settling([-0.9, -0.3, 0.0]) == 0.2  # magnitudes


def test_the_steady_window_starts_at_steady_from_s_with_the_grid_rounding_allowed() -> None:
    """``t >= steady_from_s``, with ``k * dt`` allowed to round below by up to 1e-9 s: the sample
    at ``steady_from_s`` is in the window, the one before is not; a window with no sample gives None."""
    dt = 0.03
    t = np.arange(60) * dt
    k_below = 11  # 11 * 0.03 = 0.32999999999999996 < 0.33: k * dt rounds below its decimal value
    assert t[k_below] < 0.33
    values = np.arange(60, dtype=float) / 100.0  # max |q_ev| grows with k: the window's start shows in the maximum and the mean
    h = _one_axis(list(values), t)

    def window(steady_from_s: float) -> tuple[float, float]:
        acc = _accumulator(t, 1, steady_from_s=steady_from_s)
        acc.add_history(h)
        m = acc.run_metrics(0)
        return m["steady_max_abs_qev"], m["steady_mean_abs_qev"]

    for k in (30, k_below):
        mx, mean = window(round(k * dt, 6))
        assert mx == values[-1]
        assert mean == pytest.approx(values[k:].mean(), rel=SUM_RTOL, abs=0.0), k  # samples k .. 59: k included
    mx, mean = window(t[30] + 2 * TIME_TOL_S)  # just after sample 30: it is out
    assert mean == pytest.approx(values[31:].mean(), rel=SUM_RTOL, abs=0.0)
    mx, mean = window(t[30] + TIME_TOL_S)  # sample 30 is 1e-9 s early: the rounding allowed, in
    assert mean == pytest.approx(values[30:].mean(), rel=SUM_RTOL, abs=0.0)
    acc = _accumulator(t, 1, steady_from_s=t[-1])  # a window of one sample
    acc.add_history(h)
    assert acc.run_metrics(0)["steady_mean_abs_qev"] == acc.run_metrics(0)["steady_max_abs_qev"] == values[-1]
    assert acc.criteria_arrays()["steady_mean_abs_qev"].tolist() == [values[-1]]
    acc = _accumulator(t, 1, steady_from_s=t[-1] + 2 * TIME_TOL_S)  # after the last sample
    acc.add_history(h)
    assert acc.run_metrics(0)["steady_max_abs_qev"] is None and acc.run_metrics(0)["steady_mean_abs_qev"] is None


def test_rpf_error_is_taken_at_the_sample_nearest_t2_or_none_when_the_run_ends_before() -> None:
    t = np.arange(10) * 0.1
    q_ev = np.zeros((10, 1, 3))
    q_ev[:, 0, 0] = np.arange(10) / 100.0
    rho = np.zeros((10, 1, 3))
    rho[:, 0, 0] = 0.5
    h = _history(t, q_ev, rho=rho)

    def at(t2_s: float) -> float | None:
        acc = _accumulator(t, 1, t2_s=t2_s)
        acc.add_history(h)
        result: float | None = acc.run_metrics(0)["rpf_error_at_t2"]
        return result

    assert at(0.0) == 0.5  # the first sample
    assert at(0.34) == pytest.approx(0.5 - 0.03, abs=1e-16)  # nearest sample: k = 3
    assert at(0.36) == pytest.approx(0.5 - 0.04, abs=1e-16)  # k = 4
    assert at(0.9 + 0.05) == pytest.approx(0.5 - 0.09, abs=1e-16)  # half a step after the end: still the last sample
    assert at(0.9 + 0.06) is None  # the run ended before t2


def test_overshoot_is_the_largest_excursion_opposite_to_the_initial_sign() -> None:
    """``max_{i,t} max(0, -sign(q_ev,i(0)) q_ev,i(t))`` with ``sign(0) = +1``."""
    q_ev = np.array([[0.3, -0.2, 0.0], [0.1, -0.1, -0.02], [-0.04, 0.05, 0.01], [-0.01, 0.07, -0.03]])[:, None, :]
    h = _history(np.arange(4) * 0.1, q_ev)
    acc = _accumulator(h.t, 1)
    acc.add_history(h)
    assert acc.run_metrics(0)["overshoot"] == 0.07  # axis 1 started negative and reached +0.07
    h2 = _history(np.arange(2) * 0.1, np.array([[0.3, -0.2, 0.1], [0.1, -0.1, 0.05]])[:, None, :])
    acc2 = _accumulator(h2.t, 1)
    acc2.add_history(h2)
    assert acc2.run_metrics(0)["overshoot"] == 0.0  # never opposite: zero, not negative
    h3 = _history(np.arange(2) * 0.1, np.array([[0.1, -0.1, 0.0], [0.05, -0.05, -0.04]])[:, None, :])
    acc3 = _accumulator(h3.t, 1)
    acc3.add_history(h3)
    assert acc3.run_metrics(0)["overshoot"] == 0.04  # axis 2 started at 0: sign +1, so -0.04 is opposite


def test_band_exits_saturation_and_return_after_a_fault() -> None:
    """Time outside the band (count x dt on a uniform grid), the fraction of saturated samples, and
    with faults: whether the error left the band at or after the first fault's start and when it
    re-entered for good; an error outside at the end has not returned."""
    t = np.arange(10) * 0.1
    q_ev = np.zeros((10, 2, 3))
    q_ev[[1, 5, 6], 0, 2] = 0.2  # run 0: outside at 0.1 (before the fault) and 0.5, 0.6 s
    q_ev[[2, 9], 1, 0] = -0.2  # run 1: outside at 0.2 and at the end
    band = (np.full((10, 2, 3), -0.1), np.full((10, 2, 3), 0.1))
    saturated = np.zeros((10, 2, 3), dtype=bool)
    saturated[[0, 3, 4], 0, 1] = True
    saturated[4, 0, 2] = True
    h = _history(t, q_ev, band=band, saturated=saturated)
    acc = _accumulator(t, 2, fault_windows=[(0.5, 0.7), (0.4, 0.45)])
    acc.add_history(h)
    m0, m1 = acc.run_metrics(0), acc.run_metrics(1)
    assert m0["time_outside_constraint_s"] == 3 * 0.1 and m1["time_outside_constraint_s"] == 2 * 0.1
    assert m0["saturation_fraction"] == 0.3 and m1["saturation_fraction"] == 0.0
    assert (m0["left_constraint_after_fault"], m0["returned_to_constraint"], m0["returned_at_s"]) == (True, True, t[7])
    assert (m1["left_constraint_after_fault"], m1["returned_to_constraint"], m1["returned_at_s"]) == (True, False, None)
    before = _accumulator(t, 2, fault_windows=[(0.65, 0.7)])  # run 0 left only before this fault
    before.add_history(h)
    assert (before.run_metrics(0)["left_constraint_after_fault"], before.run_metrics(0)["returned_at_s"]) == (False, None)
    assert before.run_metrics(0)["returned_to_constraint"] is True
    none = _accumulator(t, 2)  # no faults: the fault metrics are null
    none.add_history(h)
    assert none.run_metrics(0)["returned_to_constraint"] is None and none.run_metrics(0)["left_constraint_after_fault"] is None


def test_a_sample_without_a_band_is_outside_the_constraint_and_without_rho_there_is_no_rpf_error() -> None:
    """Before its first valid sample the controller has no performance function (NaN rows): the
    error is not within a constraint there, so such a sample counts as outside; a run that never
    had one is outside for its whole length and never returns; no rho at t2: ``rpf_error_at_t2``
    is None.  (Issue 25, 2.2: offline counted NaN bands as inside, a never-commanded run 0 s.)"""
    t = np.arange(10) * 0.1
    q_ev = np.full((10, 2, 3), 0.01)
    lower, upper = np.full((10, 2, 3), -0.1), np.full((10, 2, 3), 0.1)
    rho = np.full((10, 2, 3), 0.02)
    lower[:4, 0], upper[:4, 0], rho[:4, 0] = np.nan, np.nan, np.nan  # run 0 starts at 0.4 s
    lower[:, 1], upper[:, 1], rho[:, 1] = np.nan, np.nan, np.nan  # run 1 never starts
    upper[2, 0, 1] = 0.1  # one bound alone is no band either
    h = _history(t, q_ev, rho=rho, band=(lower, upper))
    acc = _accumulator(t, 2, t2_s=0.2, fault_windows=[(0.0, 1.0)])
    acc.add_history(h)
    m0, m1 = acc.run_metrics(0), acc.run_metrics(1)
    assert m0["time_outside_constraint_s"] == 4 * 0.1 and m0["returned_to_constraint"] is True and m0["returned_at_s"] == t[4]
    assert m1["time_outside_constraint_s"] == 10 * 0.1 and m1["returned_to_constraint"] is False and m1["returned_at_s"] is None
    assert m0["rpf_error_at_t2"] is None and m1["rpf_error_at_t2"] is None
    late = _accumulator(t, 2, t2_s=0.5)
    late.add_history(h)
    assert late.run_metrics(0)["rpf_error_at_t2"] == pytest.approx(0.01, abs=1e-17) and late.run_metrics(1)["rpf_error_at_t2"] is None
    for got, want in zip((m0, m1), oracle(h, steady_from_s=1.0, settle_threshold=0.1, t2_s=0.2, fault_windows=[(0.0, 1.0)])):
        _check(got, want)


def test_a_failed_run_is_described_by_its_samples_before_the_failure() -> None:
    """``finite`` is False once the state or the torque is non-finite; the other metrics use the
    samples before (torque, overshoot, band, saturation); a NaN error at t2 gives None."""
    t = np.arange(8) * 0.1
    q_ev = np.full((8, 1, 3), 0.01)
    q_ev[6:, 0, 0] = -0.5  # after the failure: ignored
    torque = np.full((8, 1, 3), 0.2)
    torque[5:, 0, 2] = 0.9
    saturated = np.zeros((8, 1, 3), dtype=bool)
    saturated[5:, 0, 0] = True
    h = _history(t, q_ev, torque=torque, saturated=saturated, band=(np.full((8, 1, 3), -0.1), np.full((8, 1, 3), 0.1)))
    h.torque_B[5, 0, 1] = math.nan  # fails at sample 5
    acc = _accumulator(t, 1, t2_s=0.6)
    acc.add_history(h)
    m = acc.run_metrics(0)
    assert m["finite"] is False and m["max_abs_torque_Nm"] == 0.2 and m["overshoot"] == 0.0
    assert m["time_outside_constraint_s"] == 0.0 and m["saturation_fraction"] == 0.0 and m["rpf_error_at_t2"] is None
    for field in ("q_BN", "omega_BN_B"):  # the state too
        h2 = _history(t, np.full((8, 1, 3), 0.01), torque=np.full((8, 1, 3), 0.2))
        getattr(h2, field)[3, 0, 0] = math.inf
        acc2 = _accumulator(t, 1)
        acc2.add_history(h2)
        assert acc2.run_metrics(0)["finite"] is False and acc2.run_metrics(0)["max_abs_torque_Nm"] == 0.2, field


def test_the_band_is_closed_and_the_error_returns_at_the_last_sample() -> None:
    """An error exactly on a band edge is inside (each axis, each side); an error outside up to the
    second-to-last sample has returned, at the last sample's time; a sample 1e-9 s before the
    fault's start counts as at the start (the grid rounding allowed)."""
    t = np.arange(8) * 0.1
    q_ev = np.zeros((8, 1, 3))
    for k, (i, side) in enumerate(((0, -1), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1)), start=1):
        q_ev[k, 0, i] = 0.1 * side  # on the edge
    band = (np.full((8, 1, 3), -0.1), np.full((8, 1, 3), 0.1))
    h = _history(t, q_ev, band=band)
    acc = _accumulator(t, 1, fault_windows=[(0.3, 0.4)])
    acc.add_history(h)
    m = acc.run_metrics(0)
    assert m["time_outside_constraint_s"] == 0.0 and m["left_constraint_after_fault"] is False and m["returned_to_constraint"] is True
    q_ev[6, 0, 1] = 0.2  # outside at the second-to-last sample only
    h = _history(t, q_ev, band=band)
    for start in (0.6, t[6] + TIME_TOL_S):  # the fault starts at the sample, or 1e-9 s after it
        acc = _accumulator(t, 1, fault_windows=[(start, 0.7)])
        acc.add_history(h)
        m = acc.run_metrics(0)
        assert (m["left_constraint_after_fault"], m["returned_to_constraint"], m["returned_at_s"]) == (True, True, t[7]), start


def test_runs_of_one_and_two_samples() -> None:
    """The shortest runs: one sample (its saturation is the whole run; nothing to hold it for), two
    samples on a grid of their own step (time outside = count x dt; never outside: returned)."""
    q_ev = np.array([[[0.2, 0.0, 0.0]]])
    saturated = np.ones((1, 1, 3), dtype=bool)
    h = _history(np.array([0.0]), q_ev, saturated=saturated)
    acc = _accumulator(h.t, 1, settle_threshold=0.5, t2_s=0.0)
    acc.add_history(h)
    m = acc.run_metrics(0)
    assert m["saturation_fraction"] == 1.0 and m["settling_time_s"] == 0.0 and m["rpf_error_at_t2"] == 0.2
    t = np.array([0.0, 0.25])
    band = (np.full((2, 2, 3), -0.1), np.full((2, 2, 3), 0.1))
    q_ev = np.zeros((2, 2, 3))
    q_ev[:, 0, 0] = 0.3  # run 0 outside at both samples, run 1 never
    h = _history(t, q_ev, band=band)
    acc = _accumulator(t, 2, fault_windows=[(0.0, 0.25)])
    acc.add_history(h)
    assert acc.run_metrics(0)["time_outside_constraint_s"] == 0.5 and acc.run_metrics(0)["returned_to_constraint"] is False
    assert acc.run_metrics(1)["time_outside_constraint_s"] == 0.0 and acc.run_metrics(1)["returned_to_constraint"] is True


def test_the_settings_are_keyword_only() -> None:
    """``steady_from_s``, ``settle_threshold``, ``t2_s``, ``fault_windows`` are keyword-only (three
    floats in a row are easy to swap)."""
    with pytest.raises(TypeError):
        MetricsAccumulator(np.zeros(3), 1, 1.0, 0.1, 1.0, [])  # type: ignore[call-arg]


def test_each_component_is_held_to_its_own_band() -> None:
    """"Any component outside its constraint band": component i against band i, on each side.
    One component moves per sample (the others at 0, inside), over bands of different widths, so
    a component compared with another's band would count differently."""
    rng = np.random.default_rng(7)
    T = 300
    t = np.arange(T) * 0.01
    q_ev = np.zeros((T, 1, 3))
    axis = np.arange(T) % 3
    q_ev[np.arange(T), 0, axis] = rng.uniform(-0.4, 0.4, T)
    lower = np.broadcast_to(np.array([-0.1, -0.25, -0.05]), (T, 1, 3)).copy()
    upper = np.broadcast_to(np.array([0.2, 0.05, 0.3]), (T, 1, 3)).copy()
    h = _history(t, q_ev, band=(lower, upper))
    acc = _accumulator(t, 1)
    acc.add_history(h)
    own = q_ev[np.arange(T), 0, axis]
    outside = (own < lower[0, 0, axis]) | (own > upper[0, 0, axis])
    assert 0 < outside.sum() < T
    assert acc.run_metrics(0)["time_outside_constraint_s"] == outside.sum() * 0.01


def _torque_run(t: np.ndarray, torque: list[list[float]]) -> History:
    """One run with the produced torques ``torque`` (T rows of 3 axes) and a small constant error."""
    u = np.asarray(torque, dtype=float)[:, None, :]
    return _history(t, np.full((t.size, 1, 3), 0.01), torque=u)


def _switching(h: History, **settings: Any) -> tuple[MetricsAccumulator, dict[str, Any]]:
    acc = _accumulator(h.t, h.torque_B.shape[1], **settings)
    acc.add_history(h)
    return acc, acc.run_metrics(0)


#: The window t >= 0.5 s of a 0.5 s grid: samples 1 .. 9, span 4 s. Sample 0 (outside) differs from
#: sample 1 on every axis, so a transition across the window's start would count.
SWITCHING_T = np.arange(10) * 0.5
SWITCHING_U = [
    # axis 0: on/off pulses   axis 1: constant   axis 2: direct reversals
    [-0.2, 0.0, -0.2],  # k = 0, before the window
    [0.2, -0.1, 0.2],
    [0.0, -0.1, 0.2],
    [0.2, -0.1, -0.2],
    [-0.0, -0.1, -0.2],  # -0.0 is a zero, not a negative torque
    [-0.2, -0.1, 0.2],
    [0.0, -0.1, 0.2],
    [-0.2, -0.1, -0.2],
    [0.0, -0.1, -0.2],
    [0.2, -0.1, -0.2],
]


def test_torque_sign_changes_count_every_switch_of_sign_in_the_window_per_axis() -> None:
    """``torque_sign_changes_per_s``: changes of sign(u) in {-1, 0, +1} between consecutive samples
    of the window (on, off and over each count one), per axis, the largest over the window's span;
    ``torque_reversals_per_s``: non-zero signs opposite to the last non-zero one, zeros skipped.
    Axis 0 (+ 0 + 0 - 0 - 0 +) switches 8 times and reverses twice; axis 1 never; axis 2
    (+ + - - + + - - -) switches and reverses 3 times: the two maxima come from different axes."""
    acc, m = _switching(_torque_run(SWITCHING_T, SWITCHING_U), steady_from_s=0.5)
    assert acc.torque_sign_changes.tolist() == [[8, 0, 3]]
    assert acc.torque_reversals.tolist() == [[2, 0, 3]]
    assert m["torque_sign_changes_per_s"] == 8 / 4.0 == 2.0
    assert m["torque_reversals_per_s"] == 3 / 4.0
    c = acc.criteria_arrays()
    assert c["torque_sign_changes_per_s"].tolist() == [2.0] and c["torque_reversals_per_s"].tolist() == [0.75]
    # the window from sample 0: the transitions 0 -> 1 count too (every axis changes sign there)
    acc, m = _switching(_torque_run(SWITCHING_T, SWITCHING_U), steady_from_s=0.0)
    assert acc.torque_sign_changes.tolist() == [[9, 1, 4]] and acc.torque_reversals.tolist() == [[3, 0, 4]]
    assert m["torque_sign_changes_per_s"] == 9 / 4.5 and m["torque_reversals_per_s"] == 4 / 4.5
    # the window from sample 3 (t = 1.5 s, span 3 s): axis 0 is + 0 - 0 - 0 +, axis 2 - - + + - - -
    acc, m = _switching(_torque_run(SWITCHING_T, SWITCHING_U), steady_from_s=1.5)
    assert acc.torque_sign_changes.tolist() == [[6, 0, 2]] and acc.torque_reversals.tolist() == [[2, 0, 2]]
    assert m["torque_sign_changes_per_s"] == 6 / 3.0 and m["torque_reversals_per_s"] == 2 / 3.0


def test_a_torque_that_never_switches_gives_zero_and_one_that_switches_every_sample_one_over_dt() -> None:
    t = np.arange(6) * 0.25
    for u in ([0.3, -0.3, 0.0], [0.0, 0.0, 0.0], [-1e-300, 5e-324, 0.0]):  # constant (zero, and the tiniest torques, included)
        _, m = _switching(_torque_run(t, [u] * 6), steady_from_s=0.0)
        assert m["torque_sign_changes_per_s"] == 0.0 and m["torque_reversals_per_s"] == 0.0, u
    alternating = [[0.1 * (-1) ** k, 0.0, 0.0] for k in range(6)]  # + - + - + -: 5 changes over 1.25 s
    _, m = _switching(_torque_run(t, alternating), steady_from_s=0.0)
    assert m["torque_sign_changes_per_s"] == m["torque_reversals_per_s"] == 5 / 1.25 == 1 / 0.25
    pulses = [[0.0, 0.1 * (k % 2), 0.0] for k in range(6)]  # 0 + 0 + 0 +: on/off every sample, never reversed
    _, m = _switching(_torque_run(t, pulses), steady_from_s=0.0)
    assert m["torque_sign_changes_per_s"] == 4.0 and m["torque_reversals_per_s"] == 0.0
    first = [[0.0, 0.0, -0.1]] + [[0.0, 0.0, 0.1]] * 5  # the window's first non-zero sign is negative, then positive
    _, m = _switching(_torque_run(t, first), steady_from_s=0.0)
    assert m["torque_sign_changes_per_s"] == m["torque_reversals_per_s"] == 1 / 1.25


def test_the_switching_rates_need_two_samples_in_the_window() -> None:
    """One sample in the window has no interval to switch in: None (as an empty window); two
    samples: one change over one step."""
    t = np.arange(4) * 0.5
    h = _torque_run(t, [[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    for steady_from_s in (t[-1], t[-1] + 2 * TIME_TOL_S):  # one sample, none
        acc, m = _switching(h, steady_from_s=steady_from_s)
        assert m["torque_sign_changes_per_s"] is None and m["torque_reversals_per_s"] is None, steady_from_s
        assert np.isnan(acc.criteria_arrays()["torque_sign_changes_per_s"][0]) and np.isnan(acc.criteria_arrays()["torque_reversals_per_s"][0])
    assert np.isnan(_switching(h, steady_from_s=t[-1])[0].steady_span_s()).all()  # each run's span: none
    acc, m = _switching(h, steady_from_s=t[-2])
    assert acc.steady_span_s().tolist() == [0.5] and m["torque_sign_changes_per_s"] == 2.0 and m["torque_reversals_per_s"] == 2.0


def test_switching_is_counted_across_blocks_runs_and_up_to_a_failure() -> None:
    """A change between the last sample of one block and the first of the next counts once; runs
    keep their own counts (and concatenate); a failed run counts its changes before the failure,
    over the whole window's span."""
    t = np.arange(10) * 0.5
    u = np.zeros((10, 2, 3))
    u[:, 0, :] = np.asarray(SWITCHING_U)
    u[[2, 3], 1, 1], u[[6, 7], 1, 1] = 0.1, -0.1  # run 1, axis 1: 0 0 + + 0 0 - - 0 0: 4 changes and 1 reversal in [0.5, 4.5]
    h = _history(t, np.full((10, 2, 3), 0.01), torque=u)
    x = np.concatenate((h.q_BN, h.omega_BN_B), axis=2)
    blocks = _accumulator(t, 2, steady_from_s=0.5)
    for k0, k1 in ((0, 1), (1, 2), (2, 4), (4, 5), (5, 10)):  # the changes at 1 -> 2, 3 -> 4, 4 -> 5 cross blocks, and
        # run 1's reversal: its + (sample 3) and its - (sample 6) lie two blocks apart
        blocks.update(k0, t[k0:k1], x[k0:k1], u[k0:k1], h.q_BR[k0:k1], h.rho[k0:k1], h.saturated[k0:k1], h.band_lower[k0:k1],
                      h.band_upper[k0:k1])
    assert blocks.torque_sign_changes.tolist() == [[8, 0, 3], [0, 4, 0]] and blocks.torque_reversals.tolist() == [[2, 0, 3], [0, 1, 0]]
    assert blocks.run_metrics(1)["torque_sign_changes_per_s"] == 1.0 and blocks.run_metrics(1)["torque_reversals_per_s"] == 0.25
    parts = []
    for n in range(2):
        part = _accumulator(t, 1, steady_from_s=0.5)
        part.add_history(History(**{f: h.t if f == "t" else None if getattr(h, f) is None else getattr(h, f)[:, n : n + 1]
                                    for f in History.__dataclass_fields__}))
        parts.append(part)
    joined = MetricsAccumulator.concatenate(parts)
    assert joined.torque_sign_changes.tolist() == [[8, 0, 3], [0, 4, 0]] and joined.torque_reversals.tolist() == [[2, 0, 3], [0, 1, 0]]
    assert [joined.run_metrics(n) for n in range(2)] == [blocks.run_metrics(n) for n in range(2)]
    failed = _torque_run(t, SWITCHING_U)
    failed.omega_BN_B[6, 0, 0] = math.nan  # fails at sample 6: the window's samples 1 .. 5 count
    acc, m = _switching(failed, steady_from_s=0.5)
    assert m["finite"] is False and acc.torque_sign_changes.tolist() == [[4, 0, 2]] and acc.torque_reversals.tolist() == [[1, 0, 2]]
    assert m["torque_sign_changes_per_s"] == 4 / 4.0 and m["torque_reversals_per_s"] == 2 / 4.0


def _state_of(acc: MetricsAccumulator) -> dict[str, Any]:
    return {name: getattr(acc, name) for name in MetricsAccumulator._PER_RUN + MetricsAccumulator._SUMMED + ("samples",)}


def _same_bits(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is b
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("grid", ["uniform", "jittered"])
def test_the_interpreted_kernel_gives_the_compiled_kernels_bits(grid: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """``sappc report`` runs the metrics kernel's source in the interpreter when numba is not loaded
    (a small block): every per-run array is the compiled kernel's, bit for bit, on histories with
    faults, a failed run, band exits, switching torques, blocks fed one after another, and on a
    closed-loop run of experiment 1's scenario."""
    from sappc.evaluation import metrics
    from sappc.offline.compiled_loop import simulate_compiled
    from sappc.scenario import load_scenario

    t = 2.0 + np.arange(41) * 0.05
    if grid == "jittered":
        t = t + np.random.default_rng(3).uniform(-0.004, 0.004, t.size) * (np.arange(t.size) > 0)
    h = _rich_history(t)
    settings = {"steady_from_s": 3.2, "settle_threshold": 0.03, "t2_s": 2.75, "fault_windows": [(3.0, 3.1), (2.9, 4.0)]}
    x = np.asarray(np.concatenate((h.q_BN, h.omega_BN_B), axis=2), dtype=np.float64)
    closed = simulate_compiled(load_scenario("config/scenarios/paper_tracking.yaml")).history()
    states = []
    for kernel in (metrics.interpreted_update_kernel(), metrics._update_kernel):
        monkeypatch.setattr(metrics, "_update_function", lambda samples, k=kernel: k)
        acc = _accumulator(t, 3, **settings)
        for k0, k1 in ((0, 7), (7, 24), (24, 41)):
            acc.update(k0, t[k0:k1], x[k0:k1], h.torque_B[k0:k1], h.q_BR[k0:k1], h.rho[k0:k1], h.saturated[k0:k1],
                       h.band_lower[k0:k1], h.band_upper[k0:k1])
        run = MetricsAccumulator(closed.t, 1, steady_from_s=20.0, settle_threshold=1e-3, t2_s=20.0, fault_windows=[(10.0, 12.0)])
        run.add_history(closed)
        states.append((_state_of(acc), _state_of(run)))
    for interpreted, compiled in zip(*states):
        for name, value in compiled.items():
            assert _same_bits(interpreted[name], value), name
    assert metrics.interpreted_update_kernel() is not metrics._update_kernel.py_func  # its helpers are the Python ones


def test_per_orbit_metrics_equal_their_definitions_whole_in_blocks_and_concatenated() -> None:
    """:meth:`MetricsAccumulator.orbit_metrics` against the module docstring's definitions, computed
    here with numpy over each orbit's samples (orbit ``j``: ``j T <= t < (j + 1) T``): 2.4 orbits of a
    made-up period, two runs, four wheels and three rods with random records, the steady window
    starting inside the first orbit; the same fed as two blocks split inside an orbit, and as two
    one-run accumulators concatenated.  Exact but the means (sums in another order: ``SUM_RTOL``)."""
    from sappc.scenario import OrbitBins

    rng = np.random.default_rng(36)
    T_s, dt = 10.0, 0.1
    t = np.arange(241) * dt  # 0 .. 24 s: orbits 0, 1 and the start of 2
    q_ev = rng.uniform(-1e-3, 1e-3, (t.size, 2, 3))
    W, M = 4, 3
    G = rng.normal(size=(3, W))
    Js = np.array([0.1, 0.2, 0.3, 0.4])
    m_max = np.array([10.0, 20.0, 40.0])
    speed = rng.normal(scale=50.0, size=(t.size, 2, W))
    dipoles = rng.uniform(-40.0, 40.0, (t.size, 2, M))
    bins = OrbitBins(T_s, Js, G, m_max)
    h = _history(t, q_ev)
    h.wheel_speed_rad_s, h.wheel_torque_Nm = speed, np.zeros_like(speed)
    h.orbit = np.concatenate((np.zeros((t.size, 2, 9)), dipoles), axis=2)
    steady_from_s = 3.0

    whole = _accumulator(t, 2, steady_from_s=steady_from_s, orbit_bins=bins)
    whole.add_history(h)
    blocks = _accumulator(t, 2, steady_from_s=steady_from_s, orbit_bins=bins)
    for k0, k1 in ((0, 150), (150, t.size)):  # split at 15 s, inside orbit 1
        blocks.add_history(History(**{f: h.t[k0:k1] if f == "t" else None if getattr(h, f) is None else getattr(h, f)[k0:k1]
                                      for f in History.__dataclass_fields__}))
    parts = []
    for n in range(2):
        part = _accumulator(t, 1, steady_from_s=steady_from_s, orbit_bins=bins)
        part.add_history(History(**{f: h.t if f == "t" else None if getattr(h, f) is None else getattr(h, f)[:, n:n + 1]
                                    for f in History.__dataclass_fields__}))
        parts.append(part)
    joined = MetricsAccumulator.concatenate(parts)

    hB = np.linalg.norm((speed * Js) @ G.T, axis=2)  # (T, N)
    for n in range(2):
        got = whole.orbit_metrics(n)
        assert [e["orbit"] for e in got] == [0, 1, 2] and [e["from_s"] for e in got] == [0.0, 10.0, 20.0]
        for j, e in enumerate(got):
            m = (t >= j * T_s) & (t < (j + 1) * T_s)
            ms = m & (t >= steady_from_s)
            assert e["steady_max_abs_qev"] == np.abs(q_ev[ms, n]).max()
            assert e["steady_mean_abs_qev"] == pytest.approx(np.abs(q_ev[ms, n]).mean(axis=0).max(), rel=SUM_RTOL)
            assert e["max_wheel_momentum_B_Nms"] == hB[m, n].max() and e["end_wheel_momentum_B_Nms"] == hB[m, n][-1]
            assert e["max_abs_wheel_speed_rad_s"] == np.abs(speed[m, n]).max()
            assert e["rods_mean_dipole_fraction"] == pytest.approx((np.abs(dipoles[m, n]) / m_max).mean(), rel=SUM_RTOL)
        for other in (blocks.orbit_metrics(n), joined.orbit_metrics(n)):
            assert [e.keys() for e in other] == [e.keys() for e in got]
            for a, b in zip(other, got):
                for key in a:
                    assert a[key] == pytest.approx(b[key], rel=SUM_RTOL), key
    assert _accumulator(t, 1).orbit_metrics(0) == []  # no orbit: none
    # rods in the scenario but no commands in the record (a bag without a management node: 9 columns): no duty
    h.orbit = h.orbit[:, :, :9]
    idle = _accumulator(t, 2, steady_from_s=steady_from_s, orbit_bins=bins)
    idle.add_history(h)
    assert [e["rods_mean_dipole_fraction"] for e in idle.orbit_metrics(0)] == [None] * 3
    assert [e["steady_max_abs_qev"] for e in idle.orbit_metrics(0)] == [e["steady_max_abs_qev"] for e in whole.orbit_metrics(0)]


def test_control_lost_is_judged_from_the_steady_window_to_the_end() -> None:
    """``control_lost_at_s``: from the first sample of the final stretch of steady samples beyond
    ``LOSS_OF_CONTROL_FACTOR * settle_threshold`` (strictly: a sample at the bound is within);
    a transient beyond it before the steady window is not judged; ``None`` when the run ends within
    the bound or before the steady window.  Blocks split anywhere give the same time."""
    bound = LOSS_OF_CONTROL_FACTOR * 0.05  # 0.5

    def lost(values: list[float], steady_from_s: float = 0.2, blocks: tuple[int, ...] = ()) -> float | None:
        h = _one_axis(values)
        acc = _accumulator(h.t, 1, settle_threshold=0.05, steady_from_s=steady_from_s)
        x = np.concatenate((h.q_BN, h.omega_BN_B), axis=2)
        edges = (0, *blocks, h.t.size)
        for k0, k1 in zip(edges[:-1], edges[1:]):
            acc.update(k0, h.t[k0:k1], x[k0:k1], h.torque_B[k0:k1], h.q_BR[k0:k1], h.rho[k0:k1], h.saturated[k0:k1],
                       h.band_lower[k0:k1], h.band_upper[k0:k1])
        result: float | None = acc.run_metrics(0)["control_lost_at_s"]
        return result

    t = np.arange(5) * 0.1  # _one_axis's grid
    assert bound == 0.5
    assert lost([0.9, 0.9, 0.1, 0.6, 0.7]) == t[3]  # beyond from k = 3 to the end
    assert lost([0.9, 0.9, 0.1, 0.6, 0.7], blocks=(1, 4)) == t[3]
    assert lost([0.9, 0.9, 0.1, 0.6, 0.5]) is None  # back at the bound at the last sample: within
    assert lost([0.9, 0.9, 0.9, 0.9, 0.9]) == t[2]  # beyond since the steady window opened
    assert lost([0.9, 0.9, 0.1, 0.2, 0.3]) is None  # beyond only in the transient
    assert lost([0.9, 0.9, 0.9], steady_from_s=1.0) is None  # the run ends before its steady window
    assert lost([0.9, 0.1, 0.9, 0.1, 0.6], steady_from_s=0.0) == t[4]

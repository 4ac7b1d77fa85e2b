"""The figures of a long run from a bounded envelope (issue 47, docs/design/streaming.md item 3).

:class:`~sappc.evaluation.envelope.HistoryEnvelope` is fed a run block by block and keeps, per
time bin, the samples of least and greatest value of every series a figure draws.  Checked here: a
one-sample spike anywhere in a long record (inside a block, at a block's edge) is in the
envelope's data at its time and value; the envelope is the same whatever the blocks; each bin's
extremes are the record's and every kept row is a sample of the record; a short run is kept
whole (its figures are the full record's files); the envelope's memory does not grow with the
run; and ``plot_run`` draws an envelope."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sappc.evaluation.envelope import CHUNK_SAMPLES, ENVELOPE_BINS, FULL_RATE_MAX_SAMPLES, ZOOM_FROM_S, HistoryEnvelope
from sappc.evaluation.estimation import EstimateHistory, attitude_errors
from sappc.evaluation.history import History

#: The sample interval of the synthetic records [s] (the scenarios' 100 Hz).
DT_S = 0.01
#: Block of the offline driver (design, item 1).
DRIVER_BLOCK = 65536
#: Wheels of the synthetic records.
W = 4
#: Rods of the synthetic records' orbit array (9 columns of fields and torque before them).
RODS = 3


def _noise(k: np.ndarray, salt: int) -> np.ndarray:
    """Uniform in [-0.5, 0.5) from the sample index ``k`` (splitmix64): a function of the sample,
    so any cut of the record into blocks gives the same values."""
    with np.errstate(over="ignore"):
        z = k.astype(np.uint64) + np.uint64(salt) * np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z ^= z >> np.uint64(31)
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53 - 0.5


def _wheels() -> Any:
    from spacecraft_sim.core.wheels import ReactionWheels

    return ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=0.01, max_torque_Nm=0.1, max_speed_rad_s=600.0)


def _record(lo: int, hi: int, *, estimator: bool = True, monotone: bool = False) -> History:
    """Samples ``lo .. hi - 1`` of a synthetic run (N = 1) with every field (wheels, the orbit
    array, with ``estimator`` the estimator's record): noise on every drawn series (each component
    its own), NaN where the filter has no estimate yet (the first 2 s) and in one stretch of the
    law's outputs.  ``monotone``: every drawn series constant or increasing instead (a bin then
    keeps its first and last samples only)."""
    k = np.arange(lo, hi)
    B, t = hi - lo, k * DT_S
    salt = iter(range(1, 1000))

    def series(c: int, scale: float = 1.0) -> np.ndarray:
        if monotone:
            return np.broadcast_to((scale * 1e-9 * k)[:, None, None], (B, 1, c)).copy()
        return scale * np.stack([_noise(k, next(salt)) for _ in range(c)], axis=-1)[:, None, :]

    q_ev = series(3, 1e-3)
    q_BR = np.concatenate((q_ev, np.sqrt(1.0 - np.sum(q_ev**2, axis=-1, keepdims=True))), axis=-1)
    axis = np.array([0.6, 0.0, 0.8])
    angle = np.full(B, 0.1) if monotone else 0.1 + _noise(k, 500)
    q_BN = np.concatenate((np.sin(0.5 * angle)[:, None] * axis, np.cos(0.5 * angle)[:, None]), axis=-1)[:, None, :]
    band = np.full((B, 1, 3), 0.02) if monotone else 0.02 + 1e-3 * series(3)
    h = History(t=t, q_BN=q_BN, omega_BN_B=series(3), q_BR=q_BR, torque_B=series(3, 0.1), torque_cmd_B=series(3, 0.1),
                saturated=series(3) > 0.3, disturbance_B=series(3, 1e-5), rho=0.01 + series(3, 1e-3), band_lower=-band,
                band_upper=band, eps=series(3), z=series(3), V=series(3), wheel_speed_rad_s=series(W, 100.0),
                wheel_torque_Nm=series(W, 0.0 if monotone else 0.05),
                orbit=series(9 + RODS))
    if not monotone:
        h.eps[(t >= 40.0) & (t < 40.5)] = np.nan  # a stretch without the law's outputs
    if estimator:
        q_est = q_BN if monotone else q_BN + 1e-5 * series(4)
        q_est = q_est / np.linalg.norm(q_est, axis=-1, keepdims=True)
        diagonal = 1e-8 * (1.5 + series(6))
        cov = np.zeros((B, 1, 6, 6))
        cov[..., range(6), range(6)] = diagonal
        cov[..., 0, 1] = cov[..., 1, 0] = 1e-10
        est = EstimateHistory(q_BN=q_est, omega_BN_B=series(3), gyro_bias=series(3, 1e-5), covariance=cov,
                              nis=3.0 + series(1)[..., 0],
                              status=(series(1)[..., 0] > 0.4).astype(np.int8), gyro_bias_true=series(3, 1e-5),
                              monitor_level=np.zeros((B, 1)), monitor_nis_sum=series(1)[..., 0], usable=np.ones((B, 1)),
                              recoveries=np.zeros((B, 1)))
        for a in (est.q_BN, est.omega_BN_B, est.gyro_bias, est.covariance, est.nis):
            a[t < 2.0] = np.nan
        h.estimate = est
    return h


def _fed(n: int, block: int, env: HistoryEnvelope | None = None, *, record: History | None = None, **kw: Any) -> HistoryEnvelope:
    """An envelope (the default one of an ``n``-sample run) fed ``n`` samples ``block`` at a time:
    views of ``record`` when given, else made block by block (``_record``'s ``kw``)."""
    env = env if env is not None else HistoryEnvelope((n - 1) * DT_S, wheels=_wheels())
    for lo in range(0, n, block):
        env.add(record.samples(lo, min(lo + block, n)) if record is not None else _record(lo, min(lo + block, n), **kw))
    return env


def _arrays(h: History) -> dict[str, np.ndarray]:
    out = {f.name: a for f in dataclasses.fields(h) if isinstance(a := getattr(h, f.name), np.ndarray)}
    if h.estimate is not None:
        est = h.estimate
        out |= {f"estimate.{f.name}": a for f in dataclasses.fields(est) if isinstance(a := getattr(est, f.name), np.ndarray)}
    return out


def _assert_same(a: History, b: History) -> None:
    """Every array of ``a`` and ``b`` equal (NaN where NaN), of the same dtype and shape."""
    x, y = _arrays(a), _arrays(b)
    assert x.keys() == y.keys()
    for k in x:
        assert x[k].dtype == y[k].dtype and x[k].shape == y[k].shape, k
        assert np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f"), k


def _drawn(h: History, wheels: Any) -> dict[str, np.ndarray]:
    """The series the figures draw, as they compute them, (T, columns)."""
    T, est = h.t.shape[0], h.estimate
    out = {"q_ev": h.q_ev, "abs_q_ev": np.abs(h.q_ev), "rho": h.rho, "abs_rho": np.abs(h.rho), "band_lower": h.band_lower,
           "band_upper": h.band_upper, "torque": h.torque_B, "eps": h.eps, "abs_V": np.abs(h.V),
           "wheel_speed": h.wheel_speed_rad_s, "wheel_torque": h.wheel_torque_Nm,
           "undelivered": h.torque_B[:, 0] + h.wheel_torque_Nm[:, 0] @ wheels.G.T}
    if est is not None:
        out |= {"attitude_error": attitude_errors(est.q_BN[:, 0], h.q_BN[:, 0]), "bias_error": est.gyro_bias_true - est.gyro_bias,
                "sigma": np.sqrt(np.abs(np.diagonal(est.covariance, axis1=-2, axis2=-1))), "nis": est.nis}
    return {k: np.asarray(v).reshape(T, -1) for k, v in out.items()}


def _bins(t: np.ndarray, t_end_s: float, bins: int, zoom_from_s: float = ZOOM_FROM_S) -> np.ndarray:
    """Each sample's bin by the documented rule: ``bins`` over ``[0, zoom_from_s)`` and ``bins``
    over ``[zoom_from_s, t_end_s]``."""
    pre = t < zoom_from_s
    out = np.where(pre, np.floor(t / (zoom_from_s / bins)), bins + np.floor((t - zoom_from_s) / ((t_end_s - zoom_from_s) / bins)))
    return np.clip(out, np.where(pre, 0, bins), np.where(pre, bins - 1, 2 * bins - 1)).astype(np.int64)


def test_a_one_sample_spike_in_a_long_record_is_in_the_envelope_at_its_time_and_value() -> None:
    """The issue's test: 2 million samples (5.6 h at 100 Hz) fed in the driver's blocks, spikes in
    the middle of a block, at a block's first sample and at a block's last sample: each is in the
    envelope at its exact time and value, and is the extreme of its series there."""
    n = 2_000_000
    spikes = [  # (sample, field, component, value)
        (7 * DRIVER_BLOCK + DRIVER_BLOCK // 2, "q_BR", 1, 0.37),  # inside a block (and a chunk)
        (20 * DRIVER_BLOCK, "torque_B", 2, -3.0),  # a block's first sample
        (26 * DRIVER_BLOCK - 1, "wheel_torque_Nm", 3, 0.9),  # a block's last sample
        (n - 1, "eps", 0, 5.0),  # the run's last sample
    ]
    env = HistoryEnvelope((n - 1) * DT_S, wheels=_wheels())
    q_ev_max = np.full(3, -np.inf)  # the record's extremes over the zoom window
    for lo in range(0, n, DRIVER_BLOCK):
        h = _record(lo, min(lo + DRIVER_BLOCK, n), estimator=False)
        for k, name, i, value in spikes:
            if lo <= k < lo + DRIVER_BLOCK:
                getattr(h, name)[k - lo, 0, i] = value
        zoom = h.t >= ZOOM_FROM_S
        q_ev_max = np.maximum(q_ev_max, h.q_ev[zoom, 0].max(axis=0, initial=-np.inf))
        env.add(h)
    e = env.history()
    assert not env.full_rate and e.t.shape[0] <= env.max_rows
    for k, name, i, value in spikes:
        row = np.flatnonzero(e.t == k * DT_S)
        assert row.size == 1, (k, name)
        assert getattr(e, name)[row[0], 0, i] == value
        assert (np.nanmax if value > 0 else np.nanmin)(getattr(e, name)[:, 0, i]) == value
    np.testing.assert_array_equal(e.q_ev[e.t >= ZOOM_FROM_S, 0].max(axis=0), q_ev_max)  # the zoom's view is the record's
    assert np.all(np.diff(e.t) > 0.0)


@pytest.mark.parametrize("bins", [8, 400])
@pytest.mark.parametrize("block", [1, 7, 4096, 3001])
def test_the_envelope_is_the_same_whatever_the_blocks_on_a_short_record(block: int, bins: int) -> None:
    """3001 samples binned (a low full-rate threshold; bins of hundreds of samples, and of a few):
    one block each sample, 7, a chunk's worth and the whole record give the same envelope, bit
    for bit."""
    n = 3001

    def env() -> HistoryEnvelope:
        return HistoryEnvelope((n - 1) * DT_S, bins=bins, full_rate_max_samples=500, wheels=_wheels())

    record = _record(0, n)
    whole = _fed(n, n, env(), record=record).history()
    _assert_same(_fed(n, block, env(), record=record).history(), whole)
    if bins == 8:  # bins of a few samples keep most of them: some 80 columns each keep one
        assert whole.t.shape[0] < n // 2


@pytest.mark.parametrize("block", [1000, CHUNK_SAMPLES - 1, DRIVER_BLOCK])
def test_the_envelope_is_the_same_whatever_the_blocks_on_a_long_record(block: int) -> None:
    """120001 samples, the default bins: blocks of 1000, of one less than a chunk and the driver's."""
    n = 120_001
    record = _record(0, n)
    whole = _fed(n, n, record=record).history()
    _assert_same(_fed(n, block, record=record).history(), whole)


@pytest.mark.parametrize("full_rate_max_samples", [500, FULL_RATE_MAX_SAMPLES])
def test_blocks_may_be_views_of_a_buffer_the_driver_reuses(full_rate_max_samples: int) -> None:
    """The offline driver hands each block as views of one buffer it overwrites: the envelope
    (binned, and a short run kept whole) keeps copies."""
    n, block = 3001, 256
    record = _record(0, n)
    buffer = _record(0, block)

    def env() -> HistoryEnvelope:
        return HistoryEnvelope((n - 1) * DT_S, full_rate_max_samples=full_rate_max_samples, wheels=_wheels())

    reused = env()
    for lo in range(0, n, block):
        hi = min(lo + block, n)
        part, mine = _arrays(record.samples(lo, hi)), _arrays(buffer)
        for k in part:
            mine[k][: hi - lo] = part[k]
        reused.add(buffer.samples(0, hi - lo))
        for k in mine:  # the driver's next block overwrites it
            mine[k][...] = np.nan if mine[k].dtype.kind == "f" else 0
    _assert_same(reused.history(), _fed(n, n, env(), record=record).history())


def test_each_bin_keeps_the_records_extremes_and_every_row_is_a_sample_of_the_record() -> None:
    """Per bin and per drawn series (as the figures compute them), the envelope's least and
    greatest values are the record's; every row is the record's sample at that time (the
    covariance: its diagonal, NaN off it), in time order, each once."""
    n, bins = 100_001, 50
    wheels = _wheels()
    env = HistoryEnvelope((n - 1) * DT_S, bins=bins, wheels=wheels)
    _fed(n, 10_000, env)
    full, e = _record(0, n), env.history()
    assert e.t.shape[0] < n // 10
    at = np.searchsorted(full.t, e.t)
    assert np.array_equal(full.t[at], e.t) and np.all(np.diff(at) > 0)
    rows = _arrays(full.samples(0, n))
    for k, a in _arrays(e).items():
        if k == "estimate.covariance":
            i = np.arange(6)
            np.testing.assert_array_equal(a[..., i, i], rows[k][at][..., i, i])
            assert np.all(np.isnan(a[..., 0, 1]))
        else:
            np.testing.assert_array_equal(a, rows[k][at], err_msg=k)
    b_full, b_env = _bins(full.t, (n - 1) * DT_S, bins), _bins(e.t, (n - 1) * DT_S, bins)
    drawn_full, drawn_env = _drawn(full, wheels), _drawn(e, wheels)
    for name in drawn_full:
        for b in (0, 3, bins - 1, bins, bins + 17, 2 * bins - 1):
            x, y = drawn_full[name][b_full == b], drawn_env[name][b_env == b]
            for col in range(x.shape[1]):
                finite = x[np.isfinite(x[:, col]), col]
                if finite.size:
                    assert np.nanmin(y[:, col]) == finite.min() and np.nanmax(y[:, col]) == finite.max(), (name, b, col)
                else:  # a bin without a value keeps its first sample: the line has its gap
                    assert np.isnan(y[0, col]) and e.t[b_env == b][0] == full.t[b_full == b][0], (name, b, col)


def test_a_short_run_is_kept_whole() -> None:
    """A run of at most FULL_RATE_MAX_SAMPLES samples: the envelope is its History, every array
    equal (dtype, shape, NaN), whatever the blocks; one sample more and it is binned."""
    n = FULL_RATE_MAX_SAMPLES
    full = _record(0, n)
    env = _fed(n, 1000)
    assert env.full_rate
    _assert_same(env.history(), full)
    env.add(_record(n, n + 1))  # binned: 18.5 samples a bin after the zoom's start, most of them an extreme of some series
    assert not env.full_rate and env.history().t.shape[0] <= n + 1


def test_a_short_runs_figures_are_the_files_of_its_record(tmp_path: Path) -> None:
    """The paper's 60 s (6001 samples): plot_run of the envelope writes the same bytes as plot_run
    of the record."""
    from sappc.analysis.plots import plot_run

    n = 6001
    wheels = _wheels()
    full = _record(0, n)
    mine = plot_run(_fed(n, 512).history(), tmp_path / "envelope", title="t", wheels=wheels, parallel=False)
    theirs = plot_run(full, tmp_path / "record", title="t", wheels=wheels, parallel=False)
    assert [p.name for p in mine] == [p.name for p in theirs] and len(mine) == 8
    for a, b in zip(mine, theirs):
        assert a.read_bytes() == b.read_bytes(), a.name


def test_the_envelopes_memory_does_not_grow_with_the_run() -> None:
    """A run 10 times longer (10^6 samples against 10^5) keeps the same bytes: series constant or
    increasing keep two samples a bin; noisy ones stay under the bound, a row per bin and column."""
    sizes = []
    for n in (100_001, 1_000_001):
        env = _fed(n, DRIVER_BLOCK, monotone=True)
        h = env.history()
        sizes.append((env.nbytes, sum(a.nbytes for a in _arrays(h).values()), h.t.shape[0]))
    assert sizes[0] == sizes[1]
    assert sizes[0][2] <= 2 * 2 * ENVELOPE_BINS  # first and last sample of each bin
    env = _fed(200_001, DRIVER_BLOCK)
    assert env.max_rows is not None and env.history().t.shape[0] <= env.max_rows


def test_plot_run_draws_a_long_runs_envelope(tmp_path: Path) -> None:
    """plot_run on the envelope of 200001 samples (wheels, the estimator) writes every figure
    (100 bins a grid: with noise on every series a bin keeps some 80 rows, which every curve
    draws; 10,000 rows draw in a few seconds)."""
    from sappc.analysis.plots import plot_run

    n = 200_001
    wheels = _wheels()
    h = _fed(n, DRIVER_BLOCK, HistoryEnvelope((n - 1) * DT_S, bins=100, wheels=wheels)).history()
    assert h.t.shape[0] < n // 10
    paths = plot_run(h, tmp_path, title="long", wheels=wheels, fault_windows=[(100.0, 200.0)], parallel=False)
    names = {p.name for p in paths}
    assert names == {"qev.png", "qev_zoom.png", "qev_log.png", "torque.png", "eps_lyapunov.png", "wheels.png", "estimator.png",
                     "estimator_nis.png"}
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_the_zoom_window_starts_where_plot_run_zooms() -> None:
    from sappc.analysis.plots import plot_run

    assert inspect.signature(plot_run).parameters["zoom_from_s"].default == ZOOM_FROM_S


def test_blocks_must_go_on_in_time_and_keep_their_fields() -> None:
    env = HistoryEnvelope(10.0)
    env.add(_record(100, 200))
    with pytest.raises(ValueError, match="non-decreasing"):
        env.add(_record(0, 10))
    with pytest.raises(ValueError, match="other fields"):
        env.add(_record(200, 210, estimator=False))
    with pytest.raises(ValueError, match="no sample"):
        HistoryEnvelope(10.0).history()
    with pytest.raises(ValueError, match="span"):
        HistoryEnvelope(0.0)

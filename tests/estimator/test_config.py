"""The estimator's settings (:mod:`sappc_estimator.core.config`) and its stepping object
(:class:`sappc_estimator.core.estimator.Mekf`): every check of :class:`MekfConfig` names the
setting and refuses the value, every column of the kernel's parameter array is the documented
quantity (``docs/estimator.md``, "Defaults from the sensor specification"), a batch packs one row
per run, and :class:`Mekf` is the kernel called sample by sample, bit for bit.  Pure: no ROS, fast
(the mutation run's first stage for these modules)."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from scipy.stats import chi2

from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, InputError
from sappc_estimator.core import mekf
from sappc_estimator.core.config import (DEFAULT_GATE_FALSE_ALARM, DEFAULT_INITIAL_BIAS_SIGMA_RAD_S, DEFAULT_MAX_BODY_RATE_RAD_S,
                                         DEFAULT_MAX_CONSECUTIVE_REJECTIONS, DEFAULT_MONITOR_DRIFT_FALSE_ALARM, DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA,
                                         DEFAULT_MONITOR_ERROR_PROBABILITY, DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY, DEFAULT_MONITOR_PERSISTENCE,
                                         DEFAULT_MONITOR_WARN_PROBABILITY,
                                         DEFAULT_MONITOR_WINDOW_SAMPLES, MekfConfig, chi2_3dof_isf, chi2_band, cusum_mean_run_length,
                                         cusum_threshold, pack_estimator)
from sappc_estimator.core.estimator import Mekf

#: Per-axis figures of a data sheet, all different so that a swapped or dropped axis shows [rad, rad/sqrt(s), rad/s/sqrt(s)].
NOISE, ARW, BRW = (1e-5, 2e-5, 7e-5), (1e-6, 2e-6, 3e-6), (1e-10, 2e-10, 3e-10)
#: Relative tolerance of a chi-square quantile against scipy.stats' (both double precision; the
#: closed-form one is within 1e-12: test_mekf.py).
QUANTILE_RTOL = 1e-9


def config(**kw: object) -> MekfConfig:
    base: dict[str, object] = dict(tracker_noise_rad=NOISE, gyro_angle_random_walk_rad_sqrt_s=ARW, gyro_bias_random_walk_rad_s_sqrt_s=BRW)
    base.update(kw)
    return MekfConfig(**base)  # type: ignore[arg-type]


def test_the_settings_cannot_change_once_made() -> None:
    """A filter packs its parameters once (``Mekf``, the node): settings changed afterwards would no
    longer be the filter's, so they cannot be changed (and, being immutable, they hash)."""
    c = config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.gate_false_alarm = 0.5  # type: ignore[misc]
    assert hash(c) == hash(config())


def test_the_defaults_are_the_documented_ones() -> None:
    c = MekfConfig(tracker_noise_rad=1e-5)
    assert (c.gate_false_alarm, c.max_consecutive_rejections, c.max_body_rate_rad_s) == (1e-4, 20, 10.0)
    assert (c.gate_false_alarm, c.max_consecutive_rejections, c.max_body_rate_rad_s) == (
        DEFAULT_GATE_FALSE_ALARM, DEFAULT_MAX_CONSECUTIVE_REJECTIONS, DEFAULT_MAX_BODY_RATE_RAD_S)
    assert c.initial_bias_sigma_rad_s == DEFAULT_INITIAL_BIAS_SIGMA_RAD_S == 1e-5
    assert (c.monitor_window_samples, c.monitor_warn_probability, c.monitor_error_probability, c.monitor_mean_error_probability,
            c.monitor_persistence) == (20, 0.99, 1.0 - 1e-6, 1.0 - 3e-5, 2)
    assert (DEFAULT_MONITOR_WINDOW_SAMPLES, DEFAULT_MONITOR_WARN_PROBABILITY, DEFAULT_MONITOR_ERROR_PROBABILITY,
            DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY, DEFAULT_MONITOR_PERSISTENCE) == (20, 0.99, 1.0 - 1e-6, 1.0 - 3e-5, 2)
    assert (c.monitor_drift_shift_sigma, c.monitor_drift_false_alarm) == (DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA, DEFAULT_MONITOR_DRIFT_FALSE_ALARM) \
        == (0.5, 1e-6)
    assert c.max_attitude_norm_error == QUATERNION_NORM_TOL
    assert c.initial_q_BN is None and c.initial_attitude_sigma_rad is None and c.bias_recovery_sigma_rad_s is None


def test_every_column_of_the_parameter_array_is_the_documented_quantity() -> None:
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q = q / np.linalg.norm(q) * (1.0 + 5e-7)  # within the unit-norm tolerance: normalised when packed
    c = config(initial_bias_rad_s=(1e-6, -2e-6, 3e-6), initial_bias_sigma_rad_s=(4e-6, 5e-6, 6e-6), initial_q_BN=tuple(q),
               initial_attitude_sigma_rad=(0.1, 0.2, 0.3), gate_false_alarm=1e-3, max_consecutive_rejections=7, max_body_rate_rad_s=3.5,
               max_attitude_norm_error=5e-7, monitor_window_samples=12, monitor_warn_probability=0.95, monitor_error_probability=0.999,
               monitor_mean_error_probability=0.9999, monitor_persistence=3, bias_recovery_sigma_rad_s=(7e-6, 8e-6, 9e-6), monitor_drift_shift_sigma=0.8,
               monitor_drift_false_alarm=1e-4)
    p = c.params()
    assert p.shape == (mekf.N_EST_PARAMS,)

    def cols(at: int, n: int = 3) -> list[float]:
        return p[at:at + n].tolist()

    assert cols(mekf.EP_R) == [v * v for v in NOISE]
    assert cols(mekf.EP_SV2) == [v * v for v in ARW]
    assert cols(mekf.EP_SU2) == [v * v for v in BRW]
    assert cols(mekf.EP_P0A) == [v * v for v in (0.1, 0.2, 0.3)]
    assert cols(mekf.EP_P0B) == [v * v for v in (4e-6, 5e-6, 6e-6)]
    assert cols(mekf.EP_B0) == [1e-6, -2e-6, 3e-6]
    assert p[mekf.EP_GATE] == pytest.approx(chi2.isf(1e-3, 3), rel=QUANTILE_RTOL)
    assert p[mekf.EP_MAXREJ] == 7 and p[mekf.EP_MAX_RATE] == 3.5 and p[mekf.EP_MAX_NORM_ERR] == 5e-7
    assert p[mekf.EP_INIT] == mekf.INIT_FROM_PRIOR
    np.testing.assert_allclose(cols(mekf.EP_Q0, 4), q / np.linalg.norm(q), rtol=0, atol=1e-16)
    assert abs(np.linalg.norm(p[mekf.EP_Q0:mekf.EP_Q0 + 4]) - 1.0) < 1e-15
    assert p[mekf.EP_MON_WINDOW] == 12 and p[mekf.EP_MON_PERSIST] == 3
    np.testing.assert_allclose(cols(mekf.EP_MON_NIS, 4), [chi2.ppf(0.0005, 36), chi2.ppf(0.025, 36), chi2.isf(0.025, 36), chi2.isf(0.0005, 36)],
                               rtol=QUANTILE_RTOL)
    np.testing.assert_allclose(cols(mekf.EP_MON_MEAN, 2), [chi2.isf(0.05, 3), chi2.isf(1e-4, 3)], rtol=QUANTILE_RTOL)
    assert cols(mekf.EP_RECOVERY_PBB) == [v * v for v in (7e-6, 8e-6, 9e-6)]
    # the drift test: the reference half the shift; the threshold at which six CUSUMs' mean run length
    # (Siegmund's approximation, written out here) gives 1e-4 false alarms a sample together
    k, h = cols(mekf.EP_MON_DRIFT, 2)
    b = h + 2.0 * 1.4603545088095868 / math.sqrt(2.0 * math.pi)  # Siegmund's overshoot: -2 zeta(1/2) / sqrt(2 pi)
    assert k == 0.4 and 6.0 / ((math.exp(2.0 * k * b) - 2.0 * k * b - 1.0) / (2.0 * k * k)) == pytest.approx(1e-4, rel=1e-12)
    # from the tracker: the tracker's noise is the first attitude's, the gate off at 0, one number for three axes
    p = config(gate_false_alarm=0.0, tracker_noise_rad=3e-5, bias_recovery_sigma_rad_s=0.0).params()
    assert p[mekf.EP_INIT] == mekf.INIT_FROM_TRACKER and cols(mekf.EP_Q0, 4) == [0.0] * 4
    assert cols(mekf.EP_P0A) == cols(mekf.EP_R) == [3e-5 * 3e-5] * 3
    assert p[mekf.EP_GATE] == math.inf and config(gate_false_alarm=0.0).gate_chi2 == math.inf
    assert cols(mekf.EP_RECOVERY_PBB) == [0.0] * 3
    assert cols(mekf.EP_RECOVERY_PBB) != cols(mekf.EP_P0B)
    assert config(monitor_drift_false_alarm=0.0).params()[mekf.EP_MON_DRIFT + 1] == math.inf  # no drift test


@pytest.mark.parametrize("kw, words", [
    ({"tracker_noise_rad": 0.0}, "tracker_noise_rad must be > 0"),
    ({"tracker_noise_rad": (1e-5, 1e-5)}, "tracker_noise_rad must be one finite number or 3"),
    ({"tracker_noise_rad": (1e-5, math.nan, 1e-5)}, "tracker_noise_rad must be one finite number or 3"),
    ({"tracker_noise_rad": "1e-5"}, "tracker_noise_rad must be one number or 3"),
    ({"tracker_noise_rad": True}, "tracker_noise_rad must be one number or 3"),
    ({"tracker_noise_rad": (1e-5, True, 1e-5)}, "tracker_noise_rad must be one number or 3"),
    ({"gyro_angle_random_walk_rad_sqrt_s": -1e-6}, "gyro_angle_random_walk_rad_sqrt_s must be >= 0"),
    ({"gyro_bias_random_walk_rad_s_sqrt_s": (0.0, -1e-9, 0.0)}, "gyro_bias_random_walk_rad_s_sqrt_s must be >= 0"),
    ({"initial_bias_rad_s": math.inf}, "initial_bias_rad_s must be one finite number or 3"),
    ({"initial_bias_sigma_rad_s": 0.0}, "initial_bias_sigma_rad_s must be > 0"),
    ({"initial_q_BN": (0.0, 0.0, 0.0, 1.0)}, "initial_attitude_sigma_rad must be given with initial_q_BN"),
    ({"initial_attitude_sigma_rad": 0.0}, "initial_attitude_sigma_rad must be > 0"),
    ({"gate_false_alarm": 1.0}, "gate_false_alarm must be in [0, 1) (0: no gate), got 1.0"),
    ({"gate_false_alarm": -1e-9}, "gate_false_alarm must be in [0, 1)"),
    ({"gate_false_alarm": math.nan}, "gate_false_alarm must be in [0, 1)"),
    ({"gate_false_alarm": True}, "gate_false_alarm must be in [0, 1)"),
    ({"gate_false_alarm": "0.1"}, "gate_false_alarm must be in [0, 1)"),
    ({"max_consecutive_rejections": 0}, "max_consecutive_rejections must be an integer >= 1, got 0"),
    ({"max_consecutive_rejections": 2.0}, "max_consecutive_rejections must be an integer >= 1"),
    ({"max_consecutive_rejections": True}, "max_consecutive_rejections must be an integer >= 1"),
    ({"max_body_rate_rad_s": 0.0}, "max_body_rate_rad_s"),
    ({"max_body_rate_rad_s": True}, "max_body_rate_rad_s must be a number, got True"),
    ({"max_attitude_norm_error": False}, "max_attitude_norm_error must be a number, got False"),
    ({"max_attitude_norm_error": 2e-6}, "max_attitude_norm_error must be in (0, 1e-06], got 2e-06"),
    ({"monitor_window_samples": 0}, "monitor_window_samples must be an integer in [1, 100], got 0"),
    ({"monitor_window_samples": 101}, "monitor_window_samples must be an integer in [1, 100], got 101"),
    ({"monitor_window_samples": 20.0}, "monitor_window_samples must be an integer in [1, 100]"),
    ({"monitor_window_samples": True}, "monitor_window_samples must be an integer in [1, 100]"),
    ({"monitor_warn_probability": 0.0}, "monitor_warn_probability must be in (0, 1), got 0.0"),
    ({"monitor_error_probability": 1.0}, "monitor_error_probability must be in (0, 1), got 1.0"),
    ({"monitor_warn_probability": True}, "monitor_warn_probability must be in (0, 1)"),
    ({"monitor_warn_probability": math.nan}, "monitor_warn_probability must be in (0, 1)"),
    ({"monitor_error_probability": "0.999"}, "monitor_error_probability must be in (0, 1), got '0.999'"),
    ({"monitor_error_probability": 0.98}, "monitor_error_probability (0.98) must be at least monitor_warn_probability (0.99)"),
    ({"monitor_mean_error_probability": 1.0}, "monitor_mean_error_probability must be in (0, 1), got 1.0"),
    ({"monitor_mean_error_probability": True}, "monitor_mean_error_probability must be in (0, 1)"),
    ({"monitor_mean_error_probability": 0.98}, "monitor_mean_error_probability (0.98) must be at least monitor_warn_probability (0.99)"),
    ({"monitor_persistence": 0}, "monitor_persistence must be an integer in [1, monitor_window_samples = 20], got 0"),
    ({"monitor_persistence": 21}, "monitor_persistence must be an integer in [1, monitor_window_samples = 20], got 21"),
    ({"monitor_persistence": 2.0}, "monitor_persistence must be an integer in [1, monitor_window_samples = 20]"),
    ({"tracker_stale_s": 0.0}, "tracker_stale_s must be a number > 0 (inf: never stale), got 0.0"),
    ({"tracker_stale_s": float("nan")}, "tracker_stale_s must be a number > 0 (inf: never stale), got nan"),
    ({"tracker_stale_s": True}, "tracker_stale_s must be a number > 0 (inf: never stale), got True"),
    ({"monitor_persistence": True}, "monitor_persistence must be an integer in [1, monitor_window_samples = 20]"),
    ({"bias_recovery_sigma_rad_s": -1e-6}, "bias_recovery_sigma_rad_s must be >= 0"),
    ({"monitor_drift_shift_sigma": 0.0}, "monitor_drift_shift_sigma must be a finite number > 0, got 0.0"),
    ({"monitor_drift_shift_sigma": math.inf}, "monitor_drift_shift_sigma must be a finite number > 0"),
    ({"monitor_drift_shift_sigma": True}, "monitor_drift_shift_sigma must be a finite number > 0"),
    ({"monitor_drift_false_alarm": 1.0}, "monitor_drift_false_alarm must be in [0, 1) (0: no drift test), got 1.0"),
    ({"monitor_drift_false_alarm": -1e-9}, "monitor_drift_false_alarm must be in [0, 1)"),
    ({"monitor_drift_false_alarm": math.nan}, "monitor_drift_false_alarm must be in [0, 1)"),
    ({"monitor_drift_false_alarm": "1e-6"}, "monitor_drift_false_alarm must be in [0, 1)"),
    # six CUSUMs of reference 2.5 alarming at 0.9 a sample: no positive threshold does that
    ({"monitor_drift_shift_sigma": 5.0, "monitor_drift_false_alarm": 0.9}, "monitor_drift_false_alarm (0.9) is too large for monitor_drift_shift_sigma (5.0)"),
])
def test_a_bad_setting_is_refused_with_its_name(kw: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(words)):
        config(**kw)


def test_a_prior_off_the_unit_sphere_is_refused() -> None:
    with pytest.raises(InputError, match=re.escape("initial_q_BN must be a unit quaternion")):
        config(initial_q_BN=(0.0, 0.0, 0.0, 2.0), initial_attitude_sigma_rad=0.1)


def test_the_boundary_values_are_accepted() -> None:
    """The closed ends of each range: no gate (0), one rejection, a window of 1 and of
    MON_MAX_WINDOW, a persistence equal to the window, equal warning and error probabilities,
    the unit-norm tolerance itself, a recovery of 0, bias and noise walks of 0, no drift test (0)."""
    c = config(gate_false_alarm=0.0, max_consecutive_rejections=1, monitor_window_samples=1, monitor_persistence=1,
               monitor_warn_probability=0.9, monitor_error_probability=0.9, monitor_mean_error_probability=0.9,
               max_attitude_norm_error=QUATERNION_NORM_TOL,
               bias_recovery_sigma_rad_s=0.0, gyro_angle_random_walk_rad_sqrt_s=0.0, gyro_bias_random_walk_rad_s_sqrt_s=0.0,
               monitor_drift_false_alarm=0.0)
    assert c.params()[mekf.EP_MON_WINDOW] == 1 and c.params()[mekf.EP_MON_DRIFT + 1] == math.inf
    assert config(monitor_window_samples=mekf.MON_MAX_WINDOW, monitor_persistence=mekf.MON_MAX_WINDOW).params()[mekf.EP_MON_PERSIST] == 100
    assert config(max_body_rate_rad_s=1, initial_bias_rad_s=-1e-6).params()[mekf.EP_MAX_RATE] == 1.0  # an int, a negative bias


def test_the_chi_square_quantiles() -> None:
    """``chi2_3dof_isf`` refuses a probability outside (0, 1) and is scipy's quantile inside, up to
    and beyond a bracket of 3 (the root search doubles it); ``chi2_band`` is the equal-tailed band."""
    for p in (0.0, 1.0, -0.1, 1.5):
        with pytest.raises(ConfigError, match=re.escape(f"a false-alarm probability must be in (0, 1), got {p!r}")):
            chi2_3dof_isf(p)
    for p in (0.99, 0.5, 0.4, 0.2, 1e-2, 1e-6, 1e-15):
        assert chi2_3dof_isf(p) == pytest.approx(chi2.isf(p, 3), rel=1e-12), p
    lo, hi = chi2_band(60, 0.99)
    assert lo == pytest.approx(chi2.ppf(0.005, 60), rel=QUANTILE_RTOL) and hi == pytest.approx(chi2.isf(0.005, 60), rel=QUANTILE_RTOL)


def test_the_drift_threshold_inverts_the_mean_run_length() -> None:
    """``cusum_threshold`` is the inverse of ``cusum_mean_run_length`` for six CUSUMs (three
    components, two signs) across references and false-alarm probabilities, to the rounding of its
    solve; the run length grows with the threshold and with the reference (subtracted from every
    sample, it pulls a consistent filter's statistic down harder); ``0`` is no test."""
    for k in (0.05, 0.25, 0.5, 1.5):
        for p in (1e-2, 1e-4, 5e-6, 1e-9):
            h = cusum_threshold(k, p)
            assert 6.0 / cusum_mean_run_length(k, h) == pytest.approx(p, rel=1e-12), (k, p)
    assert cusum_mean_run_length(0.25, 20.0) < cusum_mean_run_length(0.25, 21.0)
    assert cusum_mean_run_length(0.3, 20.0) > cusum_mean_run_length(0.25, 20.0)
    assert cusum_threshold(0.25, 0.0) == math.inf


def test_a_batch_packs_one_row_per_run() -> None:
    c = config()
    arrays = pack_estimator(c, 3)
    assert arrays.prm.shape == (3, mekf.N_EST_PARAMS) and arrays.prm.flags.c_contiguous and arrays.prm.flags.writeable
    assert all(row.tolist() == c.params().tolist() for row in arrays.prm)
    assert pack_estimator(None, 4).prm.shape == (4, 0)
    rows = np.arange(2.0 * mekf.N_EST_PARAMS).reshape(2, mekf.N_EST_PARAMS)
    own = pack_estimator(c, 2, rows)
    assert own.prm.tolist() == rows.tolist() and own.prm is not rows  # a copy: the caller's rows are not aliased
    with pytest.raises(ValueError, match=re.escape(f"estimator params must be (3, {mekf.N_EST_PARAMS}), got (2, {mekf.N_EST_PARAMS})")):
        pack_estimator(c, 3, rows)
    assert mekf.EstimatorArrays.run_axes() == {"prm": 0}


# ----------------------------------------------------------------------------- Mekf


def _samples(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, omega, epoch) of a body turning at a constant rate, a 10 Hz tracker held at 100 Hz
    (noise-free: the object's bookkeeping is under test, not the filter)."""
    rate = np.array([0.01, -0.02, 0.005])
    t = np.arange(n) * 0.01
    epoch = np.floor(t * 10.0 + 1e-9) / 10.0
    angle = np.linalg.norm(rate) * epoch
    axis = rate / np.linalg.norm(rate)
    q = np.column_stack((np.sin(angle / 2)[:, None] * axis, np.cos(angle / 2)))
    omega = np.broadcast_to(rate + 1e-6, (n, 3)).copy()
    return t, q, omega, epoch


def test_mekf_is_the_kernel_called_sample_by_sample_and_reads_its_state() -> None:
    c = config()
    f = Mekf(c)
    assert f.config is c and f.prm.tolist() == c.params().tolist() and not f.initialised
    assert not f.usable and np.isnan(f.nis) and np.isnan(f.monitor_nis_sum) and np.isnan(f.monitor_mean_statistic)
    f.warm_up()  # throwaway arrays: this filter untouched
    assert not f.initialised and np.array_equal(f.st, mekf.new_state(), equal_nan=True)
    assert np.all(f.P == 0.0) and np.all(np.isnan(f.out))
    n = 260
    t, q, omega, epoch = _samples(n)
    st, P, work, out = mekf.new_state(), np.zeros((6, 6)), np.zeros((mekf.N_EST_WORK, 6)), np.zeros(mekf.N_EST_OUT)
    y = np.zeros(mekf.N_MEAS)
    for k in range(n):
        status = f.step(float(t[k]), q[k], omega[k], float(epoch[k]))
        y[:4], y[4:7], y[mekf.Y_EPOCH] = q[k], omega[k], epoch[k]
        assert status == mekf.mekf_step(c.params(), float(t[k]), y, st, P, work, out)
        np.testing.assert_array_equal(f.out, out)
        np.testing.assert_array_equal(f.P, P)
    assert f.initialised and f.usable
    assert f.q_BN.tolist() == out[mekf.EO_Q:mekf.EO_Q + 4].tolist()
    assert f.omega_BN_B.tolist() == out[mekf.EO_OMEGA:mekf.EO_OMEGA + 3].tolist()
    assert f.gyro_bias_rad_s.tolist() == out[mekf.EO_B:mekf.EO_B + 3].tolist()
    assert f.attitude_sigma_rad.tolist() == out[mekf.EO_SIGMA:mekf.EO_SIGMA + 3].tolist()
    assert f.bias_sigma_rad_s.tolist() == out[mekf.EO_SIGMA + 3:mekf.EO_SIGMA + 6].tolist()
    assert f.nis == st[mekf.ES_NIS] and not np.isnan(f.nis)
    assert f.updates == st[mekf.ES_N_UPD] == 25  # the tracker's samples at 0.1 .. 2.5 s
    assert (f.rejections, f.reinitialisations, f.recoveries) == (0, 0, 0)
    # noise-free samples: the windows' NIS sums fall below the error band (the tracker is far better than its R
    # says) at each of the 6 verdicts: ERROR from the second (the persistence), no recovery (not overconfident)
    assert f.monitor_level == mekf.MON_ERROR and f.monitor_nis_sum < f.prm[mekf.EP_MON_NIS]
    assert f.monitor_nis_sum == st[mekf.ES_MON_NIS] and f.monitor_mean_statistic == st[mekf.ES_MON_MEAN]
    # the drift test's statistic, the largest of its six CUSUMs, as the kernel gives it (0: noise-free samples' whitened
    # innovations stay below the reference value), no drift alarm
    assert f.monitor_drift_statistic == out[mekf.EO_MON_DRIFT] == max(st[mekf.ES_MON_DRIFT:mekf.ES_MON_DRIFT + 6]) == 0.0
    assert f.drift_alarms == 0 and isinstance(f.drift_alarms, int) and isinstance(f.monitor_drift_statistic, float)
    assert isinstance(f.updates, int) and isinstance(f.monitor_level, int) and isinstance(f.usable, bool)

"""The estimator's settings: a frozen, validated dataclass, and its packing for the kernel.

:class:`MekfConfig` holds every number the filter needs, stated as the sensors' data-sheet
quantities (star-tracker noise, gyro angle and bias random walks), so that a user who states the
hardware gets a consistent filter without hand tuning: ``R = tracker_noise_rad^2``,
``sigma_v = angle random walk``, ``sigma_u = bias random walk`` (:mod:`.mekf`).  A scenario's
``estimator`` section fills what it does not state from its ``sensors`` section
(:func:`sappc.scenario`); the estimator node takes them as parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, check_positive, check_unit_quaternion
from sappc_estimator.core import mekf

__all__ = ["pack_estimator", "DEFAULT_GATE_FALSE_ALARM", "DEFAULT_MONITOR_ERROR_PROBABILITY", "DEFAULT_MONITOR_WARN_PROBABILITY",
           "DEFAULT_MONITOR_WINDOW_SAMPLES", "DEFAULT_MONITOR_PERSISTENCE", "DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA", "DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY",
           "DEFAULT_MONITOR_DRIFT_FALSE_ALARM", "CUSUM_OVERSHOOT_SIGMA", "cusum_mean_run_length", "cusum_threshold", "chi2_band", "DEFAULT_MAX_BODY_RATE_RAD_S", "DEFAULT_INITIAL_BIAS_SIGMA_RAD_S", "DEFAULT_MAX_CONSECUTIVE_REJECTIONS", "MekfConfig", "chi2_3dof_isf"]

Array = NDArray[np.float64]

#: Probability that the innovation gate rejects a good tracker sample (chi-square, 3 degrees of
#: freedom): 1e-4 gives the threshold 21.1; a 10 Hz tracker then loses one good sample in about
#: 17 minutes, while an outlier of 5 sigma or more is rejected.
DEFAULT_GATE_FALSE_ALARM = 1e-4
#: Consecutive rejected tracker samples after which the filter re-initialises its attitude from
#: the tracker: 20 (2 s at 10 Hz), far longer than an outlier burst and far shorter than a run.
DEFAULT_MAX_CONSECUTIVE_REJECTIONS = 20
#: Default ``max_body_rate_rad_s`` [rad/s] (573 deg/s): above the full-scale range of spacecraft
#: rate gyros (navigation-grade fibre-optic gyros measure up to 10 to 20 deg/s, MEMS gyros up to
#: about 7 rad/s), so a larger measured rate is a sensor or link fault, not a state (the
#: controller's input check takes the same default for the same reason).
DEFAULT_MAX_BODY_RATE_RAD_S = 10.0
#: 1-sigma of the gyro bias before the first estimate [rad/s] when the user gives none: 1e-5 rad/s
#: (about 2 deg/h), the order of a fibre-optic or good MEMS gyro's turn-on bias before
#: calibration; the filter converges from it within seconds at 10 Hz tracker updates.
DEFAULT_INITIAL_BIAS_SIGMA_RAD_S = 1e-5
#: The health monitor's window [compared tracker samples]: 20 (2 s at 10 Hz).  Long enough that a
#: drift of a few tracker sigmas per window stands out of the band of ``3 x 20`` degrees of freedom,
#: short enough that a bias step on a cross-boresight axis is flagged before the innovation gate
#: starts rejecting (measured: docs/estimator.md, "Health monitor").
DEFAULT_MONITOR_WINDOW_SAMPLES = 20
#: Probability that a consistent filter's window stays inside the monitor's warning band
#: (two-sided; 1 % of a consistent filter's verdicts warn).
DEFAULT_MONITOR_WARN_PROBABILITY = 0.99
#: Probability that a consistent filter's window NIS sum stays inside the monitor's error band
#: (two-sided), per verdict: 1 - 1e-6.  The band tests the innovations' spread (an overconfident
#: filter, a tracker noisier than its R); a mean shift (a bias step) raises the sum too, but the mean
#: test and the drift test see it first.  The monitor is chosen for the rate at which a consistent
#: filter fails (a false recovery) per hour of flight, not per verdict: the verdicts slide by one
#: sample, 36 000 an hour at 10 Hz.  At rest over 400 h of a consistent filter (docs/estimator.md,
#: "False alarms, per hour"), the band at 1 - 3e-5 (the design before, with the mean test) failed it
#: 0.085 times an hour, at 1 - 1e-6 0.005: the 0.08 an hour it frees are the drift test's budget
#: (:data:`DEFAULT_MONITOR_DRIFT_FALSE_ALARM`), so the monitor fails a consistent filter less often
#: than before (0.27 an hour against 0.34, the same 400 h through the kernel).
DEFAULT_MONITOR_ERROR_PROBABILITY = 1.0 - 1e-6
#: Probability that a consistent filter's window mean statistic stays below the mean test's error
#: bound, per verdict: 1 - 3e-5 (23.6).  With :data:`DEFAULT_MONITOR_PERSISTENCE` it fails a
#: consistent filter 0.255 times an hour (at rest, 400 h): the largest share of the monitor's false
#: alarms, kept because it flags a large bias step sooner than the drift test (a 20-sample test
#: reacts at once to a shift of a sigma or more, a CUSUM tuned to half a sigma accumulates): about a
#: cross-boresight axis a 2e-5 rad/s step must be flagged before the gate rejects a sample (~1.8 s),
#: and at 1 - 2e-5, or with 3 verdicts in a row, it is not (issue 33; docs/estimator.md, "False
#: alarms").  At the gate's 1e-4 a verdict and no persistence (issue 33's first design) a consistent
#: filter failed 2.5 times an hour (white innovations) and 4.5 times an hour on the flight scenario
#: (3 of 40 one-minute runs).
DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY = 1.0 - 3e-5
#: Consecutive verdicts outside the error band before the monitor fails (ERROR, the recovery); a
#: single one is WARN.  60 % of a consistent filter's excursions out of the error band last a single
#: verdict (white innovations, 400 h: 0.75 an hour at 1 - 3e-5, 0.30 of two verdicts or more), a
#: drift's keeps growing: 2 (0.1 s at 10 Hz) delays a bias step's flag by one tracker sample.
DEFAULT_MONITOR_PERSISTENCE = 2
#: The mean shift of the whitened innovations [innovation sigmas] the drift test is tuned to: its
#: CUSUMs' reference value is half of it (Page 1954; for a shift of this size the CUSUM is the
#: quickest test at a given false-alarm rate, Lorden 1971, Moustakides 1986).  0.5: what a 1e-5
#: rad/s gyro bias step about the tracker's boresight shows in the flight scenario's whitened z
#: innovation (the filter's noise-free response: 0.46 five seconds after the step, 0.65 after ten;
#: docs/estimator.md, "The drift test"), the smallest of issue 46's steps that any test of these
#: innovations can flag within 10 s at this false-alarm rate (the 5e-6 step's whole response over
#: those 10 s is 2.3 sigmas); a cross-boresight step of 5e-6 rad/s shows 0.8 and is flagged sooner.
DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA = 0.5
#: Probability per compared tracker sample that the drift test fails a consistent filter (the
#: inverse of its mean run length between false alarms): 1e-6, one false drift alarm in a million
#: compared samples (28 h at 10 Hz: 0.036 an hour; measured at rest over 400 h, 11 alarms: 0.028).  Its budget
#: is what the NIS sum's stricter error band frees (:data:`DEFAULT_MONITOR_ERROR_PROBABILITY`).
DEFAULT_MONITOR_DRIFT_FALSE_ALARM = 1e-6
#: The drift test's one-sided CUSUMs: three whitened components, each upward and downward.
_DRIFT_CUSUMS = 6
#: Siegmund's correction to a CUSUM's threshold for the overshoot of normal increments [sigmas]:
#: ``-2 zeta(1/2) / sqrt(2 pi)`` = 1.1652 (Siegmund, *Sequential Analysis*, Springer 1985, ch. X;
#: Basseville and Nikiforov, *Detection of Abrupt Changes*, Prentice Hall 1993, 5.2).
CUSUM_OVERSHOOT_SIGMA = 2.0 * 1.4603545088095868 / math.sqrt(2.0 * math.pi)
#: Iterations of :func:`cusum_threshold`'s fixed-point solve: it contracts by ``1 / (A + x + 1)``
#: a step (1.3e-6 at the defaults: 3 iterations reach the rounding level; at most 0.57 for any
#: accepted value), so 200 only bound a bug.
_CUSUM_MAX_ITERATIONS = 200


#: Iterations of :func:`chi2_3dof_isf`'s safeguarded Newton solve: it converges to the rounding
#: level in 6 to 10 from its start for every ``p`` in [1e-300, 1 - 1e-16]; 100 only bounds a bug.
_ISF_MAX_ITERATIONS = 100


def _chi2_3dof_sf(x: float) -> float:
    """``P(chi2_3 > x)`` in closed form: ``erfc(sqrt(x/2)) + sqrt(2x/pi) exp(-x/2)``."""
    return math.erfc(math.sqrt(0.5 * x)) + math.sqrt(2.0 * x / math.pi) * math.exp(-0.5 * x)


def chi2_3dof_isf(p: float) -> float:
    """The ``x`` with ``P(chi2_3 > x) = p`` (chi-square with 3 degrees of freedom), ``0 < p < 1``:
    Newton's method on the closed-form survival function (its derivative is minus the density
    ``sqrt(x) exp(-x/2) / sqrt(2 pi)``), kept inside a shrinking bracket (no scipy.stats, whose
    import costs half a second at every start-up).  Within 1e-12 relative of scipy's for ``p`` in
    [1e-100, 0.999] (tested); above 0.999 the survival function's ``1 - tiny`` loses digits (a gate
    that rejects 99.9 % of good samples is no gate), below 1e-300 it underflows."""
    if not 0.0 < p < 1.0:
        raise ConfigError(f"a false-alarm probability must be in (0, 1), got {p!r}")
    lo, hi = 0.0, 3.0
    while _chi2_3dof_sf(hi) > p:  # the root is below hi
        lo, hi = hi, 2.0 * hi
    x = 0.5 * (lo + hi)
    for _ in range(_ISF_MAX_ITERATIONS):
        f = _chi2_3dof_sf(x) - p
        if f > 0.0:
            lo = x
        else:
            hi = x
        density = math.sqrt(x) * math.exp(-0.5 * x) / math.sqrt(2.0 * math.pi)
        step = f / density if density > 0.0 else math.inf
        new = x + step
        if not lo < new < hi:
            new = 0.5 * (lo + hi)
        if abs(new - x) <= 4.0 * math.ulp(x):
            return new
        x = new
    return x


def chi2_band(dof: int, probability: float) -> tuple[float, float]:
    """The two-sided ``probability`` band of a chi-square variable with ``dof`` degrees of freedom
    (equal tails): the test of a sum of ``dof / 3`` NIS values of a consistent filter (Bar-Shalom,
    Li and Kirubarajan, *Estimation with Applications to Tracking and Navigation*, Wiley 2001,
    5.4.2).  ``scipy.special.chdtri`` (the inverse survival function), imported here only: the
    band is computed when a filter's parameters are packed, never at import."""
    from scipy.special import chdtri

    tail = 0.5 * (1.0 - probability)
    return float(chdtri(dof, 1.0 - tail)), float(chdtri(dof, tail))


def cusum_mean_run_length(reference: float, threshold: float) -> float:
    """The mean number of samples between false alarms of one one-sided CUSUM
    ``g <- max(0, g + w - reference)``, alarm at ``g > threshold``, on independent N(0, 1) samples
    ``w`` (a consistent filter's whitened innovation component), by Siegmund's approximation:
    ``(exp(2 k b) - 2 k b - 1) / (2 k^2)`` with ``k`` the reference and ``b = threshold +``
    :data:`CUSUM_OVERSHOOT_SIGMA` (Siegmund 1985; within a few per cent of the exact run length for
    thresholds of a few sigmas and more, tested by simulation).  ``reference > 0``."""
    b = threshold + CUSUM_OVERSHOOT_SIGMA
    x = 2.0 * reference * b
    return (math.expm1(x) - x) / (2.0 * reference * reference)


def cusum_threshold(reference: float, false_alarm: float) -> float:
    """The drift test's threshold [innovation sigmas]: the ``h`` at which its
    :data:`_DRIFT_CUSUMS` one-sided CUSUMs of reference ``reference`` fail a consistent filter with
    probability ``false_alarm`` per compared sample together (``6 / false_alarm`` samples between
    false alarms of each, :func:`cusum_mean_run_length`); ``inf`` for ``false_alarm = 0`` (no drift
    test).  Solves ``exp(x) - x - 1 = A`` (``x = 2 k b``, ``A = 2 k^2 6 / false_alarm``) by the
    contraction ``x <- log(A + x + 1)``.

    Raises
    ------
    ConfigError
        When ``false_alarm`` is so large that the threshold would not be positive.
    """
    if false_alarm == 0.0:
        return math.inf
    A = 2.0 * reference * reference * _DRIFT_CUSUMS / false_alarm
    x = math.log1p(A)
    for _ in range(_CUSUM_MAX_ITERATIONS):
        new = math.log(A + x + 1.0)
        if abs(new - x) <= 4.0 * math.ulp(x):
            x = new
            break
        x = new
    h = x / (2.0 * reference) - CUSUM_OVERSHOOT_SIGMA
    if not h > 0.0:
        raise ConfigError(f"monitor_drift_false_alarm ({false_alarm!r}) is too large for monitor_drift_shift_sigma ({2.0 * reference!r}): "
                          f"the drift test's threshold would be {h:.3g} <= 0")
    return h


def _three(name: str, value: object, *, bound: str = "any") -> tuple[float, float, float]:
    """One number or three (x, y, z) as a 3-tuple, finite, with ``bound`` ``"any"``, ``">= 0"`` or ``"> 0"``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, tuple, list)):
        raise ConfigError(f"{name} must be one number or 3 (x, y, z), got {value!r}")
    if isinstance(value, (tuple, list)) and any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        raise ConfigError(f"{name} must be one number or 3 (x, y, z), got {value!r}")
    v = np.asarray(value, dtype=np.float64)
    v = np.full(3, float(v)) if v.ndim == 0 else v
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be one finite number or 3 (x, y, z), got {value!r}")
    if (bound == "> 0" and not np.all(v > 0)) or (bound == ">= 0" and not np.all(v >= 0)):
        raise ConfigError(f"{name} must be {bound}, got {value!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class MekfConfig:
    """Settings of the multiplicative EKF (:mod:`.mekf`, ``docs/estimator.md``).

    Attributes
    ----------
    tracker_noise_rad : float or 3 floats
        1-sigma star-tracker error about each body axis [rad] (``R``); > 0.
    gyro_angle_random_walk_rad_sqrt_s : float or 3 floats
        The gyro's angle random walk ``sigma_v`` [rad/sqrt(s)].
    gyro_bias_random_walk_rad_s_sqrt_s : float or 3 floats
        The gyro's bias (rate) random walk ``sigma_u`` [rad/s/sqrt(s)].
    initial_bias_rad_s : float or 3 floats
        The bias estimate before the first update [rad/s] (a calibration's value; 0 without one).
    initial_bias_sigma_rad_s : float or 3 floats
        The 1-sigma of ``initial_bias_rad_s`` [rad/s]; :data:`DEFAULT_INITIAL_BIAS_SIGMA_RAD_S`.
    initial_q_BN : 4 floats or None
        ``None``: the filter starts at the first star-tracker sample, with the tracker's noise as
        its attitude uncertainty.  A unit quaternion (scalar last): a prior (e.g. a coarse
        sensor's attitude), corrected by the first tracker sample; needs
        ``initial_attitude_sigma_rad``.
    initial_attitude_sigma_rad : float, 3 floats or None
        The prior's 1-sigma about each axis [rad] (``None``: the tracker's noise).
    gate_false_alarm : float
        Probability that the innovation gate rejects a good tracker sample, in ``[0, 1)``; 0 turns
        the gate off (:data:`DEFAULT_GATE_FALSE_ALARM`).
    max_consecutive_rejections : int
        Rejections in a row after which the attitude is re-initialised from the tracker, >= 1
        (:data:`DEFAULT_MAX_CONSECUTIVE_REJECTIONS`).
    max_body_rate_rad_s : float
        A measured rate beyond this [rad/s] is no measurement (:data:`DEFAULT_MAX_BODY_RATE_RAD_S`).
    max_attitude_norm_error : float
        A measured quaternion whose norm differs from 1 by more is no measurement, in
        ``(0, QUATERNION_NORM_TOL]`` (:data:`~gnc_common.validation.QUATERNION_NORM_TOL`).
    monitor_window_samples : int
        The health monitor's window [compared tracker samples], in ``[1, MON_MAX_WINDOW]``
        (:data:`DEFAULT_MONITOR_WINDOW_SAMPLES`).
    monitor_warn_probability : float
        The two-sided probability of the monitor's warning band, in (0, 1)
        (:data:`DEFAULT_MONITOR_WARN_PROBABILITY`).
    monitor_error_probability : float
        The two-sided probability of its error band (the window's NIS sum), in
        ``[monitor_warn_probability, 1)`` (:data:`DEFAULT_MONITOR_ERROR_PROBABILITY`).
    monitor_mean_error_probability : float
        The probability of the mean test's error bound (one-sided), in
        ``[monitor_warn_probability, 1)`` (:data:`DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY`).
    monitor_persistence : int
        Consecutive verdicts outside the error band before the monitor fails (ERROR and the
        recovery), in ``[1, monitor_window_samples]``; fewer are WARN (:data:`DEFAULT_MONITOR_PERSISTENCE`).
    monitor_drift_shift_sigma : float
        The mean shift of the whitened innovations [innovation sigmas] the monitor's drift test (a
        CUSUM of each component, both signs) is tuned to, > 0: its reference value is half of it
        (:data:`DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA`).
    monitor_drift_false_alarm : float
        Probability per compared tracker sample that the drift test fails a consistent filter, in
        ``[0, 1)``; its threshold follows (:func:`cusum_threshold`); 0 turns the drift test off
        (:data:`DEFAULT_MONITOR_DRIFT_FALSE_ALARM`).
    bias_recovery_sigma_rad_s : float, 3 floats or None
        The bias change [rad/s, 1-sigma per axis] a failed monitor (or a re-initialisation) admits:
        its square is added to the bias covariance.  ``None``: ``initial_bias_sigma_rad_s`` (the
        bias may be as far off as before its first estimate); 0 turns the recovery off.
    tracker_stale_s : float
        The health reports STALE once the last tracker sample the filter used is older than this
        [s] (> 0): a blinded tracker gives no innovations, so the window's verdict would stay as it
        was; ``inf`` (default): never.
    """

    tracker_noise_rad: float | tuple[float, float, float]
    gyro_angle_random_walk_rad_sqrt_s: float | tuple[float, float, float] = 0.0
    gyro_bias_random_walk_rad_s_sqrt_s: float | tuple[float, float, float] = 0.0
    initial_bias_rad_s: float | tuple[float, float, float] = 0.0
    initial_bias_sigma_rad_s: float | tuple[float, float, float] = DEFAULT_INITIAL_BIAS_SIGMA_RAD_S
    initial_q_BN: tuple[float, float, float, float] | None = None
    initial_attitude_sigma_rad: float | tuple[float, float, float] | None = None
    gate_false_alarm: float = DEFAULT_GATE_FALSE_ALARM
    max_consecutive_rejections: int = DEFAULT_MAX_CONSECUTIVE_REJECTIONS
    max_body_rate_rad_s: float = DEFAULT_MAX_BODY_RATE_RAD_S
    max_attitude_norm_error: float = QUATERNION_NORM_TOL
    monitor_window_samples: int = DEFAULT_MONITOR_WINDOW_SAMPLES
    monitor_warn_probability: float = DEFAULT_MONITOR_WARN_PROBABILITY
    monitor_error_probability: float = DEFAULT_MONITOR_ERROR_PROBABILITY
    monitor_mean_error_probability: float = DEFAULT_MONITOR_MEAN_ERROR_PROBABILITY
    monitor_persistence: int = DEFAULT_MONITOR_PERSISTENCE
    monitor_drift_shift_sigma: float = DEFAULT_MONITOR_DRIFT_SHIFT_SIGMA
    monitor_drift_false_alarm: float = DEFAULT_MONITOR_DRIFT_FALSE_ALARM
    bias_recovery_sigma_rad_s: float | tuple[float, float, float] | None = None
    tracker_stale_s: float = math.inf

    def __post_init__(self) -> None:
        _three("tracker_noise_rad", self.tracker_noise_rad, bound="> 0")
        _three("gyro_angle_random_walk_rad_sqrt_s", self.gyro_angle_random_walk_rad_sqrt_s, bound=">= 0")
        _three("gyro_bias_random_walk_rad_s_sqrt_s", self.gyro_bias_random_walk_rad_s_sqrt_s, bound=">= 0")
        _three("initial_bias_rad_s", self.initial_bias_rad_s)
        _three("initial_bias_sigma_rad_s", self.initial_bias_sigma_rad_s, bound="> 0")
        if self.initial_q_BN is not None:
            check_unit_quaternion("initial_q_BN", self.initial_q_BN)
            if self.initial_attitude_sigma_rad is None:
                raise ConfigError("initial_attitude_sigma_rad must be given with initial_q_BN (the prior's uncertainty)")
        if self.initial_attitude_sigma_rad is not None:
            _three("initial_attitude_sigma_rad", self.initial_attitude_sigma_rad, bound="> 0")
        g = self.gate_false_alarm
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not (math.isfinite(g) and 0.0 <= g < 1.0):
            raise ConfigError(f"gate_false_alarm must be in [0, 1) (0: no gate), got {g!r}")
        m = self.max_consecutive_rejections
        if isinstance(m, bool) or not isinstance(m, int) or m < 1:
            raise ConfigError(f"max_consecutive_rejections must be an integer >= 1, got {m!r}")
        for name in ("max_body_rate_rad_s", "max_attitude_norm_error"):
            if isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be a number, got {getattr(self, name)!r}")
            check_positive(name, getattr(self, name))
        w = self.monitor_window_samples
        if isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= mekf.MON_MAX_WINDOW:
            raise ConfigError(f"monitor_window_samples must be an integer in [1, {mekf.MON_MAX_WINDOW}], got {w!r}")
        for name in ("monitor_warn_probability", "monitor_error_probability", "monitor_mean_error_probability"):
            p = getattr(self, name)
            if isinstance(p, bool) or not isinstance(p, (int, float)) or not (math.isfinite(p) and 0.0 < p < 1.0):
                raise ConfigError(f"{name} must be in (0, 1), got {p!r}")
        for name in ("monitor_error_probability", "monitor_mean_error_probability"):
            if getattr(self, name) < self.monitor_warn_probability:
                raise ConfigError(f"{name} ({getattr(self, name)!r}) must be at least "
                                  f"monitor_warn_probability ({self.monitor_warn_probability!r})")
        k = self.monitor_persistence
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= w:
            raise ConfigError(f"monitor_persistence must be an integer in [1, monitor_window_samples = {w!r}], got {k!r}")
        d = self.monitor_drift_shift_sigma
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not (math.isfinite(d) and d > 0.0):
            raise ConfigError(f"monitor_drift_shift_sigma must be a finite number > 0, got {d!r}")
        f = self.monitor_drift_false_alarm
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not (math.isfinite(f) and 0.0 <= f < 1.0):
            raise ConfigError(f"monitor_drift_false_alarm must be in [0, 1) (0: no drift test), got {f!r}")
        cusum_threshold(0.5 * d, f)  # a threshold > 0, or the error naming both
        if self.bias_recovery_sigma_rad_s is not None:
            _three("bias_recovery_sigma_rad_s", self.bias_recovery_sigma_rad_s, bound=">= 0")
        ts = self.tracker_stale_s
        if isinstance(ts, bool) or not isinstance(ts, (int, float)) or not ts > 0.0:  # NaN fails too
            raise ConfigError(f"tracker_stale_s must be a number > 0 (inf: never stale), got {ts!r}")
        if self.max_attitude_norm_error > QUATERNION_NORM_TOL:
            raise ConfigError(f"max_attitude_norm_error must be in (0, {QUATERNION_NORM_TOL:g}], got {self.max_attitude_norm_error!r}")

    @property
    def gate_chi2(self) -> float:
        """The gate's threshold on the NIS (``inf``: no gate)."""
        return math.inf if self.gate_false_alarm == 0.0 else chi2_3dof_isf(self.gate_false_alarm)

    def params(self) -> Array:
        """The kernel's parameter array (:data:`.mekf.N_EST_PARAMS`,)."""
        p = np.zeros(mekf.N_EST_PARAMS)
        noise = np.asarray(_three("tracker_noise_rad", self.tracker_noise_rad))
        p[mekf.EP_R:mekf.EP_R + 3] = noise * noise
        arw = np.asarray(_three("arw", self.gyro_angle_random_walk_rad_sqrt_s))
        p[mekf.EP_SV2:mekf.EP_SV2 + 3] = arw * arw
        brw = np.asarray(_three("brw", self.gyro_bias_random_walk_rad_s_sqrt_s))
        p[mekf.EP_SU2:mekf.EP_SU2 + 3] = brw * brw
        att = noise if self.initial_attitude_sigma_rad is None else np.asarray(_three("sigma", self.initial_attitude_sigma_rad))
        p[mekf.EP_P0A:mekf.EP_P0A + 3] = att * att
        bs = np.asarray(_three("initial_bias_sigma_rad_s", self.initial_bias_sigma_rad_s))
        p[mekf.EP_P0B:mekf.EP_P0B + 3] = bs * bs
        p[mekf.EP_B0:mekf.EP_B0 + 3] = _three("initial_bias_rad_s", self.initial_bias_rad_s)
        p[mekf.EP_GATE] = self.gate_chi2
        p[mekf.EP_MAXREJ] = float(self.max_consecutive_rejections)
        p[mekf.EP_MAX_NORM_ERR] = self.max_attitude_norm_error
        p[mekf.EP_MAX_RATE] = self.max_body_rate_rad_s
        dof = 3 * self.monitor_window_samples  # the window's NIS sum: chi-square, 3 per sample
        err_lo, err_hi = chi2_band(dof, self.monitor_error_probability)
        warn_lo, warn_hi = chi2_band(dof, self.monitor_warn_probability)
        p[mekf.EP_MON_WINDOW] = float(self.monitor_window_samples)
        p[mekf.EP_MON_NIS:mekf.EP_MON_NIS + 4] = (err_lo, warn_lo, warn_hi, err_hi)
        # the mean test, one-sided: |sum of the whitened innovations|^2 / n is chi-square with 3
        p[mekf.EP_MON_MEAN] = chi2_3dof_isf(1.0 - self.monitor_warn_probability)
        p[mekf.EP_MON_MEAN + 1] = chi2_3dof_isf(1.0 - self.monitor_mean_error_probability)
        # the drift test: CUSUMs of reference half the shift, the threshold of the false-alarm probability
        reference = 0.5 * self.monitor_drift_shift_sigma
        p[mekf.EP_MON_DRIFT] = reference
        p[mekf.EP_MON_DRIFT + 1] = cusum_threshold(reference, self.monitor_drift_false_alarm)
        rec = np.asarray(_three("bias_recovery_sigma_rad_s", self.initial_bias_sigma_rad_s if self.bias_recovery_sigma_rad_s is None
                                else self.bias_recovery_sigma_rad_s))
        p[mekf.EP_RECOVERY_PBB:mekf.EP_RECOVERY_PBB + 3] = rec * rec
        p[mekf.EP_TRACKER_STALE] = float(self.tracker_stale_s)
        p[mekf.EP_MON_PERSIST] = float(self.monitor_persistence)
        if self.initial_q_BN is None:
            p[mekf.EP_INIT] = mekf.INIT_FROM_TRACKER
        else:
            q = np.asarray(self.initial_q_BN, dtype=np.float64)
            p[mekf.EP_INIT] = mekf.INIT_FROM_PRIOR
            p[mekf.EP_Q0:mekf.EP_Q0 + 4] = q / np.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3])
        return p


def pack_estimator(config: MekfConfig | None, n_runs: int, params: Array | None = None) -> mekf.EstimatorArrays:
    """A batch's estimator for the whole-run loop: ``config``'s parameters for every run, or
    ``params`` (n_runs, :data:`.mekf.N_EST_PARAMS`) one row per run (a campaign's dispersed
    sensors give each run its own filter), or none (``config`` ``None``)."""
    if params is not None:
        prm = np.array(params, dtype=np.float64, order="C")
        if prm.shape != (n_runs, mekf.N_EST_PARAMS):
            raise ValueError(f"estimator params must be ({n_runs}, {mekf.N_EST_PARAMS}), got {prm.shape}")
    elif config is None:
        prm = np.zeros((n_runs, 0))
    else:
        prm = np.array(np.broadcast_to(config.params(), (n_runs, mekf.N_EST_PARAMS)), dtype=np.float64, order="C")
    return mekf.EstimatorArrays(prm)

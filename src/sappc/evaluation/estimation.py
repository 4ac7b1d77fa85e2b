"""How good the attitude estimate is, from the truth the plant records: estimation errors and the
filter's consistency (normalised estimation error squared, NEES).

Definitions (docs/estimator.md; the filter's own error convention):

``attitude error`` ``a`` (T, N, 3) [rad]
    The rotation vector of ``q_hat^* ⊗ q_true`` (body frame, shortest rotation): the error state
    the filter estimates the covariance of.
``bias error`` ``db`` (T, N, 3) [rad/s]
    ``b_true - b_hat``.
``NEES``
    ``e^T P^-1 e`` with ``e = (a, db)`` and the filter's covariance ``P`` (6, 6) at the same
    sample.  For a consistent filter it is chi-square with 6 degrees of freedom; the mean over
    ``M`` independent runs at one time, times ``M``, is chi-square with ``6 M``
    (:func:`nees_band`).

Samples where the filter has no estimate yet (NaN) are left out of every statistic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EstimateHistory", "N_ERROR_STATES", "attitude_errors", "nees", "nees_band", "rotation_vectors"]

Array = NDArray[np.float64]

#: Error states of the filter: attitude (3) and gyro bias (3).
N_ERROR_STATES = 6


@dataclass
class EstimateHistory:
    """What the estimator gave at every sample: arrays (T, N, ...).

    ``q_BN`` (T, N, 4) the attitude estimate, ``omega_BN_B`` (T, N, 3) [rad/s] the rate estimate,
    ``gyro_bias`` (T, N, 3) [rad/s] the bias estimate, ``covariance`` (T, N, 6, 6) ``P`` (rad^2,
    rad^2/s, rad^2/s^2), ``nis`` (T, N) the last update's normalised innovation squared,
    ``status`` (T, N) int8 the step's status (:data:`sappc_estimator.core.mekf.STATUS_NAMES`), and
    ``gyro_bias_true`` (T, N, 3) [rad/s] the gyro's true bias (the truth the plant records;
    ``None`` when not recorded); the health monitor's ``monitor_level`` (T, N) (``MON_*``: 0 ok, 1
    warn, 2 error), ``monitor_nis_sum`` (T, N) its window's NIS sum, ``usable`` (T, N) 1 where the
    estimate was given to the controller, 0 where it was withheld, ``recoveries`` (T, N) the bias
    recoveries so far (each ``None`` when not recorded).  NaN where the filter had no estimate (the
    attitude and rate estimates also where it was withheld)."""

    q_BN: Array
    omega_BN_B: Array
    gyro_bias: Array
    covariance: Array
    nis: Array
    status: NDArray[np.int8]
    gyro_bias_true: Array | None = None
    monitor_level: Array | None = None
    monitor_nis_sum: Array | None = None
    usable: Array | None = None
    recoveries: Array | None = None


def rotation_vectors(q: Array) -> Array:
    """Rotation vectors (..., 3) [rad] of the shortest rotations of unit quaternions ``q`` (..., 4)
    (scalar last): ``2 atan2(|v|, |w|) v / |v|`` with the sign of ``w`` folded into ``v``."""
    sign = np.where(q[..., 3:] < 0.0, -1.0, 1.0)
    v, w = sign * q[..., :3], sign[..., 0] * q[..., 3]
    nv = np.sqrt(np.sum(v * v, axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(nv > 0.0, 2.0 * np.arctan2(nv, w) / np.where(nv > 0.0, nv, 1.0), 2.0 / w)
    out: Array = f[..., None] * v
    return out


def attitude_errors(q_est: Array, q_true: Array) -> Array:
    """``rotvec(q_est^* ⊗ q_true)`` (..., 3) [rad]: the true attitude relative to the estimate, in
    the body frame (the filter's error convention)."""
    ex, ey, ez, ew = -q_est[..., 0], -q_est[..., 1], -q_est[..., 2], q_est[..., 3]
    tx, ty, tz, tw = q_true[..., 0], q_true[..., 1], q_true[..., 2], q_true[..., 3]
    d = np.stack((
        ew * tx + tw * ex + (ey * tz - ez * ty),
        ew * ty + tw * ey + (ez * tx - ex * tz),
        ew * tz + tw * ez + (ex * ty - ey * tx),
        ew * tw - (ex * tx + ey * ty + ez * tz),
    ), axis=-1)
    return rotation_vectors(d)


def nees(errors: Array, covariance: Array) -> Array:
    """``e^T P^-1 e`` (...) of errors ``e`` (..., 6) and covariances ``P`` (..., 6, 6); NaN where
    either is NaN (no estimate)."""
    ok = np.all(np.isfinite(errors), axis=-1) & np.all(np.isfinite(covariance), axis=(-2, -1))
    out = np.full(errors.shape[:-1], np.nan)
    if np.any(ok):
        e, P = errors[ok], covariance[ok]
        x = np.linalg.solve(P, e[..., None])[..., 0]
        out[ok] = np.sum(e * x, axis=-1)
    return out


def nees_band(n_runs: int, probability: float = 0.95, dof: int = N_ERROR_STATES) -> tuple[float, float]:
    """The two-sided ``probability`` band of the NEES averaged over ``n_runs`` independent runs of
    a consistent filter: the ``chi2_{dof n}`` band (:func:`sappc_estimator.core.config.chi2_band`,
    the health monitor's) divided by ``n`` (Bar-Shalom, Li and Kirubarajan, *Estimation with
    Applications to Tracking and Navigation*, 5.4.2).  Not scipy.stats' ``chi2.ppf``: its import
    cost a campaign's summary 0.35 s; ``chdtri``'s quantiles are within 5e-16 relative of its."""
    from sappc_estimator.core.config import chi2_band

    lo, hi = chi2_band(dof * n_runs, probability)
    return lo / n_runs, hi / n_runs

"""The desired attitude trajectory of the paper (Sec. V.A).

    q_d(0) = (0, 0, 0, 1)                                   (scalar last: identity)
    omega_d(t) = A [cos(t/40), sin(t/30), -cos(t/50)],      A = 0.573 deg/s

``omega_d`` is the rate of the desired frame R relative to N in R components
(``omega_RN_R``).  docs/paper_notes.md: the amplitude is in deg/s (0.573 deg/s = 0.01
rad/s); read as rad/s the 0.5 N m actuator could not follow it.  ``q_RN`` is
integrated from ``dq_RN/dt = 1/2 q_RN ⊗ (omega_RN_R, 0)``; ``omegadot_RN_R``
is analytic.

The rates are computed by the compiled kernel
(:func:`spacecraft_sim.core.kernels.reference_rates`, the one implementation of the
formula).  The quaternion is integrated once per scenario with an 8th-order Dormand-Prince
method at ``rtol = 1e-12`` and sampled on the control grid, so the reference is
the same wherever it is used (offline runner, reference publisher node) and is
far more accurate than the plant's RK4 step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.attitude import quat_kinematics, quat_normalize
from gnc_common.validation import ConfigError, as_finite_array, check_unit_quaternion
from spacecraft_sim.core import kernels

__all__ = ["PaperReference", "ReferenceSamples", "sample_times"]

Array = NDArray[np.float64]

#: Integration tolerances of the reference quaternion: near float64 precision
#: for a unit quaternion; the error over 100 s is below 1e-11 (tests check it
#: against a constant-rate closed form).
_RTOL = 1e-12
_ATOL = 1e-14


def sample_times(duration_s: float, control_period_s: float) -> Array:
    """The sample grid ``k dt``, ``k = 0 .. round(duration / dt)`` [s], shared by the offline
    runner and the nodes (``k * dt`` is computed the same way everywhere)."""
    n_steps = int(round(duration_s / control_period_s))
    return np.arange(n_steps + 1, dtype=np.float64) * control_period_s  # k exact in float64: the same products as int k


@dataclass(frozen=True)
class ReferenceSamples:
    """The reference on a time grid: ``t`` (T,), ``q_RN`` (T, 4), ``omega_RN_R`` and ``omegadot_RN_R`` (T, 3)."""

    t: Array
    q_RN: Array
    omega_RN_R: Array
    omegadot_RN_R: Array


@dataclass(frozen=True)
class PaperReference:
    """Desired trajectory of Sec. V.A.

    Attributes
    ----------
    q_RN0 : tuple
        Initial desired attitude (scalar last).
    amplitude_deg_s : float
        Rate amplitude ``A`` [deg/s].
    periods_s : tuple of 3 floats
        The divisors of ``t`` in the three components: (40, 30, 50) [s].
    """

    q_RN0: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    amplitude_deg_s: float = 0.573
    periods_s: tuple[float, float, float] = field(default=(40.0, 30.0, 50.0))

    def __post_init__(self) -> None:
        check_unit_quaternion("reference.q_RN0", self.q_RN0)
        as_finite_array("reference.amplitude_deg_s", self.amplitude_deg_s)
        periods = as_finite_array("reference.periods_s", self.periods_s, shape_tail=(3,))
        if np.any(periods <= 0.0):
            raise ConfigError(f"reference.periods_s must be > 0, got {self.periods_s!r}")

    def rates(self, t: ArrayLike) -> tuple[Array, Array]:
        """Desired rate [rad/s] and angular acceleration [rad/s^2], each of shape ``t.shape + (3,)``
        (:func:`spacecraft_sim.core.kernels.reference_rates`)."""
        tt = np.asarray(t, dtype=np.float64)
        w, wd = kernels.rate_tables(np.ascontiguousarray(tt.reshape(-1)), float(np.radians(self.amplitude_deg_s)),
                                    np.asarray(self.periods_s, dtype=np.float64))
        return w.reshape(tt.shape + (3,)), wd.reshape(tt.shape + (3,))

    def omega_RN_R(self, t: ArrayLike) -> Array:
        """Desired rate [rad/s], shape (..., 3)."""
        return self.rates(t)[0]

    def omegadot_RN_R(self, t: ArrayLike) -> Array:
        """Desired angular acceleration [rad/s^2], shape (..., 3)."""
        return self.rates(t)[1]

    def sample(self, t: ArrayLike) -> ReferenceSamples:
        """The reference at increasing times ``t`` >= 0 [s], shape (T,)."""
        times = as_finite_array("t", t).reshape(-1)
        if times.size and (times[0] < 0.0 or np.any(np.diff(times) < 0.0)):
            raise ConfigError("reference sample times must be >= 0 and non-decreasing")
        q0 = np.asarray(self.q_RN0, dtype=np.float64)
        t_end = float(times[-1]) if times.size else 0.0
        if t_end > 0.0:
            from scipy.integrate import solve_ivp  # here, not at import: it costs 0.2 s (see cli)

            a_rad_s = float(np.radians(self.amplitude_deg_s))
            periods = np.asarray(self.periods_s, dtype=np.float64)
            w, wd = np.empty(3), np.empty(3)

            def rhs(tt: float, q: Array) -> Array:
                kernels.reference_rates(float(tt), a_rad_s, periods, w, wd)
                return quat_kinematics(q, w)

            sol = solve_ivp(
                rhs,
                (0.0, t_end),
                q0,
                method="DOP853",
                t_eval=times,
                rtol=_RTOL,
                atol=_ATOL,
            )
            q = quat_normalize(sol.y.T)
        else:
            q = np.broadcast_to(q0, (times.size, 4)).copy()
        return ReferenceSamples(times, q, *self.rates(times))

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
formula), and the quaternion by classical RK4 in compiled code
(:func:`spacecraft_sim.core.kernels.reference_quaternions`) with steps of at most
:data:`MAX_STEP_S`, so the reference is the same wherever it is used (offline runner, reference
publisher node), on every host (no BLAS call: docs/parity.md), and far more accurate than the
plant's RK4 step: for the paper's trajectory the largest error over 60 s is 5e-14 (measured
against DOP853 at ``rtol = 1e-13``), the rounding level of 6000 steps; the adaptive DOP853
integration at ``rtol = 1e-12`` used before reached 5.4e-13 and went through BLAS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray


from gnc_common.validation import ConfigError, as_finite_array, check_unit_quaternion
from spacecraft_sim.core import kernels

__all__ = ["PaperReference", "ReferenceSamples", "sample_times"]

Array = NDArray[np.float64]

#: Longest RK4 step of the reference quaternion [s]: the local error of RK4 scales as
#: ``(|omega| h)^5 / 120``, below 1e-20 for the paper's 0.01 rad/s at 10 ms (and 1e-16 up to
#: 0.17 rad/s, 10 deg/s), so the result is at the rounding level of the steps' sums; the paper's
#: control grid (10 ms) takes one step per sample, an interval that ``k dt``'s rounding puts a few
#: ulps above 10 ms included (:data:`~spacecraft_sim.core.kernels.REFERENCE_STEP_SLACK`).
MAX_STEP_S = 0.01


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

    def sample(self, t: ArrayLike, carry: Array | None = None) -> ReferenceSamples:
        """The reference at increasing times ``t`` >= 0 [s], shape (T,).

        ``carry``: a run's samples block after block, the same bits as in one call: the integrated
        quaternion and its time ``(q (4), t [s])`` from :meth:`start` (the run's start), which this
        call advances in place to ``t[-1]``; the next block's times must follow it."""
        times = as_finite_array("t", t).reshape(-1)
        state = self.start() if carry is None else carry
        if times.size and (times[0] < state[4] or np.any(np.diff(times) < 0.0)):
            raise ConfigError(f"reference sample times must be >= {state[4]!r} and non-decreasing")
        q = np.empty((times.size, 4))
        q_int = state[:4]  # a view: integrated in place
        kernels.reference_quaternions(np.ascontiguousarray(times), q_int, float(state[4]), float(np.radians(self.amplitude_deg_s)),
                                      np.asarray(self.periods_s, dtype=np.float64), MAX_STEP_S, q)
        if times.size:
            state[4] = times[-1]
        return ReferenceSamples(times, q, *self.rates(times))

    def start(self) -> Array:
        """The integration's state at the run's start, ``(q_RN0 (4), 0.0)``: :meth:`sample`'s ``carry``."""
        return np.array([*np.asarray(self.q_RN0, dtype=np.float64), 0.0])

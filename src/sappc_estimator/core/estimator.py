"""One attitude estimator as an object: the MEKF's state and buffers around the compiled kernel.

The kernel (:func:`~sappc_estimator.core.mekf.mekf_step`) works on the caller's arrays; :class:`Mekf`
owns one filter's arrays (parameters from a validated :class:`~sappc_estimator.core.config.MekfConfig`,
state, covariance, scratch, output) and steps them sample by sample, which is what the estimator
node needs.  It adds nothing to the filter: a step is one call of the kernel, bit for bit.
Pure: no ROS, no clock (the caller passes the time).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sappc_estimator.core import mekf
from sappc_estimator.core.config import MekfConfig

__all__ = ["Mekf"]

Array = NDArray[np.float64]

#: The filter state's totals (counts since the filter started), which :meth:`Mekf.restarted` carries on.
_TOTALS = [mekf.ES_N_UPD, mekf.ES_N_REJ, mekf.ES_N_REINIT, mekf.ES_N_RECOVER, mekf.ES_N_DRIFT]


class Mekf:
    """A multiplicative EKF (``docs/estimator.md``), stepped one sample at a time.

    Parameters
    ----------
    config : MekfConfig
        The validated settings.

    Attributes
    ----------
    config : MekfConfig
        The settings.
    prm : ndarray (:data:`~sappc_estimator.core.mekf.N_EST_PARAMS`,)
        The kernel's parameters (``config.params()``).
    st : ndarray (:data:`~sappc_estimator.core.mekf.N_EST_STATE`,)
        The filter state between steps.
    P : ndarray (6, 6)
        The covariance of the error state (attitude error [rad], bias error [rad/s]).
    out : ndarray (:data:`~sappc_estimator.core.mekf.N_EST_OUT`,)
        The last step's outputs (NaN before initialisation but the status).
    """

    def __init__(self, config: MekfConfig) -> None:
        self.config = config
        self.prm: Array = config.params()
        self.st: Array = mekf.new_state()
        self.P: Array = np.zeros((6, 6))
        self.work: Array = np.zeros((mekf.N_EST_WORK, 6))
        self.y: Array = np.zeros(mekf.N_MEAS)
        self.out: Array = np.full(mekf.N_EST_OUT, np.nan)

    def warm_up(self) -> None:
        """One step on throwaway arrays: loads the compiled kernel now (the numba cache, about a
        second), not at the first sample; this filter's state is not touched."""
        at_rest = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0])  # identity attitude, at rest, measured at t = 0
        mekf.mekf_step(self.prm, 0.0, at_rest, mekf.new_state(), np.zeros((6, 6)), np.zeros_like(self.work), np.empty(mekf.N_EST_OUT))

    def restarted(self) -> Mekf:
        """A fresh filter of the same config (not initialised: ``Mekf(self.config)``) whose totals go
        on from this one's: the tracker samples accepted and gated out, the re-initialisations, the
        recoveries and the drift alarms.  The kernel only ever adds to these counts (no step reads
        them), so the fresh filter steps exactly as a new one, bit for bit, its outputs but the
        recoveries' total included (the managed estimator node's later activation)."""
        fresh = Mekf(self.config)
        fresh.st[_TOTALS] = self.st[_TOTALS]
        return fresh

    def step(self, t_s: float, q_meas: ArrayLike, omega_meas: ArrayLike, epoch_s: float) -> int:
        """One filter step at time ``t_s`` [s] with the tracker's ``q_meas`` (x, y, z, w), measured
        at ``epoch_s`` [s] (the tracker sample's own time, ``<= t_s``: a new sample is one of a later
        epoch), and the gyro's ``omega_meas`` [rad/s]; returns the step's status
        (``mekf.STATUS_*``), outputs in :attr:`out` and the properties below."""
        self.y[:4] = q_meas
        self.y[4:7] = omega_meas
        self.y[mekf.Y_EPOCH] = epoch_s
        return int(mekf.mekf_step(self.prm, t_s, self.y, self.st, self.P, self.work, self.out))

    @property
    def initialised(self) -> bool:
        """Whether the filter has an estimate."""
        return bool(self.st[mekf.ES_INIT] != 0.0)

    @property
    def usable(self) -> bool:
        """Whether the last step's estimate may be used (initialised and confirmed: not a prior or a
        re-initialisation that no tracker sample has confirmed yet)."""
        return bool(self.out[mekf.EO_USABLE] == 1.0)

    @property
    def monitor_level(self) -> int:
        """The health monitor's level (``mekf.MON_*``: the ROS diagnostic levels OK, WARN, ERROR)."""
        return int(self.st[mekf.ES_MON_LEVEL])

    @property
    def monitor_nis_sum(self) -> float:
        """The monitor window's NIS sum at its last verdict (NaN before the first)."""
        return float(self.st[mekf.ES_MON_NIS])

    @property
    def monitor_mean_statistic(self) -> float:
        """The monitor window's mean statistic at its last verdict (NaN before the first)."""
        return float(self.st[mekf.ES_MON_MEAN])

    @property
    def monitor_outside(self) -> int:
        """Consecutive verdicts outside the error band so far (the monitor fails at its persistence)."""
        return int(self.st[mekf.ES_MON_OUTSIDE])

    @property
    def monitor_drift_statistic(self) -> float:
        """The drift test's statistic after the last step: the largest of its six CUSUMs [innovation
        sigmas] (the monitor fails above ``prm[mekf.EP_MON_DRIFT + 1]``; 0 after the window is emptied)."""
        return float(np.max(self.st[mekf.ES_MON_DRIFT : mekf.ES_MON_DRIFT + 6]))

    @property
    def monitor_drift_threshold(self) -> float:
        """The drift test's threshold [innovation sigmas]: the monitor fails when the statistic passes it."""
        return float(self.prm[mekf.EP_MON_DRIFT + 1])

    @property
    def drift_alarms(self) -> int:
        """Failed monitors the drift test started (each a recovery or a re-initialisation)."""
        return int(self.st[mekf.ES_N_DRIFT])

    @property
    def recoveries(self) -> int:
        """Bias covariance inflations after a failed monitor."""
        return int(self.st[mekf.ES_N_RECOVER])

    @property
    def q_BN(self) -> Array:
        """The last step's attitude estimate (x, y, z, w); a view of :attr:`out`."""
        return self.out[mekf.EO_Q : mekf.EO_Q + 4]

    @property
    def omega_BN_B(self) -> Array:
        """The last step's rate estimate [rad/s] (the measured rate less the bias); a view."""
        return self.out[mekf.EO_OMEGA : mekf.EO_OMEGA + 3]

    @property
    def gyro_bias_rad_s(self) -> Array:
        """The bias estimate [rad/s]; a view."""
        return self.out[mekf.EO_B : mekf.EO_B + 3]

    @property
    def attitude_sigma_rad(self) -> Array:
        """1-sigma of the attitude error per body axis [rad]; a view."""
        return self.out[mekf.EO_SIGMA : mekf.EO_SIGMA + 3]

    @property
    def bias_sigma_rad_s(self) -> Array:
        """1-sigma of the bias error per axis [rad/s]; a view."""
        return self.out[mekf.EO_SIGMA + 3 : mekf.EO_SIGMA + 6]

    @property
    def nis(self) -> float:
        """The last normalised innovation squared (NaN before the first tracker sample was compared)."""
        return float(self.st[mekf.ES_NIS])

    @property
    def updates(self) -> int:
        """Tracker samples accepted."""
        return int(self.st[mekf.ES_N_UPD])

    @property
    def rejections(self) -> int:
        """Tracker samples rejected by the innovation gate."""
        return int(self.st[mekf.ES_N_REJ])

    @property
    def reinitialisations(self) -> int:
        """Attitude re-initialisations after consecutive rejections."""
        return int(self.st[mekf.ES_N_REINIT])

"""Time histories of a run or a batch: the record that offline runs, campaigns and bags share.

Offline runs and campaigns get it from the compiled loop
(:meth:`sappc.offline.compiled_loop.CompiledRun.history`), bags from :mod:`sappc.bag.read`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc.evaluation.estimation import EstimateHistory

__all__ = ["History"]

Array = NDArray[np.float64]

@dataclass
class History:
    """Full time histories of a run or a batch: arrays (T, N, ...) with ``t`` (T,).

    With reaction wheels (W of them), ``wheel_speed_rad_s`` (T, N, W) each wheel's speed relative
    to the body and ``wheel_torque_Nm`` (T, N, W) its motor torque; ``None`` with the ideal actuator.
    With an estimator, ``estimate`` what it gave (:class:`~sappc.evaluation.estimation.EstimateHistory`);
    ``None`` without.  In orbit, ``orbit`` (T, N, 9 + M): the true field ``B_B`` [T], the flight
    software's (measured) field [T], the environment's torque ``L_env_B`` [N m] and the M rods'
    dipole commands [A m^2] (:attr:`sappc.offline.compiled_loop.LoopRecord.env`'s columns; from a
    bag the torque is NaN, not published, and the rods' columns are there with a management node's
    ``control/dipole`` only); ``None`` without an orbit.  ``answer`` (T, N) int8: how the controller
    answered each sample (the contract's ``ANSWER_*`` codes, the loop's record of them); ``None``
    where not recorded (a bag's are :attr:`sappc.bag.read.BagRun.answer`).  With flight modes,
    ``mode`` (T, N) int8 the mode flown (:data:`sappc_modes.core.modes.MODE_NAMES`' index) and
    ``mode_reason`` (T, N) int8 the reason of the transition taken at the sample (``R_*``,
    ``R_NONE`` for none); ``None`` without modes."""

    t: Array
    q_BN: Array
    omega_BN_B: Array
    q_BR: Array
    torque_B: Array
    torque_cmd_B: Array
    saturated: NDArray[np.bool_]
    disturbance_B: Array
    rho: Array
    band_lower: Array
    band_upper: Array
    eps: Array
    z: Array
    V: Array
    wheel_speed_rad_s: Array | None = None
    wheel_torque_Nm: Array | None = None
    estimate: EstimateHistory | None = None
    orbit: Array | None = None
    answer: NDArray[np.int8] | None = None
    mode: NDArray[np.int8] | None = None
    mode_reason: NDArray[np.int8] | None = None

    @property
    def q_ev(self) -> Array:
        """Vector part of the error quaternion, (T, N, 3)."""
        return self.q_BR[..., :3]

    def samples(self, lo: int, hi: int) -> History:
        """Samples ``lo .. hi - 1`` of every array (the estimator's record included): views, no
        copy.  The metrics take a long record this way, a block at a time
        (:meth:`sappc.evaluation.metrics.MetricsAccumulator.add_history`)."""
        def cut(record: Any) -> dict[str, Any]:
            return {f.name: a[lo:hi] for f in dataclasses.fields(record) if isinstance(a := getattr(record, f.name), np.ndarray)}

        est = self.estimate
        return dataclasses.replace(self, **cut(self), estimate=None if est is None else dataclasses.replace(est, **cut(est)))

"""The offline closed loop: controller core + rigid-body plant core, one run or a batch.

Timing (the same as the lockstep ROS 2 graph): at ``t_k = k dt`` the plant's
state is sampled, the controller computes the torque from it and the
reference at ``t_k``, the disturbance is sampled at ``t_k``, and the plant
integrates over ``[t_k, t_k+1]`` with both held (zero-order hold).  Samples are
taken for ``k = 0 .. n_steps``; the torque computed at the last sample is
logged but not applied.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from sappc_controller.core.base import AttitudeController
from gnc_common.attitude import error_quaternion
from spacecraft_sim.core.disturbance import DisturbanceModel
from spacecraft_sim.core.dynamics import RigidBody
from spacecraft_sim.core.reference import ReferenceSamples
from spacecraft_sim.core.reference import sample_times as step_times

from sappc.evaluation.history import Observer

__all__ = ["run_closed_loop", "step_times"]

Array = NDArray[np.float64]

#: Samples of disturbance evaluated at once: amortises the models' numpy calls
#: while a block for 3000 runs stays small (256 x 3000 x 3 doubles = 18 MB).
DISTURBANCE_BLOCK = 256

def run_closed_loop(
    plant: RigidBody,
    controller: AttitudeController,
    reference: ReferenceSamples,
    disturbance: DisturbanceModel,
    x0: Array,
    control_period_s: float,
    *,
    substeps: int = 1,
    observer: Observer,
    measure: Callable[[int, Array], Array] | None = None,
) -> Array:
    """Simulate the closed loop over the reference's time grid.

    Parameters
    ----------
    plant : RigidBody
    controller : AttitudeController
        Reset before the run.
    reference : ReferenceSamples
        Desired trajectory sampled at ``step_times(duration, dt)``.
    disturbance : DisturbanceModel
    x0 : ndarray, shape (N, 7)
        Initial states (unit quaternions, finite rates; checked by the caller).
    control_period_s : float
        Sampling period ``dt`` [s].
    substeps : int
        RK4 steps per control period.
    observer : callable
        Called at every sample (see :data:`Observer`).
    measure : callable, optional
        ``measure(k, x) -> x_measured``: the state the controller sees (sensor
        model).  The observer still gets the true state, and ``out.q_BR`` is
        replaced by the *true* error quaternion, so metrics describe the real
        attitude error while the torque comes from the measurement.

    Returns
    -------
    ndarray, shape (N, 7)
        The final state.
    """
    controller.reset()
    x = np.array(x0, dtype=np.float64, order="F")  # components contiguous over runs (see attitude.py)
    n_runs = x.shape[0]
    ref = reference
    last = ref.t.size - 1
    d_block = np.empty((0, 1, 3))
    for k in range(ref.t.size):
        if k % DISTURBANCE_BLOCK == 0:  # disturbances are pure functions of time: sample a block at once
            d_block = disturbance.torque_B(ref.t[k : k + DISTURBANCE_BLOCK], n_runs)
        t = float(ref.t[k])
        ref_k = (ref.q_RN[k : k + 1], ref.omega_RN_R[k : k + 1], ref.omegadot_RN_R[k : k + 1])
        y = x if measure is None else measure(k, x)
        out = controller.step_unchecked(t, control_period_s, controller.error_state(y[:, :4], y[:, 4:], *ref_k))
        if measure is not None:
            out = dataclasses.replace(out, q_BR=error_quaternion(ref_k[0], x[:, :4]))
        d = d_block[k % DISTURBANCE_BLOCK]
        observer(k, t, x, out, d)
        if k < last:
            x = plant.propagate(x, out.torque_B + d, control_period_s, substeps)
    return x

"""Rigid-body attitude dynamics and a fixed-step RK4 integrator with zero-order-hold inputs.

Model (eq. errorsystem written for the body, Assumption 1):

    dq_BN/dt      = 1/2 q_BN ⊗ (omega_BN_B, 0)
    J domega/dt   = -omega_BN_B × J omega_BN_B + torque_B

with ``J`` a general symmetric positive-definite inertia [kg m^2] and
``torque_B`` the total external torque in body axes [N m] (control plus
disturbance).  The state of a batch of N runs is one (N, 7) array
``x = (q_BN (x, y, z, w), omega_BN_B)``; see :mod:`.attitude` for the
quaternion convention.

Integration: classical RK4 with the torque held constant over the step
(zero-order hold, as a sampled actuator applies it), followed by a projection
of ``q_BN`` back onto the unit sphere.  The projection changes ``q`` by
the RK4 truncation error only (``O(dt^5)`` per step).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.attitude import Linear3, cross, dot, matvec, quat_normalize
from gnc_common.validation import InputError, check_spd_inertia

__all__ = ["RigidBody", "STATE_SIZE", "initial_state", "kinetic_energy_J"]

Array = NDArray[np.float64]

#: Length of the state vector: quaternion (4) and body rate (3).
STATE_SIZE = 7


class RigidBody:
    """Torque-driven rigid body with inertia ``J``.

    Parameters
    ----------
    inertia_kg_m2 : array_like, shape (3, 3) or (N, 3, 3)
        Symmetric positive-definite inertia, shared by the batch or one per run.

    Raises
    ------
    ConfigError
        If ``J`` is not symmetric positive definite.
    """

    def __init__(self, inertia_kg_m2: ArrayLike) -> None:
        self.J: Array = check_spd_inertia("inertia_kg_m2", inertia_kg_m2)
        self.J_inv: Array = np.asarray(np.linalg.inv(self.J), dtype=np.float64)
        self._J = Linear3(self.J)
        self._J_inv = Linear3(self.J_inv)

    def derivative(self, x: Array, torque_B: Array) -> Array:
        """State derivative ``dx/dt`` for states (N, 7) and torques (N, 3)."""
        return self._derivative(x, self._J_inv(torque_B))

    def _derivative(self, x: Array, accel_ext: Array) -> Array:
        """``dx/dt`` given the external angular acceleration ``J^-1 torque`` (constant over a step)."""
        q = x[:, :4]
        w = x[:, 4:]
        qv = q[:, :3]
        out = np.empty_like(x)
        out[:, :3] = 0.5 * (q[:, 3:] * w + cross(qv, w))
        out[:, 3] = -0.5 * dot(qv, w)
        out[:, 4:] = accel_ext - self._J_inv(cross(w, self._J(w)))
        return out

    def rk4_step(self, x: Array, torque_B: Array, dt: float) -> Array:
        """One RK4 step of length ``dt`` [s] with ``torque_B`` held constant; ``q`` renormalised."""
        a = self._J_inv(torque_B)
        h2 = 0.5 * dt
        k1 = self._derivative(x, a)
        k2 = self._derivative(x + h2 * k1, a)
        k3 = self._derivative(x + h2 * k2, a)
        k4 = self._derivative(x + dt * k3, a)
        x_new = x + (dt / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        x_new[:, :4] = quat_normalize(x_new[:, :4])
        return x_new

    def propagate(self, x: Array, torque_B: Array, dt: float, substeps: int = 1) -> Array:
        """Advance ``x`` by ``dt`` [s] in ``substeps`` RK4 steps with the torque held (ZOH).

        Raises
        ------
        InputError
            If ``dt`` is not finite and positive or ``substeps`` is not a positive integer.
        """
        if not (np.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be finite and > 0, got {dt!r}")
        if int(substeps) != substeps or substeps < 1:
            raise InputError(f"substeps must be a positive integer, got {substeps!r}")
        h = dt / substeps
        for _ in range(int(substeps)):
            x = self.rk4_step(x, torque_B, h)
        return x


def initial_state(q_BN: ArrayLike, omega_BN_B: ArrayLike) -> Array:
    """Stack quaternion(s) and rate(s) into the (N, 7) state array (Fortran order)."""
    q = np.atleast_2d(np.asarray(q_BN, dtype=np.float64))
    w = np.atleast_2d(np.asarray(omega_BN_B, dtype=np.float64))
    n = max(q.shape[0], w.shape[0])
    x = np.empty((n, STATE_SIZE), order="F")  # components contiguous over runs (see attitude.py)
    x[:, :4] = q
    x[:, 4:] = w
    return x


def kinetic_energy_J(J: Array, omega_BN_B: Array) -> Array:
    """Rotational kinetic energy ``omega^T J omega / 2`` [J], shape (N,)."""
    return 0.5 * dot(omega_BN_B, matvec(J, omega_BN_B))


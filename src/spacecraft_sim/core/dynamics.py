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

The model and the integrator are computed by the compiled kernels
(:func:`spacecraft_sim.core.kernels.propagate`, one implementation for the plant
node, the offline run and a campaign); :class:`RigidBody` checks the inertia once
and the step at each call, and loops over the runs of a batch in compiled code.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.attitude import dot, matvec
from gnc_common.compiled import inverse3_stack
from gnc_common.validation import InputError, check_spd_inertia
from spacecraft_sim.core import kernels

__all__ = ["RigidBody", "STATE_SIZE", "initial_state", "kinetic_energy_J", "pack_plant"]

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
        self.J_inv: Array = inverse3_stack(self.J)  # written out: the same bits on every host (docs/parity.md)
        # (NJ, 3, 3), C order, NJ = 1 (shared) or N: the kernels' layout, made once
        self._J3: Array = np.ascontiguousarray(self.J.reshape(-1, 3, 3), dtype=np.float64)
        self._J_inv3: Array = np.ascontiguousarray(self.J_inv.reshape(-1, 3, 3), dtype=np.float64)

    def _runs(self, x: ArrayLike, torque_B: ArrayLike) -> tuple[Array, Array, Array, int]:
        """``x`` (Nx, 7) and ``torque_B`` (Nu, 3) as C-contiguous float64 and a new (N, 7) output
        (the kernels' layout), and how to return it: 0 as (N, 7), 1 as one run (7,), 2 in Fortran
        order; raises :class:`InputError` on shapes that do not match."""
        xa = np.asarray(x, dtype=np.float64)
        u = np.asarray(torque_B, dtype=np.float64)
        x2 = xa.reshape(1, -1) if xa.ndim == 1 else xa
        u2 = u.reshape(1, -1) if u.ndim == 1 else u
        if x2.ndim != 2 or x2.shape[1] != STATE_SIZE or u2.ndim != 2 or u2.shape[1] != 3:
            raise InputError(f"expected states (7,) or (N, 7) and torques (3,) or (N, 3), got shapes {xa.shape} and {u.shape}")
        nx, nu, nj = x2.shape[0], u2.shape[0], self._J3.shape[0]
        n = max(nx, nu, nj)
        if (nx != n and nx != 1) or (nu != n and nu != 1) or (nj != n and nj != 1):
            raise InputError(f"batch sizes do not match: states {nx}, torques {nu}, inertias {nj}")
        form = 1 if (xa.ndim == 1 and n == 1) else (2 if (n > 1 and not xa.flags.c_contiguous and xa.flags.f_contiguous) else 0)
        return np.ascontiguousarray(x2), np.ascontiguousarray(u2), np.empty((n, STATE_SIZE)), form

    @staticmethod
    def _shaped(out: Array, form: int) -> Array:
        if form == 1:
            one: Array = out[0]
            return one
        return np.asfortranarray(out) if form == 2 else out  # a Fortran batch stays Fortran (see initial_state)

    def derivative(self, x: ArrayLike, torque_B: ArrayLike) -> Array:
        """State derivative ``dx/dt`` for states (N, 7) or (7,) and torques (N, 3) or (3,)
        (:func:`spacecraft_sim.core.kernels.derivative`)."""
        x2, u2, out, form = self._runs(x, torque_B)
        kernels.derivative_runs(x2, u2, self._J3, self._J_inv3, out)
        return self._shaped(out, form)

    def rk4_step(self, x: ArrayLike, torque_B: ArrayLike, dt: float) -> Array:
        """One RK4 step of length ``dt`` [s] with ``torque_B`` held constant; ``q`` renormalised
        (:meth:`propagate` with one substep)."""
        return self.propagate(x, torque_B, dt, 1)

    def propagate(self, x: ArrayLike, torque_B: ArrayLike, dt: float, substeps: int = 1) -> Array:
        """Advance ``x`` by ``dt`` [s] in ``substeps`` RK4 steps with the torque held (ZOH).

        ``x`` is one run (7,) or a batch (N, 7), ``torque_B`` (3,) or (N, 3) [N m]; a batch of
        one (states, torques or the inertia) is shared by the N runs.  Returns a new state array
        of ``x``'s shape and memory order (``x`` is not changed), computed by
        :func:`spacecraft_sim.core.kernels.propagate` for each run (a compiled loop over runs).

        Raises
        ------
        InputError
            If ``dt`` is not finite and positive, ``substeps`` is not a positive integer, or the
            shapes do not match.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be finite and > 0, got {dt!r}")
        if int(substeps) != substeps or substeps < 1:
            raise InputError(f"substeps must be a positive integer, got {substeps!r}")
        x2, u2, out, form = self._runs(x, torque_B)
        kernels.propagate_runs(x2, u2, float(dt), int(substeps), self._J3, self._J_inv3, out)
        return self._shaped(out, form)


    def propagate_into(self, x: Array, torque_B: Array, dt: float, substeps: int, out: Array) -> None:
        """:meth:`propagate` into ``out`` (N, 7), for a caller that steps its own arrays each sample
        (the plant node: no array made, no shape worked out per call): ``x`` (N or 1, 7) and
        ``torque_B`` (N or 1, 3) float64, ``out`` not aliasing ``x``, ``dt`` and ``substeps`` as
        :meth:`propagate` checks them (the caller checked them once).  The same kernel: the same bits."""
        kernels.propagate_runs(x, torque_B, dt, substeps, self._J3, self._J_inv3, out)


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


def pack_plant(x0: ArrayLike, inertia_kg_m2: ArrayLike, substeps: int) -> kernels.PlantArrays:
    """The rigid body of a batch for the whole-run loop: ``x0`` (N, 7 + W) the runs' initial states,
    ``inertia_kg_m2`` (3, 3) shared or (N, 3, 3) per run; ``J^-1`` by the closed-form inverse
    (:func:`gnc_common.compiled.inverse3_stack`: the same bits on every host, docs/parity.md)."""
    x = np.array(x0, dtype=np.float64, order="C", copy=True)
    J = np.array(np.broadcast_to(check_spd_inertia("inertia_kg_m2", inertia_kg_m2), (x.shape[0], 3, 3)), dtype=np.float64, order="C")
    return kernels.PlantArrays(x, J, inverse3_stack(J), int(substeps))

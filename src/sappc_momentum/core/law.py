"""Momentum management with magnetorquers: the cross-product law and the wheels' feed-forward
(issue 36), the chain of Basilisk's example ``scenarioMtbMomentumManagementSimple``.

Each sample, from the wheels' speeds ``Omega`` (W,) relative to the body (their tachometers), the
measured field ``B_B`` (3,) [T] (the magnetometer) and the attitude controller's body torque
``tau_c`` (3,) [N m]:

1. **Torque request** (Basilisk ``mtbMomentumManagementSimple``): the wheels' momentum in B,
   ``h_B = G_s (J_s Omega)``, fed back to a target ``h*_B`` (the module's target is zero):

       tau_req_B = -K_p (h_B - h*_B)                                   [N m]

2. **Body dipole** (Basilisk ``torque2Dipole``; the cross-product law, Markley & Crassidis
   eq. 7.59, Camillo & Markley 1980): the dipole whose torque ``m x B`` is the part of
   ``tau_req`` normal to ``B`` (a rod cannot torque about the field):

       m_B = (B_B x tau_req_B) / |B_B|^2        (zero when |B_B|^2 <= 1e-30, Basilisk's DB0_EPS)

3. **Rods' dipoles** (Basilisk ``dipoleMapping``): ``m = S m_B`` with the steering matrix ``S``
   (M, 3) (the rods' minimum-norm inverse ``G_t^+``), each rod saturated at ``m_max,j``.

4. **Feed-forward** (Basilisk ``mtbFeedforward``): the rods' torque on the body,
   ``tau_mtb = (G_t m) x B_B``, is taken from the wheels' command, so the wheels absorb it and the
   attitude sees the controller's torque only (dumping does not fight the controller):

       tau_w_B = tau_c - (G_t m) x B_B

   The wheels deliver ``tau_w`` (allocation ``u = -G_s^+ tau_w``), the rods ``tau_mtb``: the body
   receives ``tau_c``, and the wheels' momentum changes by ``-G_s^+ (tau_c - tau_mtb)`` a second,
   the rods' part driving ``h_B`` toward ``h*_B`` at the rate ``K_p`` (normal to ``B``).

Flight software: never imports the simulator; every kernel takes plain arrays and allocates
nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.validation import ConfigError

__all__ = ["B_NORM_SQ_MIN_T2", "MomentumArrays", "MomentumManagement", "dipole_mapping", "feedforward_torque_B", "momentum_management_step",
           "momentum_torque_request_B", "pack_momentum", "torque_to_dipole_B"]

Array = NDArray[np.float64]

#: The smallest ``|B|^2`` [T^2] the cross-product law divides by: Basilisk's ``DB0_EPS`` (1e-30),
#: below which ``torque2Dipole`` commands no dipole (a field of 1e-15 T is no field: the Earth's is
#: 2e-5 to 6e-5 T in low orbit).
B_NORM_SQ_MIN_T2 = 1e-30


@dataclass(frozen=True)
class MomentumManagement:
    """The law's settings (module docstring).

    Attributes
    ----------
    gain_per_s : float
        ``K_p`` [1/s] > 0: the rate at which the wheels' excess momentum is dumped (normal to B).
    target_momentum_B_Nms : 3 floats
        ``h*_B`` [N m s]: the wheels' momentum to hold (zero: Basilisk's target).
    """

    gain_per_s: float = 0.0
    target_momentum_B_Nms: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        k = self.gain_per_s
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not math.isfinite(k) or not k > 0:
            raise ConfigError(f"gain_per_s must be a finite number > 0, got {k!r}")
        h = self.target_momentum_B_Nms
        if (not isinstance(h, (tuple, list)) or len(h) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in h)):
            raise ConfigError(f"target_momentum_B_Nms must be 3 finite numbers, got {h!r}")
        object.__setattr__(self, "target_momentum_B_Nms", tuple(float(v) for v in h))


class MomentumArrays(NamedTuple):
    """The law's arrays for a batch of N runs (``pack_momentum``): ``prm`` (N, 4) ``K_p, h*_B``
    (K_p = 0 and no columns: no management, ``prm.shape[1] == 0``), ``Gs`` (N, 3, W) and ``Js``
    (N, W) the wheels as the flight software knows them, ``Gt`` (N, 3, M), ``steering`` (N, M, 3)
    and ``m_max`` (N, M) the rods."""

    prm: Array
    Gs: Array
    Js: Array
    Gt: Array
    steering: Array
    m_max: Array

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field."""
        return {"prm": 0, "Gs": 0, "Js": 0, "Gt": 0, "steering": 0, "m_max": 0}


def pack_momentum(config: MomentumManagement | None, n_runs: int, Gs: Array | None = None, Js: Array | None = None, Gt: Array | None = None,
                  steering: Array | None = None, m_max: Array | None = None) -> MomentumArrays:
    """The law's arrays, the same for every run: ``config`` (``None``: no management, empty arrays)
    with the wheels' axes ``Gs`` (3, W) and spin inertias ``Js`` (W,), the rods' axes ``Gt`` (3, M),
    their steering matrix (M, 3) and dipole limits ``m_max`` (M,)."""
    if config is None:
        return MomentumArrays(np.zeros((n_runs, 0)), np.zeros((n_runs, 3, 0)), np.zeros((n_runs, 0)), np.zeros((n_runs, 3, 0)),
                              np.zeros((n_runs, 0, 3)), np.zeros((n_runs, 0)))
    if Gs is None or Js is None or Gt is None or steering is None or m_max is None:
        raise ValueError("momentum management needs the wheels (Gs, Js) and the rods (Gt, steering, m_max)")
    prm = np.array([config.gain_per_s, *config.target_momentum_B_Nms], dtype=np.float64)

    def rep(a: Array) -> Array:
        return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), (n_runs, *np.shape(a))))

    return MomentumArrays(rep(prm), rep(Gs), rep(Js), rep(Gt), rep(steering), rep(m_max))


@jit
def momentum_torque_request_B(Gs, Js, Omega, kp, h_target_B, out):
    """``tau_req_B = -K_p (G_s (J_s Omega) - h*_B)`` (3,) into ``out``: Basilisk
    ``mtbMomentumManagementSimple`` (its ``vElementwiseMult``, ``mMultV`` summed wheel by wheel,
    ``v3Scale(-Kp)``), with the target subtracted (zero: the module's own)."""
    h0 = 0.0
    h1 = 0.0
    h2 = 0.0
    for i in range(Omega.shape[0]):
        hw = Omega[i] * Js[i]  # h_W,i = Omega_i J_s,i
        h0 += Gs[0, i] * hw
        h1 += Gs[1, i] * hw
        h2 += Gs[2, i] * hw
    out[0] = (h0 - h_target_B[0]) * -kp
    out[1] = (h1 - h_target_B[1]) * -kp
    out[2] = (h2 - h_target_B[2]) * -kp


@jit
def torque_to_dipole_B(B_B, tau_B, out):
    """``m_B = (B_B x tau_B) / |B_B|^2`` (3,) [A m^2] into ``out``, zero when ``|B_B|^2 <=``
    :data:`B_NORM_SQ_MIN_T2`: Basilisk ``torque2Dipole`` (``v3Cross``, then ``v3Scale(1 / |B|^2)``)."""
    b2 = (B_B[0] * B_B[0] + B_B[1] * B_B[1]) + B_B[2] * B_B[2]
    if b2 > B_NORM_SQ_MIN_T2:
        s = 1.0 / b2
        c0 = B_B[1] * tau_B[2] - B_B[2] * tau_B[1]
        c1 = B_B[2] * tau_B[0] - B_B[0] * tau_B[2]
        c2 = B_B[0] * tau_B[1] - B_B[1] * tau_B[0]
        out[0] = c0 * s
        out[1] = c1 * s
        out[2] = c2 * s
    else:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0


@jit
def dipole_mapping(steering, m_B, m_max, out):
    """The rods' dipoles ``out_j = sat(S_j . m_B, m_max,j)`` (M,): Basilisk ``dipoleMapping``
    (``mMultV`` of the steering matrix, then each rod clipped to ``[-m_max,j, m_max,j]``)."""
    for j in range(out.shape[0]):
        m = (steering[j, 0] * m_B[0] + steering[j, 1] * m_B[1]) + steering[j, 2] * m_B[2]
        if m > m_max[j]:
            m = m_max[j]
        if m < -m_max[j]:
            m = -m_max[j]
        out[j] = m


@jit
def feedforward_torque_B(Gt, m, B_B, tau_c_B, out):
    """``tau_w_B = tau_c_B - (G_t m) x B_B`` (3,) into ``out`` (``out`` may be ``tau_c_B``): Basilisk
    ``mtbFeedforward`` (``mMultV``, ``v3Cross``, ``v3Subtract``)."""
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for j in range(m.shape[0]):
        m0 += Gt[0, j] * m[j]
        m1 += Gt[1, j] * m[j]
        m2 += Gt[2, j] * m[j]
    t0 = m1 * B_B[2] - m2 * B_B[1]
    t1 = m2 * B_B[0] - m0 * B_B[2]
    t2 = m0 * B_B[1] - m1 * B_B[0]
    out[0] = tau_c_B[0] - t0
    out[1] = tau_c_B[1] - t1
    out[2] = tau_c_B[2] - t2


@jit
def momentum_management_step(prm, Gs, Js, Gt, steering, m_max, Omega, B_B, tau_c_B, m_out, tau_w_out, tmp):
    """One sample of the whole chain (module docstring, steps 1 to 4): the rods' dipole commands
    ``m_out`` (M,) and the wheels' body torque ``tau_w_out`` (3,) from the wheels' speeds ``Omega``
    (W,), the measured field ``B_B`` and the controller's torque ``tau_c_B``; ``prm`` =
    ``(K_p, h*_B)``; ``tmp`` (2, 3) scratch."""
    momentum_torque_request_B(Gs, Js, Omega, prm[0], prm[1:4], tmp[0])
    torque_to_dipole_B(B_B, tmp[0], tmp[1])
    dipole_mapping(steering, tmp[1], m_max, m_out)
    feedforward_torque_B(Gt, m_out, B_B, tau_c_B, tau_w_out)

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

5. **Gyroscopic feed-forward** (optional, ``gyroscopic_feedforward``; the ``[omega x](G_s h_s)``
   term of Basilisk ``mrpFeedback``, Schaub & Junkins eq. 8.121 (the RW control law)): the
   stored momentum ``G_s h_s``, ``h_s,i = J_s,i (g_i . omega + Omega_i)``, turning with the body
   puts ``-omega x G_s h_s`` on it, which a controller that models the rigid body alone (SAPPC)
   sees as a disturbance growing with the momentum; the wheels add it back:

       tau_w_B += omega_B x (G_s h_s)                   (omega_B: the controller's rate input)

   A momentum the rods cannot dump (the part along B) keeps this term large: what it costs in
   motor torque is ``|omega| |h|`` (docs/how-to/momentum.md).

6. **Attitude first** (with step 5; not in Basilisk's chain): the wheels' motors carry the
   controller's torque, the gyroscopic term and the rods' feed-forward; when their minimum-norm
   allocation (``u = -G_s^+ tau_w``, the plant's own, :mod:`spacecraft_sim.core.wheels`) would pass a
   motor's limit ``u_max``, the rods' dipoles (and with them their feed-forward) are scaled by the
   largest ``s`` in [0, 1] that keeps every motor within its limit (0 when the controller's and the
   gyroscopic torque alone pass it): dumping waits, the attitude does not.

**The predictive law** (``law: predictive``; :mod:`.predictive`): step 1's request is the
receding-horizon LQR's along the onboard models' predicted field instead of ``-K_p (h - h*)``
(before the first attitude is delivered, the cross-product law's); steps 2 to 6 are the same.

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
from gnc_common.ephemeris import N_ORBIT_PARAMS
from gnc_common.validation import ConfigError
from sappc_momentum.core.predictive import (LAW_CROSS_PRODUCT, LAW_PREDICTIVE, MP_LAW, N_MM_PARAMS, N_PLAN_WORK, nominal_field_T,
                                            predictive_request_B)

__all__ = ["B_NORM_SQ_MIN_T2", "LAWS", "MAX_PLAN_STEPS", "N_MM_WORK", "MomentumArrays", "MomentumManagement", "dipole_mapping", "feedforward_torque_B", "momentum_management_step",
           "gyroscopic_torque_B", "momentum_torque_request_B", "pack_momentum", "torque_to_dipole_B"]

Array = NDArray[np.float64]

#: The smallest ``|B|^2`` [T^2] the cross-product law divides by: Basilisk's ``DB0_EPS`` (1e-30),
#: below which ``torque2Dipole`` commands no dipole (a field of 1e-15 T is no field: the Earth's is
#: 2e-5 to 6e-5 T in low orbit).
B_NORM_SQ_MIN_T2 = 1e-30
#: The laws (``law``): Basilisk's cross-product chain, and the field-predictive LQR (:mod:`.predictive`).
LAWS = {"cross_product": LAW_CROSS_PRODUCT, "predictive": LAW_PREDICTIVE}
#: The most RK4 steps a plan may take (``horizon_s / plan_step_s``): 10,000 steps are ~10 ms of
#: one core, once per ``replan_s``; a longer plan is a typo (a step in ms), refused.
MAX_PLAN_STEPS = 10000
#: Rows (3 wide) of the law's scratch ``tmp``: three of the chain's, then the plan's.
N_MM_WORK = 3 + N_PLAN_WORK


@dataclass(frozen=True)
class MomentumManagement:
    """The law's settings (module docstring).

    Attributes
    ----------
    gain_per_s : float
        ``K_p`` [1/s] > 0: the rate at which the wheels' excess momentum is dumped (normal to B).
    target_momentum_B_Nms : 3 floats
        ``h*_B`` [N m s]: the wheels' momentum to hold (zero: Basilisk's target).
    gyroscopic_feedforward : bool
        Steps 5 and 6 of the module docstring: the gyroscopic feed-forward and the attitude-first
        budget (default off: Basilisk's chain has neither).
    law : str
        ``cross_product`` (default: Basilisk's ``mtbMomentumManagementSimple`` request) or
        ``predictive`` (:mod:`.predictive`: the LQR along the predicted field, whose weight makes
        ``gain_per_s`` its decay rate normal to the field for a constant field of the orbit's
        mean strength).
    horizon_s, replan_s, plan_step_s : float
        The predictive law's horizon, how often it plans again and its plan's RK4 step [s]
        (``0 < plan_step_s <= replan_s <= horizon_s``, at most :data:`MAX_PLAN_STEPS` steps).
        Defaults: 3000 s (about half a low orbit: the field's direction turns by a full turn,
        so every direction the momentum may need is reachable within it), 60 s, 10 s (the
        field's direction turns by 0.02 rad a step; the plan is within 3.4e-7 of the exact
        solution there, tested to 1e-6).
    disturbance_time_constant_s : float
        The predictive law's low pass on the controller's torque, the disturbance's estimate [s]
        (default 200 s: the tracking torque, of 40 to 50 s periods, attenuated 25 to 30 times,
        the paper's periodic parts, of 628 s, about twice; the constant part settles in a few
        minutes).
    """

    gain_per_s: float = 0.0
    target_momentum_B_Nms: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyroscopic_feedforward: bool = False
    law: str = "cross_product"
    horizon_s: float = 3000.0
    replan_s: float = 60.0
    plan_step_s: float = 10.0
    disturbance_time_constant_s: float = 200.0

    def __post_init__(self) -> None:
        k = self.gain_per_s
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not math.isfinite(k) or not k > 0:
            raise ConfigError(f"gain_per_s must be a finite number > 0, got {k!r}")
        h = self.target_momentum_B_Nms
        if (not isinstance(h, (tuple, list)) or len(h) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in h)):
            raise ConfigError(f"target_momentum_B_Nms must be 3 finite numbers, got {h!r}")
        object.__setattr__(self, "target_momentum_B_Nms", tuple(float(v) for v in h))
        if not isinstance(self.gyroscopic_feedforward, bool):
            raise ConfigError(f"gyroscopic_feedforward must be true or false, got {self.gyroscopic_feedforward!r}")
        if self.law not in LAWS:
            raise ConfigError(f"law must be one of {', '.join(LAWS)}, got {self.law!r}")
        for name in ("horizon_s", "replan_s", "plan_step_s", "disturbance_time_constant_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not v > 0:
                raise ConfigError(f"{name} must be a finite number > 0 [s], got {v!r}")
            object.__setattr__(self, name, float(v))
        if not self.plan_step_s <= self.replan_s <= self.horizon_s:
            raise ConfigError(f"the predictive law needs plan_step_s <= replan_s <= horizon_s, got {self.plan_step_s!r}, "
                              f"{self.replan_s!r}, {self.horizon_s!r}")
        if self.horizon_s / self.plan_step_s > MAX_PLAN_STEPS:
            raise ConfigError(f"horizon_s / plan_step_s must be at most {MAX_PLAN_STEPS} steps, got {self.horizon_s!r} / "
                              f"{self.plan_step_s!r}")


class MomentumArrays(NamedTuple):
    """The law's arrays for a batch of N runs (``pack_momentum``): ``prm`` (N, 11) ``K_p, h*_B``, 1 or 0
    (the gyroscopic feed-forward and the attitude-first budget on or off), then the predictive
    law's columns (:data:`.predictive.MP_LAW` on; 0 for the cross-product law), ``Gs_pinv`` (N, W, 3) and
    ``u_max`` (N, W) the wheels' allocation and motor limits,
    (no columns: no management, ``prm.shape[1] == 0``), ``Gs`` (N, 3, W) and ``Js``
    (N, W) the wheels as the flight software knows them, ``Gt`` (N, 3, M), ``steering`` (N, M, 3)
    and ``m_max`` (N, M) the rods, ``orbit`` (N, 10) and ``field`` (N, 4) the onboard models the
    predictive law plans with (:mod:`gnc_common.ephemeris`; zeros for the cross-product law)."""

    prm: Array
    Gs: Array
    Js: Array
    Gs_pinv: Array
    u_max: Array
    Gt: Array
    steering: Array
    m_max: Array
    orbit: Array
    field: Array

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field."""
        return {"prm": 0, "Gs": 0, "Js": 0, "Gs_pinv": 0, "u_max": 0, "Gt": 0, "steering": 0, "m_max": 0, "orbit": 0, "field": 0}


def pack_momentum(config: MomentumManagement | None, n_runs: int, Gs: Array | None = None, Js: Array | None = None,
                  Gs_pinv: Array | None = None, u_max: Array | None = None, Gt: Array | None = None, steering: Array | None = None,
                  m_max: Array | None = None, orbit: Array | None = None, field: Array | None = None) -> MomentumArrays:
    """The law's arrays, the same for every run: ``config`` (``None``: no management, empty arrays)
    with the wheels' axes ``Gs`` (3, W), spin inertias ``Js`` (W,), allocation ``Gs_pinv`` (W, 3) and
    motor limits ``u_max`` (W,), the rods' axes ``Gt`` (3, M), their steering matrix (M, 3) and
    dipole limits ``m_max`` (M,), and for the predictive law the onboard orbit's and field's
    parameters ``orbit`` (10,) or one row per run (N, 10) (a campaign's dispersed orbits) and
    ``field`` (4,) (:meth:`spacecraft_sim.core.orbit.Orbit.params`,
    :meth:`spacecraft_sim.core.magnetic_field.DipoleField.params`: the plant's, the flight
    software's onboard models); each run's weight from its own orbit."""
    if config is None:
        return MomentumArrays(np.zeros((n_runs, 0)), np.zeros((n_runs, 3, 0)), np.zeros((n_runs, 0)), np.zeros((n_runs, 0, 3)),
                              np.zeros((n_runs, 0)), np.zeros((n_runs, 3, 0)), np.zeros((n_runs, 0, 3)), np.zeros((n_runs, 0)),
                              np.zeros((n_runs, 0)), np.zeros((n_runs, 0)))
    if Gs is None or Js is None or Gs_pinv is None or u_max is None or Gt is None or steering is None or m_max is None:
        raise ValueError("momentum management needs the wheels (Gs, Js, Gs_pinv, u_max) and the rods (Gt, steering, m_max)")
    prm = np.zeros((n_runs, N_MM_PARAMS))
    prm[:, :5] = [config.gain_per_s, *config.target_momentum_B_Nms, float(config.gyroscopic_feedforward)]
    orbit_prm, field_prm = np.zeros((n_runs, N_ORBIT_PARAMS)), np.zeros((n_runs, 4))
    if config.law == "predictive":
        if orbit is None or field is None:
            raise ValueError("the predictive law needs the onboard orbit and field (orbit, field)")
        orbit_prm = np.array(np.broadcast_to(np.asarray(orbit, dtype=np.float64), (n_runs, N_ORBIT_PARAMS)))
        field_prm = np.array(np.broadcast_to(np.asarray(field, dtype=np.float64), (n_runs, 4)))
        for k in range(n_runs):  # r = (B_nom / K_p)^2 (.predictive, "The weight"), each run's orbit its own
            b_nom = nominal_field_T(orbit_prm[k], field_prm[k])
            prm[k, MP_LAW:] = [LAWS[config.law], (config.gain_per_s / b_nom) ** 2, config.horizon_s, config.replan_s, config.plan_step_s,
                               config.disturbance_time_constant_s]

    def rep(a: Array) -> Array:  # a writable C-contiguous copy per run: one argument type for every call (no recompiles)
        return np.array(np.broadcast_to(np.asarray(a, dtype=np.float64), (n_runs, *np.shape(a))), dtype=np.float64, order="C", copy=True)

    return MomentumArrays(np.ascontiguousarray(prm), rep(Gs), rep(Js), rep(Gs_pinv), rep(u_max), rep(Gt), rep(steering), rep(m_max),
                          np.ascontiguousarray(orbit_prm), np.ascontiguousarray(field_prm))


@jit
def momentum_torque_request_B(Gs, Js, Omega, kp, h_target_B, out):
    """``tau_req_B = -K_p (G_s (J_s Omega) - h*_B)`` (3,) into ``out``: Basilisk
    ``mtbMomentumManagementSimple`` (its ``vElementwiseMult``, ``mMultV`` summed wheel by wheel,
    ``v3Scale(-Kp)``), with the target subtracted (zero: the module's own)."""
    excess_momentum_B(Gs, Js, Omega, h_target_B, out)
    out[0] = out[0] * -kp
    out[1] = out[1] * -kp
    out[2] = out[2] * -kp


@jit
def excess_momentum_B(Gs, Js, Omega, h_target_B, out):
    """``G_s (J_s Omega) - h*_B`` (3,) [N m s] into ``out``: the wheels' momentum in B relative to
    its target (Basilisk's ``vElementwiseMult`` and ``mMultV``, summed wheel by wheel)."""
    h0 = 0.0
    h1 = 0.0
    h2 = 0.0
    for i in range(Omega.shape[0]):
        hw = Omega[i] * Js[i]  # h_W,i = Omega_i J_s,i
        h0 += Gs[0, i] * hw
        h1 += Gs[1, i] * hw
        h2 += Gs[2, i] * hw
    out[0] = h0 - h_target_B[0]
    out[1] = h1 - h_target_B[1]
    out[2] = h2 - h_target_B[2]


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
def gyroscopic_torque_B(Gs, Js, Omega, omega_B, out):
    """``omega_B x (G_s h_s)`` (3,) [N m] into ``out``, ``h_s,i = J_s,i (g_i . omega_B + Omega_i)``
    (module docstring, step 5; Basilisk ``mrpFeedback``'s ``v3Cross(omega_BN_B, GsHs)``)."""
    w0, w1, w2 = omega_B[0], omega_B[1], omega_B[2]
    h0 = 0.0
    h1 = 0.0
    h2 = 0.0
    for i in range(Omega.shape[0]):
        hs = Js[i] * (((Gs[0, i] * w0 + Gs[1, i] * w1) + Gs[2, i] * w2) + Omega[i])
        h0 += Gs[0, i] * hs
        h1 += Gs[1, i] * hs
        h2 += Gs[2, i] * hs
    out[0] = w1 * h2 - w2 * h1
    out[1] = w2 * h0 - w0 * h2
    out[2] = w0 * h1 - w1 * h0


@jit
def dumping_scale(Gs_pinv, u_max, tau_base_B, tau_mtb_B):
    """The largest ``s`` in [0, 1] with ``|u_i| <= u_max,i`` for ``u = -G_s^+ (tau_base - s tau_mtb)``
    (module docstring, step 6); 0 when ``tau_base`` alone passes a limit."""
    s = 1.0
    for i in range(u_max.shape[0]):
        a = -((Gs_pinv[i, 0] * tau_base_B[0] + Gs_pinv[i, 1] * tau_base_B[1]) + Gs_pinv[i, 2] * tau_base_B[2])
        b = (Gs_pinv[i, 0] * tau_mtb_B[0] + Gs_pinv[i, 1] * tau_mtb_B[1]) + Gs_pinv[i, 2] * tau_mtb_B[2]
        if abs(a) > u_max[i]:
            return 0.0
        if b > 0.0:
            s = min(s, (u_max[i] - a) / b)
        elif b < 0.0:
            s = min(s, (-u_max[i] - a) / b)
    return max(s, 0.0)


@jit
def momentum_management_step(prm, Gs, Js, Gs_pinv, u_max, Gt, steering, m_max, orbit, field, t, Omega, B_B, q_BN, omega_B, tau_c_B, m_out,
                             tau_w_out, tmp, mst):
    """One sample of the whole chain (module docstring, steps 1 to 6) at time ``t`` [s]: the rods'
    dipole commands ``m_out`` (M,) and the wheels' body torque ``tau_w_out`` (3,) from the wheels'
    speeds ``Omega`` (W,), the measured field ``B_B``, the attitude ``q_BN`` and body rate
    ``omega_B`` (the controller's inputs; the attitude NaN before the first) and the controller's
    torque ``tau_c_B``; ``prm`` (:class:`MomentumArrays`), the onboard models ``orbit`` and
    ``field`` and the state ``mst`` (:func:`.predictive.new_state`) for the predictive law;
    ``tmp`` (:data:`N_MM_WORK`, 3) scratch.  The cross-product law with steps 5 and 6 off:
    Basilisk's chain, ``tau_w = tau_c - (G_t m) x B``."""
    predicted = False
    if prm[MP_LAW] == LAW_PREDICTIVE:
        excess_momentum_B(Gs, Js, Omega, prm[1:4], tmp[1])
        predicted = predictive_request_B(prm, orbit, field, t, tmp[1], q_BN, tau_c_B, B_B, mst, tmp[3:], tmp[0])
    if not predicted:
        momentum_torque_request_B(Gs, Js, Omega, prm[0], prm[1:4], tmp[0])
    torque_to_dipole_B(B_B, tmp[0], tmp[1])
    dipole_mapping(steering, tmp[1], m_max, m_out)
    if prm[4] == 0.0:
        feedforward_torque_B(Gt, m_out, B_B, tau_c_B, tau_w_out)
        return
    gyroscopic_torque_B(Gs, Js, Omega, omega_B, tmp[2])
    for i in range(3):
        tmp[2, i] += tau_c_B[i]  # what the wheels must deliver: the controller's torque and the gyroscopic term
    zero = tmp[0]
    for i in range(3):
        zero[i] = 0.0
    feedforward_torque_B(Gt, m_out, B_B, zero, tmp[1])  # -(G_t m) x B: minus the rods' torque
    for i in range(3):
        tmp[1, i] = -tmp[1, i]
    s = dumping_scale(Gs_pinv, u_max, tmp[2], tmp[1])
    if s < 1.0:
        for j in range(m_out.shape[0]):
            m_out[j] = s * m_out[j]
        feedforward_torque_B(Gt, m_out, B_B, zero, tmp[1])
        for i in range(3):
            tmp[1, i] = -tmp[1, i]
    for i in range(3):
        tau_w_out[i] = tmp[2, i] - tmp[1, i]

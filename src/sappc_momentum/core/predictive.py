"""Field-predictive momentum management (issue 36): a receding-horizon linear-quadratic regulator of
the wheels' momentum along the field the orbit will meet.

Why
---
The cross-product law (:mod:`.law`, Basilisk's ``mtbMomentumManagementSimple``) removes the part of
the wheels' momentum normal to the field *now*.  The part along the field waits until the field
turns, and under a disturbance fixed in the body it grows meanwhile: the paper's 0.035 N m stores
up to 22 to 32 N m s along the field in a quarter of this orbit's field epochs, whose gyroscopic
load ``omega x h`` (0.3 to 0.5 N m at the paper's slew rates) the 0.2 N m motors cannot carry
(``docs/how-to/momentum.md``, measured).  A law that knows where the field will point can store
momentum *ahead* of the directions it will not reach: the same rods, half the peak momentum.

Model and law
-------------
In the inertial frame N the wheels' momentum ``h`` changes by the torques from outside (the rods'
torque reaches the wheels through the feed-forward, :mod:`.law` step 4; the body's own ``J omega``
is left out: 0.07 N m s here):

    dh/dt = D + m x B(t)          (D: the disturbance, m: the rods' dipole, B: the field; all in N)

a linear system with the input matrix ``-[B(t) x]``.  Over the horizon ``[t0, t0 + T]`` the law
minimises ``integral(h^T h + r m^T m) dt`` (``Q = I``, no terminal cost), with ``D`` held at its
estimate: the affine linear-quadratic regulator (Anderson & Moore, *Optimal Control: Linear
Quadratic Methods*, 1990, sec. 2.3 and 4.2; Bryson & Ho, *Applied Optimal Control*, 1975,
sec. 5.2), whose value ``h^T P h + 2 s^T h + c`` obeys, backward from ``P(t0 + T) = 0``,
``s(t0 + T) = 0``,

    -dP/dt = I - P M P,    -ds/dt = -P M s + P D,    M = (1/r) [B x][B x]^T = (|B|^2 I - B B^T) / r

and the optimal dipole and its torque are

    m = -(1/r) B x (P h + s),     m x B = -(|B|^2 / r) (P h + s) projected normal to B.

The law is the cross-product chain with this torque request in place of ``-K_p h``
(:func:`predictive_request_B`; steps 2 to 6 of :mod:`.law`: the dipole, the rods' saturation, the
wheels' feed-forward, the attitude-first budget).  ``P`` and ``s`` are planned at ``t0`` (RK4 on
``plan_step_s``, the field of the onboard models at each stage's time: :mod:`gnc_common.ephemeris`,
the orbit propagated, the dipole turned with the Earth) and held for ``replan_s``, then planned
again from the new state (receding horizon).

**The weight** ``r`` keeps the meaning of the cross-product law's gain: for a constant field of
magnitude ``B_nom`` the steady solution is ``P = sqrt(r) / B_nom`` on the plane normal to ``B``,
and the momentum there decays at ``B_nom / sqrt(r)``: the cross-product law's ``K_p`` when
``r = (B_nom / K_p)^2`` (tested).  ``B_nom`` is the mean ``|B|`` over one orbit of the onboard
models (:func:`nominal_field_T`).

**The disturbance** ``D_B`` is estimated from the attitude controller's torque: on a rigid body
that tracks a slow reference the controller's torque cancels the environment's to within
``J dω_d/dt`` (1e-3 N m on the paper's trajectory), so ``D_B`` is a first-order low pass of
``-tau_c`` with the time constant ``disturbance_time_constant_s`` (200 s: the tracking torque's
40 to 50 s periods attenuated 25 to 30 times, the paper's 628 s periodic parts about twice),
turned into N with the attitude at each plan.  Before the first
attitude is delivered the law is the cross-product law.

Arrays
------
``prm`` columns ``MP_*`` (in :class:`.law.MomentumArrays`' ``prm`` after the cross-product law's
five); the state ``mst`` (:data:`N_MM_STATE`,): ``P`` (9, row major), ``s`` (3), the estimate
``D_B`` (3), the next plan's time and the last sample's time (NaN before the first): :func:`new_state`.
The plan's scratch: :data:`N_PLAN_WORK` rows of 3.

Flight software: never imports the simulator (the onboard models are the ground layer's); every
kernel allocates nothing.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit, quat_rotate
from gnc_common.ephemeris import O_N, dipole_field_N, position_N, to_body_B

__all__ = ["LAW_CROSS_PRODUCT", "LAW_PREDICTIVE", "MP_HORIZON", "MP_INV_R", "MP_LAW", "MP_REPLAN", "MP_STEP", "MP_TAU_D", "MS_D", "MS_P",
           "MS_S", "MS_TLAST", "MS_TNEXT", "NOMINAL_FIELD_SAMPLES", "N_MM_PARAMS", "N_MM_STATE", "N_PLAN_WORK", "new_state",
           "nominal_field_T", "plan", "predictive_request_B"]

Array = NDArray[np.float64]

#: The law (``prm[MP_LAW]``): Basilisk's cross-product chain, or this module's.
LAW_CROSS_PRODUCT, LAW_PREDICTIVE = 0.0, 1.0
#: Parameter columns after the cross-product law's ``K_p, h*_B (3), gyroscopic feed-forward``: the
#: law, ``1 / r`` [(A m^2)^2 / (N m s)^2] (the cost weighs ``h^T h`` [(N m s)^2] against
#: ``r m^T m``), the horizon, the replanning period and the plan's step [s], and the disturbance
#: estimate's time constant [s].
MP_LAW, MP_INV_R, MP_HORIZON, MP_REPLAN, MP_STEP, MP_TAU_D = 5, 6, 7, 8, 9, 10
N_MM_PARAMS = 11
#: State columns: ``P`` (9), ``s`` (3), ``D_B`` (3), the next plan's time, the last sample's time.
MS_P, MS_S, MS_D, MS_TNEXT, MS_TLAST = 0, 9, 12, 15, 16
N_MM_STATE = 17
#: The plan's scratch rows (3 wide): the field at a stage's start, middle and end, a position, the
#: disturbance in N, the momentum in N, ``P M`` (3 rows), four stages of ``dP`` (12 rows) and of
#: ``ds`` (4 rows), a stage's ``P`` (3 rows) and ``s``.
N_PLAN_WORK = 29
_B0, _BM, _B1, _R, _DN, _HN, _PM, _KP, _KS, _PT, _ST = 0, 1, 2, 3, 4, 5, 6, 9, 21, 25, 28
#: Samples of one orbit for :func:`nominal_field_T` (every 1/360 of the period).
NOMINAL_FIELD_SAMPLES = 360


def new_state() -> Array:
    """A fresh state: no plan yet (the next at once), no disturbance estimate, no sample seen."""
    st = np.zeros(N_MM_STATE)
    st[MS_TNEXT] = -np.inf
    st[MS_TLAST] = np.nan
    return st


def nominal_field_T(orbit: Array, field: Array) -> float:
    """``B_nom`` [T]: the mean ``|B|`` of the onboard models over one orbit from ``t = 0``
    (:data:`NOMINAL_FIELD_SAMPLES` samples), the field the weight ``r`` is scaled to."""
    period = 2.0 * math.pi / float(orbit[O_N])
    r, B = np.zeros(3), np.zeros(3)
    total = 0.0
    for j in range(NOMINAL_FIELD_SAMPLES):
        t = period * j / NOMINAL_FIELD_SAMPLES
        position_N(orbit, t, r)
        dipole_field_N(orbit, field, t, r, B)
        total += math.sqrt(float(B @ B))
    return total / NOMINAL_FIELD_SAMPLES


@jit
def _field_at(orbit, field, t, work, row):
    position_N(orbit, t, work[_R])
    dipole_field_N(orbit, field, t, work[_R], work[row])


@jit
def _stage(P, s, B, D, inv_r, PM, dP, ds):
    """``dP`` (3, 3) and ``ds`` (3,), the derivatives in backward time of the Riccati pair at ``P``,
    ``s`` with the field ``B``: ``I - P M P`` and ``P D - P M s`` (module docstring)."""
    b2 = (B[0] * B[0] + B[1] * B[1]) + B[2] * B[2]
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += P[i, k] * (((b2 if k == j else 0.0) - B[k] * B[j]) * inv_r)
            PM[i, j] = acc
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += PM[i, k] * P[k, j]
            dP[i, j] = (1.0 if i == j else 0.0) - acc
        a = 0.0
        c = 0.0
        for k in range(3):
            a += PM[i, k] * s[k]
            c += P[i, k] * D[k]
        ds[i] = c - a


@jit
def plan(orbit, field, t0, horizon_s, step_s, inv_r, D_N, P, s, work):
    """``P`` (3, 3) and ``s`` (3,) at ``t0`` [s]: the Riccati pair (module docstring) integrated
    backward from ``t0 + n h`` (``P = 0``, ``s = 0``; ``n = round(horizon_s / step_s)``,
    ``h = step_s``) by the classical Runge-Kutta method, the field of the onboard models
    ``orbit``, ``field`` at each stage's time, ``D_N`` held; ``P`` symmetrised after each step;
    ``work`` (:data:`N_PLAN_WORK`, 3) scratch."""
    n = int(horizon_s / step_s + 0.5)
    h = step_s
    for i in range(3):
        s[i] = 0.0
        for j in range(3):
            P[i, j] = 0.0
    PM = work[_PM:_PM + 3]
    Pt = work[_PT:_PT + 3]
    st = work[_ST]
    _field_at(orbit, field, t0 + n * h, work, _B0)
    for step in range(n):
        t_end = t0 + (n - step) * h  # this step runs from t_end back to t_end - h
        _field_at(orbit, field, t_end - 0.5 * h, work, _BM)
        _field_at(orbit, field, t_end - h, work, _B1)
        for q in range(4):
            dP = work[_KP + 3 * q:_KP + 3 * q + 3]
            ds = work[_KS + q]
            if q == 0:
                _stage(P, s, work[_B0], D_N, inv_r, PM, dP, ds)
            else:
                a = h if q == 3 else 0.5 * h  # the stage's point: half a step, half a step, a whole step
                prev, prev_s = work[_KP + 3 * (q - 1):_KP + 3 * q], work[_KS + q - 1]
                for i in range(3):
                    st[i] = s[i] + a * prev_s[i]
                    for j in range(3):
                        Pt[i, j] = P[i, j] + a * prev[i, j]
                _stage(Pt, st, work[_B1] if q == 3 else work[_BM], D_N, inv_r, PM, dP, ds)
        for i in range(3):
            s[i] += h / 6.0 * (((work[_KS, i] + 2.0 * work[_KS + 1, i]) + 2.0 * work[_KS + 2, i]) + work[_KS + 3, i])
            for j in range(3):
                P[i, j] += h / 6.0 * (((work[_KP + i, j] + 2.0 * work[_KP + 3 + i, j]) + 2.0 * work[_KP + 6 + i, j]) + work[_KP + 9 + i, j])
        for i in range(3):
            for j in range(i + 1, 3):
                m = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = m
                P[j, i] = m
        for i in range(3):
            work[_B0, i] = work[_B1, i]


@jit
def predictive_request_B(prm, orbit, field, t, h_B, q_BN, tau_c_B, B_B, mst, work, out):
    """The torque request (3,) [N m] into ``out`` at time ``t`` [s] (module docstring): the
    disturbance estimate updated with the controller's torque ``tau_c_B``, a new plan when
    ``t`` reaches the next plan's time, then ``-(|B_B|^2 / r) [BN] (P [BN]^T h_B + s)`` with the
    wheels' momentum ``h_B`` relative to its target (B), the attitude ``q_BN`` and the measured
    field ``B_B``.  Returns False (nothing written) while ``q_BN`` is not finite: the caller
    uses the cross-product law (the disturbance estimate is updated either way)."""
    t_last = mst[MS_TLAST]
    a = (t - t_last) / prm[MP_TAU_D] if t_last == t_last else 0.0  # (NaN before the first sample)
    if a > 1.0:
        a = 1.0
    mst[MS_TLAST] = t
    for i in range(3):
        mst[MS_D + i] += a * (-tau_c_B[i] - mst[MS_D + i])
    if not (np.isfinite(q_BN[0]) and np.isfinite(q_BN[1]) and np.isfinite(q_BN[2]) and np.isfinite(q_BN[3])):
        return False
    P = mst[MS_P:MS_P + 9].reshape((3, 3))
    s = mst[MS_S:MS_S + 3]
    if t >= mst[MS_TNEXT]:
        quat_rotate(q_BN, mst[MS_D:MS_D + 3], work[_DN])
        plan(orbit, field, t, prm[MP_HORIZON], prm[MP_STEP], prm[MP_INV_R], work[_DN], P, s, work)
        mst[MS_TNEXT] = t + prm[MP_REPLAN]
    hN = work[_HN]
    quat_rotate(q_BN, h_B, hN)
    v0 = ((P[0, 0] * hN[0] + P[0, 1] * hN[1]) + P[0, 2] * hN[2]) + s[0]
    v1 = ((P[1, 0] * hN[0] + P[1, 1] * hN[1]) + P[1, 2] * hN[2]) + s[1]
    v2 = ((P[2, 0] * hN[0] + P[2, 1] * hN[1]) + P[2, 2] * hN[2]) + s[2]
    hN[0], hN[1], hN[2] = v0, v1, v2
    to_body_B(q_BN, hN, out)
    k = -prm[MP_INV_R] * ((B_B[0] * B_B[0] + B_B[1] * B_B[1]) + B_B[2] * B_B[2])
    for i in range(3):
        out[i] = k * out[i]
    return True

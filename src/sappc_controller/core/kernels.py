"""The four control laws, compiled: SAPPC, TraPPC, BLFPPC and MRP feedback as per-run numba kernels.

This module is **the** implementation of the laws (issue 13: one code path); every caller goes
through :func:`controller_step`:

* the controller node and ``sappc rerun``, one sample at a time, through
  :meth:`.base.AttitudeController.step` (inputs checked there, in Python, once; it calls
  :func:`controller_step_batch` for one run or a batch);
* the offline whole-run loop and Monte Carlo (:mod:`sappc.offline.compiled_loop`), inside compiled
  code, one run per loop iteration or in a ``prange`` over runs.

The config dataclasses, their validation and the run set-up that needs scipy (the RPF's
coefficients by Lambert W, :mod:`.rpf`) stay in Python; :func:`start_coef` turns them into arrays.
Equation numbers are the paper's; the paper's errors are cited as ``docs/paper_notes.md, error N``.
One call of :func:`controller_step` computes one run's torque for one sampling instant from small
float64 arrays the caller owns:

``prm`` (:data:`N_PARAMS`,)
    Gains, actuator limits, the known inertia ``J`` and the performance-function constants,
    laid out by the ``P_*`` indices below (:func:`pack_params` fills it from a config).
``coef`` (:data:`N_COEF`, 3)
    Per-run constants fixed at the run's first sample: the sign of each initial error and, for
    SAPPC, the RPF coefficients ``t1, a1, l, A = rho_e0 - rho_einf`` (computed once in Python
    with scipy's Lambert W by :class:`.rpf.ReferencePerformanceFunction`: :func:`start_coef`).
``state`` (:data:`N_STATE`,)
    What a run carries from sample to sample: the dynamic-surface filter output ``S_d``, the
    SMETF warm start (previous ``eps, P_s, z, d eps/d delta, delta``), the time origin ``t0``,
    MRP feedback's integral and the noise filters' outputs (issue 34).
    :func:`new_state` gives a fresh one.
``work`` (:data:`N_WORK`, 4)
    Scratch (no allocation per step); its first rows hold the error state after a step.
``out`` (:data:`N_OUT`, 4)
    Results, rows ``O_*``: produced torque, commanded torque, saturation flags (1.0/0.0), the
    error quaternion, ``rho``, band lower/upper, ``eps``, ``z`` and ``V = (V1, V2, V3)``; the
    same quantities as :class:`.base.ControlOutput`.

Nothing inside is a Python object, and the kernels check nothing: the start checks (180 deg
singularity through :func:`.base.check_start`, funnel contains the initial error, RPF
feasibility) are made once, in Python, by :func:`start_coef`.

SMETF solver (eqs. Rs, solve, chosenfunction, P0PS, PS)
--------------------------------------------------------
With the paper's base transformation (eq. chosenfunction, ``a = delta``, ``b = 1``)
``R(z0) = tan(pi (z0 - 1) / (2 delta))`` on ``z0 in (1 - delta, 1 + delta)``, the SMETF value
``eps = R_s(z_s)`` is defined implicitly by ``z0 + tan(theta) R(z0) = z_s``, ``eps = R(z0)``
(eqs. Rs, solve).  With ``a = 2 delta / pi``, ``k = tan(theta)``, ``w = z_s - 1`` and
``z0 - 1 = a arctan(eps)`` this is, in ``eps``, ``h(eps) = a arctan(eps) + k eps = w``.  ``h`` is
odd, strictly increasing with ``k <= h' <= a + k`` and concave on ``eps >= 0``, so the root is
unique for every finite ``z_s`` and every ``delta > 0`` (the transformation is global, the point of
the paper).  :func:`smetf_solve` works on ``|w|`` and restores the sign.  Cold, it starts from
``lower = max(|w| / (a + k), (|w| - a pi / 2) / k)``, a lower bound of the root (``arctan x <= x``,
``arctan x < pi / 2``), from which Newton's iterates increase monotonically to the root (the
tangent of a concave increasing function lies above it).  Warm (the controller passes a
first-order prediction from the previous sample) it starts from ``max(guess, lower)``: from above
the root one Newton step lands at or below it, and every iterate is raised to ``lower``, so the
same argument applies after the first step.  It stops when ``|h(eps) - |w||`` is within
:data:`_RESIDUAL_ULPS` ulps of the terms' magnitude; cold, over ``|w|`` in [1e-16, 1e12] and
``delta`` in [1e-8, 1e10], that takes at most 12 iterations, warm 1 to 3
(``tests/controller/test_smetf.py``); :data:`_MAX_NEWTON_ITERATIONS` only bounds pathological
inputs.  Derivatives (:func:`smetf_derivatives`): ``P_s = d eps / d z_s = P_0 / (1 + k P_0)``,
``P_0 = (1 + eps^2) / a`` (eqs. P0i, P0PS, PS), evaluated as ``1 / (k + a / (1 + eps^2))``, which
cannot overflow; ``d eps / d delta = -(2/pi) arctan(eps) P_s = -((z0 - 1) / delta) P_s`` by
implicit differentiation (docs/paper_notes.md, error 3: the paper's ``d eps_0 / d delta`` misses
the denominator ``1 + k R_z``); ``eps d eps/d delta <= 0``, the sign claim of eq. (SupControl).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common import libm
from gnc_common.compiled import dcm_BR_times_of, dot3, error_quaternion, error_quaternion_of, gamma_inverse_of, gamma_inverse_times, jit, matvec3_flat
from gnc_common.compiled import matvec3_flat_of

__all__ = [
    "ControllerArrays",
    "BARRIER_MARGIN",
    "DOMAIN_MARGIN",
    "KIND_BLFPPC",
    "KIND_MRP_FEEDBACK",
    "KIND_SAPPC",
    "KIND_TRAPPC",
    "N_COEF",
    "N_OUT",
    "N_PARAMS",
    "N_STATE",
    "N_WORK",
    "controller_step",
    "controller_step_batch",
    "controller_step_one",
    "mrp_feedback_step",
    "new_state",
]

#: Controller kinds (the ``kind`` argument of :func:`controller_step`).
KIND_SAPPC, KIND_TRAPPC, KIND_BLFPPC, KIND_MRP_FEEDBACK = 0, 1, 2, 3
#: TraPPC: distance in z kept from the transformation's asymptotes (module :mod:`.trappc`):
#: ln(1/1e-9) = 20.7 bounds |eps|, a finite "at the wall" value.
DOMAIN_MARGIN = 1e-9
#: BLFPPC: smallest |1 - eps^2| used in D_rho (module :mod:`.blfppc`): on the boundary the barrier
#: term is then 1e9 / (rho_u - rho_l) times its gain, saturating the actuator.
BARRIER_MARGIN = 1e-9

# --- prm layout -------------------------------------------------------------------------------
P_P, P_T1, P_T2, P_T3, P_VFLOOR, P_Q0FLOOR = 0, 1, 2, 3, 4, 5
#: SAPPC/TraPPC: K_q, K_omega; BLFPPC: K1, K2.
P_KQ, P_KW = 6, 7
P_K1, P_K2 = 6, 7
P_DM, P_MU = 8, 9
#: SAPPC: B0; BLFPPC: K3.
P_B0 = 10
P_K3 = 10
#: SAPPC: tan(theta); TraPPC: K.
P_TANTH = 11
P_KFUN = 11
P_UMAX, P_UMIN = 12, 13
P_J = 14  # 9 entries, row major
#: SAPPC RPF: rho_einf, g_inf, t2.
P_RHO_EINF, P_GINF, P_RPF_T2 = 23, 24, 25
#: TraPPC exponential PF: rho_0, rho_inf, l.
P_PF_RHO0, P_PF_RHOINF, P_PF_L = 23, 24, 25
#: BLFPPC FTPPF: rho(0), rho_Tf, T_f, 1/m.
P_FT_RHO0, P_FT_RHOTF, P_FT_TF, P_FT_INVM = 23, 24, 25, 26
#: MRP feedback (Basilisk's mrpFeedback): K [N m], P [N m s], Ki [1/(kg m^2)], integralLimit [N m s].
P_MRP_K, P_MRP_P, P_MRP_KI, P_MRP_INT_LIMIT = 6, 7, 8, 9
#: Every law: the noise filters' cut-offs as angular frequencies ``2 pi f_c`` [rad/s], 0 = off
#: (:class:`.common.NoiseFilterConfig`): on the body rate, on the commanded torque.
P_RATE_WC, P_TORQUE_WC = 27, 28
N_PARAMS = 29

# --- coef rows --------------------------------------------------------------------------------
C_SIGN, C_T1, C_A1, C_L, C_A = 0, 1, 2, 3, 4
N_COEF = 5

# --- state layout -----------------------------------------------------------------------------
S_SD = 0  # 3: filter output S_d
S_FILTER_ON = 3  # 0.0 until the filter has its first input
S_PREV = 4  # 15: previous eps, P_s, z, d eps/d delta, delta (3 each)
S_HAS_PREV = 19
S_T0 = 20
S_INT_SIGMA = 21  # 3: MRP feedback's K * integral of sigma_BR dt [N m s] (mrpFeedback's int_sigma)
S_HAS_PRIOR_CALL = 24  # MRP feedback: 0.0 until its first call (mrpFeedback's priorTime == 0)
S_RATE_F = 25  # 3: the rate filter's output [rad/s]
S_RATE_F_ON = 28  # 0.0 until the rate filter has its first input
S_TORQUE_F = 29  # 3: the torque filter's output [N m]
S_TORQUE_F_ON = 32  # 0.0 until the torque filter has its first input
N_STATE = 33

# --- work rows --------------------------------------------------------------------------------
W_QBR, W_WBR, W_WBN, W_CWD, W_CWDD = 0, 1, 2, 3, 4  # error state (eq. errorsystem)
W_EPS, W_PSI, W_ETA, W_QEV = 5, 6, 7, 8
W_X, W_ALPHA, W_SD, W_SDDOT, W_Z2, W_JZ2 = 9, 10, 11, 12, 13, 14  # BLFPPC's (SAPPC and TraPPC keep these in registers)
N_WORK = 15

# --- out rows ---------------------------------------------------------------------------------
O_TORQUE, O_CMD, O_SAT, O_QBR, O_RHO, O_BL, O_BU, O_EPS, O_Z, O_V = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
N_OUT = 10

#: Iteration cap of the SMETF Newton solver; 12 iterations suffice over the tested range (module
#: docstring), the cap only bounds pathological inputs.
_MAX_NEWTON_ITERATIONS = 60
#: Stopping tolerance of the solver in units of the float64 epsilon times the magnitude of the
#: terms of ``h(eps) - |w|``: below this the residual is rounding noise.
_RESIDUAL_ULPS = 4.0
_TWO_OVER_PI = 2.0 / np.pi
_HALF_PI = np.pi / 2.0
_TOL = _RESIDUAL_ULPS * float(np.finfo(np.float64).eps)
_MAX_IT = _MAX_NEWTON_ITERATIONS


# ============================================================================= shared pieces


@jit(inline="always")
def predefined_time_gain(V, p, T, V_floor):
    """Predefined-time gain ``M = exp(V^p) V^(-p) / (2 p T)`` (eqs. M_q, M_omega, dSd) at ``max(V, V_floor)``.

    ``M`` grows without bound as ``V -> 0`` and is undefined at ``V = 0`` (docs/paper_notes.md,
    error 4).  ``M`` is decreasing on ``(0, 1)`` (its derivative is ``p exp(V^p) V^(-p-1) (V^p - 1)``),
    so evaluating it at ``max(V, V_floor)`` (``0 < V_floor <= 1``) caps the gain at ``M(V_floor)``
    and leaves it unchanged for ``V >= V_floor``.
    """
    Vp = libm.pow(max(V, V_floor), p)  # docs/paper_notes.md, error 4
    return libm.exp(Vp) / (Vp * (2.0 * p * T))  # eqs. M_q, M_omega, dSd


@jit(inline="always")
def error_state_of(q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R):
    """Error state of eq. (errorsystem): ``q_e = q_d^* ⊗ q_s`` (``q_e0 >= 0``, a 4-tuple),
    ``omega_e = omega_s - C_e omega_d``, ``C_e omega_d`` and ``C_e omegadot_d`` (3-tuples).  The
    inputs are arrays or tuples (the SIMD lanes' scalars, :mod:`sappc.offline.lanes`)."""
    x, y, z, q0 = error_quaternion_of(q_RN, q_BN)
    cwd = dcm_BR_times_of(x, y, z, q0, omega_RN_R[0], omega_RN_R[1], omega_RN_R[2])  # C_e omega_d
    cwdd = dcm_BR_times_of(x, y, z, q0, omegadot_RN_R[0], omegadot_RN_R[1], omegadot_RN_R[2])  # C_e omegadot_d
    wbr = (omega_BN_B[0] - cwd[0], omega_BN_B[1] - cwd[1], omega_BN_B[2] - cwd[2])  # omega_e = omega_s - C_e omega_d
    return (x, y, z, q0), wbr, cwd, cwdd


@jit(inline="always")
def error_state(q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, work):
    """:func:`error_state_of` into ``work`` rows ``W_QBR .. W_CWDD`` and ``omega_s`` into ``W_WBN``.
    (The laws' helpers pass vectors as scalars and write rows of ``work`` element by element: an
    array view of a row costs a reference count in the loop.)"""
    q, wbr, cwd, cwdd = error_state_of(q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R)
    for i in range(4):
        work[W_QBR, i] = q[i]
    for i in range(3):
        work[W_CWD, i] = cwd[i]
        work[W_CWDD, i] = cwdd[i]
    for i in range(3):
        work[W_WBN, i] = omega_BN_B[i]
        work[W_WBR, i] = wbr[i]


@jit(inline="always")
def filter_update(prm, state, dt, a0, a1, a2):
    """Dynamic-surface filter of the virtual control ``alpha = (a0, a1, a2)`` (eq. dSd), stable for
    any gain.

    Eq. (dSd) is ``dS_d/dt = -M3 H_d`` with ``H_d = S_d - alpha``, ``M3 = exp(V3^p) V3^(-p) / (2 p T3)``
    and ``V3 = |H_d|^2 / 2``.  Forward Euler is unstable once ``M3 dt > 2``, which happens as
    ``H_d -> 0`` (docs/paper_notes.md, error 4).  The update freezes ``M3`` and ``alpha`` over one
    step and integrates exactly, ``S_d[k+1] = alpha + exp(-M3 dt) (S_d[k] - alpha)``: a contraction
    for every ``M3 >= 0`` and ``dt > 0``.  The derivative fed to the law is the secant of that
    update, ``dS_d/dt = -(1 - exp(-M3 dt)) / dt H_d``, whose gain is bounded by ``1 / dt`` and tends
    to eq. (dSd) as ``dt -> 0``.  The filter starts at the first virtual control (``H_d(0) = 0``).
    Returns ``V3``, the output before the update ``S_d`` and its derivative (3-tuples)."""
    V3, S_d, S_d_dot, S_next = filter_update_of(prm, dt, state[S_FILTER_ON] != 0.0, (state[S_SD], state[S_SD + 1], state[S_SD + 2]), a0, a1, a2)
    for i in range(3):
        state[S_SD + i] = S_next[i]
    state[S_FILTER_ON] = 1.0
    return V3, S_d, S_d_dot


@jit(inline="always")
def filter_update_of(prm, dt, filter_on, S_d, a0, a1, a2):
    """:func:`filter_update` of the filter output ``S_d`` (a 3-tuple; the first virtual control when
    ``filter_on`` is false): returns ``V3``, ``S_d`` before the update, its derivative and ``S_d``
    after the update (3-tuples)."""
    s0 = S_d[0] if filter_on else a0
    s1 = S_d[1] if filter_on else a1
    s2 = S_d[2] if filter_on else a2
    h0 = s0 - a0  # H_d = S_d - alpha
    h1 = s1 - a1
    h2 = s2 - a2
    V3 = 0.5 * ((h0 * h0 + h1 * h1) + h2 * h2)
    M3 = predefined_time_gain(V3, prm[P_P], prm[P_T3], prm[P_VFLOOR])  # eq. (dSd)
    neg_rate = -(-libm.expm1(-M3 * dt) / dt)  # exact exponential update (docs/paper_notes.md, error 4)
    d0 = neg_rate * h0
    d1 = neg_rate * h1
    d2 = neg_rate * h2
    return V3, (s0, s1, s2), (d0, d1, d2), (s0 + dt * d0, s1 + dt * d1, s2 + dt * d2)


@jit(inline="always")
def w0_plus(prm, work):
    """:func:`w0_plus_of` of the error state in ``work``."""
    return w0_plus_of(prm, (work[W_WBR, 0], work[W_WBR, 1], work[W_WBR, 2]), (work[W_CWD, 0], work[W_CWD, 1], work[W_CWD, 2]),
                      (work[W_CWDD, 0], work[W_CWDD, 1], work[W_CWDD, 2]), (work[W_WBN, 0], work[W_WBN, 1], work[W_WBN, 2]))


@jit(inline="always")
def w0_plus_of(prm, wbr, cwd, cwdd, wbn):
    """``-W0``, ``W0 = J omega_e^x C_e omega_d - J C_e omegadot_d - omega_s^x J omega_s`` (after eq. U),
    a 3-tuple, from ``omega_e``, ``C_e omega_d``, ``C_e omegadot_d`` and ``omega_s`` (3-tuples)."""
    a0, a1, a2 = wbr[0], wbr[1], wbr[2]
    b0, b1, b2 = cwd[0], cwd[1], cwd[2]
    t0 = (a1 * b2 - a2 * b1) - cwdd[0]
    t1 = (a2 * b0 - a0 * b2) - cwdd[1]
    t2 = (a0 * b1 - a1 * b0) - cwdd[2]
    Jt = matvec3_flat_of(prm, P_J, t0, t1, t2)  # J (omega_e^x C_e omega_d - C_e omegadot_d)
    w0, w1, w2 = wbn[0], wbn[1], wbn[2]
    Jw = matvec3_flat_of(prm, P_J, w0, w1, w2)  # J omega_s
    c0 = w1 * Jw[2] - w2 * Jw[1]
    c1 = w2 * Jw[0] - w0 * Jw[2]
    c2 = w0 * Jw[1] - w1 * Jw[0]
    return -(Jt[0] - c0), -(Jt[1] - c1), -(Jt[2] - c2)


@jit(inline="always")
def low_pass_gain(wc, dt):
    """Gain ``1 - exp(-wc dt)`` of the first-order low-pass ``dy/dt = wc (x - y)`` sampled exactly
    over a step ``dt`` (its pole ``exp(-wc dt)``, matched; docs/design/noise.md): ``y[k] = y[k-1] +
    gain (x[k] - y[k-1])``, in (0, 1) for every ``wc > 0``, ``dt > 0``, so the filter is stable."""
    return -libm.expm1(-wc * dt)  # 1 - exp(-wc dt), exact near wc dt = 0


@jit(inline="always")
def rate_filter(prm, state, dt, work):
    """The rate filter (:class:`.common.NoiseFilterConfig`, ``rate_cutoff_hz``): the body rate in
    ``work[W_WBN]`` low-passed, ``omega_f[k] = omega_f[k-1] + g (omega[k] - omega_f[k-1])``
    (:func:`low_pass_gain`; the filter starts at its first input), and the law's rate error made
    from it, ``omega_e = omega_f - C_e omega_d`` (eq. errorsystem)."""
    if state[S_RATE_F_ON] == 0.0:
        for i in range(3):
            state[S_RATE_F + i] = work[W_WBN, i]
        state[S_RATE_F_ON] = 1.0
    g = low_pass_gain(prm[P_RATE_WC], dt)
    for i in range(3):
        w = state[S_RATE_F + i] + g * (work[W_WBN, i] - state[S_RATE_F + i])  # first-order low-pass, matched pole
        state[S_RATE_F + i] = w
        work[W_WBN, i] = w
        work[W_WBR, i] = w - work[W_CWD, i]  # omega_e = omega_s - C_e omega_d


@jit(inline="always")
def actuator(prm, state, dt, out):
    """Per-axis saturation at ``max`` and minimum-output deadband (``|u_i| < min`` gives 0),
    from ``out[O_CMD]`` into ``out[O_TORQUE]`` and ``out[O_SAT]`` (:class:`.common.ActuatorConfig`).

    With the torque filter on (``prm[P_TORQUE_WC] > 0``, :class:`.common.NoiseFilterConfig`) the
    saturated command is low-passed, ``u_f[k] = u_f[k-1] + g (sat(u[k]) - u_f[k-1])``
    (:func:`low_pass_gain`; started at its first input), before the deadband: the filter holds only
    what the actuator can deliver, so it never winds up.  ``O_SAT`` stays the law's command beyond
    ``max``; ``O_CMD`` stays the law's command."""
    umax, umin = prm[P_UMAX], prm[P_UMIN]
    wc = prm[P_TORQUE_WC]
    if wc > 0.0:
        g = low_pass_gain(wc, dt)
        first = state[S_TORQUE_F_ON] == 0.0
        state[S_TORQUE_F_ON] = 1.0
        for i in range(3):
            torque, sat, filtered = filtered_actuator_of(umax, umin, g, first, state[S_TORQUE_F + i], out[O_CMD, i])
            state[S_TORQUE_F + i] = filtered
            out[O_TORQUE, i] = torque
            out[O_SAT, i] = sat
    else:
        for i in range(3):
            torque, sat = actuator_of(umax, umin, out[O_CMD, i])
            out[O_TORQUE, i] = torque
            out[O_SAT, i] = sat


@jit(inline="always")
def filtered_actuator_of(umax, umin, g, first, prev, u):
    """One axis of :func:`actuator` with the torque filter (gain ``g``, :func:`low_pass_gain`):
    the torque the actuator produces of the command ``u``, the saturation flag (1.0/0.0) and the
    filter's new output, from its last output ``prev`` (ignored at its ``first`` input)."""
    clipped = min(max(u, -umax), umax)
    last = clipped if first else prev
    filtered = last + g * (clipped - last)  # first-order low-pass, matched pole
    return (0.0 if abs(filtered) < umin else filtered), (1.0 if abs(u) > umax else 0.0), filtered


@jit(inline="always")
def actuator_of(umax, umin, u):
    """One axis of :func:`actuator` without the torque filter: the torque the actuator produces of
    the command ``u`` (saturated at ``umax``, 0 below ``umin``) and the saturation flag (1.0/0.0)."""
    mag = abs(u)
    torque = min(max(u, -umax), umax)
    return (0.0 if mag < umin else torque), (1.0 if mag > umax else 0.0)


# ============================================================================= SAPPC pieces


@jit(inline="always")
def rpf_evaluate(prm, coef, tau, i):
    """RPF value and slope of component ``i`` at ``tau`` seconds into the run (eq. RPF, with the
    coefficients of docs/paper_notes.md, error 1, from :func:`rpf_coef`): exponential before ``t1``,
    parabola ``a1 (t - t2)^2 + g_inf`` up to ``t2``, ``g_inf`` after; times the sign of ``e(0)``."""
    return rpf_of(prm, tau, coef[C_SIGN, i], coef[C_T1, i], coef[C_A1, i], coef[C_L, i], coef[C_A, i])


@jit(inline="always")
def rpf_of(prm, tau, sign, t1, a1, l, A):
    """:func:`rpf_evaluate` of one component's coefficients ``sign, t1, a1, l, A`` (``coef``'s
    column: :func:`rpf_coef`)."""
    t = max(tau, 0.0)
    g_inf, t2 = prm[P_GINF], prm[P_RPF_T2]
    if t >= t2:
        return sign * g_inf, 0.0
    if t < t1:  # exponential part
        expo = A * libm.exp(-l * t)
        return sign * (expo + prm[P_RHO_EINF]), sign * (-l * expo)
    dt2 = t - t2  # parabola a1 (t - t2)^2 + g_inf
    return sign * (a1 * dt2 * dt2 + g_inf), sign * (2.0 * a1 * dt2)


@jit(inline="always")
def smetf_solve(z_s, delta, k, has_guess, guess):
    """Solve eq. (solve) ``(2 delta / pi) arctan(eps) + tan(theta) eps = z_s - 1`` for ``eps`` by
    monotone Newton from a lower bound, warm started at ``max(guess sign(w), lower)`` when
    ``has_guess`` (module docstring; any finite guess gives the same root to 4 ulps).

    Returns ``eps = R_s(z_s)``, ``z0 - 1 = a arctan(eps)`` (eqs. Rs, chosenfunction: the pre-image
    relative to the band centre, exact where ``1 + (z0 - 1)`` would round) and the number of
    Newton steps taken."""
    eps, lower, abs_w, a, w = smetf_start(z_s, delta, k, has_guess, guess)
    a_atan = 0.0
    steps = 0
    for _ in range(_MAX_IT):
        a_atan, done, eps_next = smetf_newton_step(eps, lower, abs_w, a, k)
        if done:
            break
        eps = eps_next
        steps += 1
    # a_atan belongs to the final eps (the loop exits right after computing it)
    return np.copysign(eps, w), np.copysign(a_atan, w), steps


@jit(inline="always")
def smetf_start(z_s, delta, k, has_guess, guess):
    """:func:`smetf_solve`'s start: the first iterate ``eps``, the lower bound, ``|w|``, ``a`` and ``w``."""
    a = _TWO_OVER_PI * delta
    w = z_s - 1.0
    abs_w = abs(w)
    lower = max(abs_w / (a + k), (abs_w - a * _HALF_PI) / k)  # arctan x <= x, arctan x < pi/2
    sgn = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else 0.0)
    eps = max(guess * sgn, lower) if has_guess else lower
    return eps, lower, abs_w, a, w


@jit(inline="always")
def smetf_newton_step(eps, lower, abs_w, a, k):
    """One iteration of :func:`smetf_solve` at ``eps``: ``a arctan(eps)``, whether ``eps`` solves
    eq. (solve) to the tolerance, and the next iterate (a Newton step raised to the lower bound:
    from above the root the step lands at or below it (concavity), from below the iterates increase
    monotonically to it)."""
    a_atan = a * libm.atan(eps)
    k_eps = k * eps
    resid = a_atan + k_eps - abs_w  # h(eps) - |w|, eq. (solve)
    done = not abs(resid) > _TOL * (a_atan + k_eps + abs_w)
    return a_atan, done, max(eps - resid / (a / (1.0 + eps * eps) + k), lower)


@jit(inline="always")
def smetf_derivatives(eps, z0_offset, delta, k):
    """Partial derivatives of ``eps_s(z_s, delta)`` at the solution ``(eps, z0 - 1)`` of
    :func:`smetf_solve`: ``P_s = d eps_s / d z_s`` (eqs. P0PS, PS) and
    ``d eps_s / d delta = -((z0 - 1) / delta) P_s`` (docs/paper_notes.md, error 3)."""
    P_s = 1.0 / (k + (_TWO_OVER_PI * delta) / (1.0 + eps * eps))  # eq. PS
    return P_s, -(z0_offset / delta) * P_s  # docs/paper_notes.md, error 3


@jit(inline="always")
def sappc_transform(prm, coef, state, tau, work, out):
    """RPF (eq. RPF) + time-varying constraint (eq. delta_i) + SMETF (eqs. Rs, solve, PS) per component:
    writes ``eps``, ``psi``, ``eta`` to ``work`` and ``rho``, the band, ``eps``, ``z`` to ``out``
    (eq. dEpsilon: ``eps_dot = psi (q_ev_dot + eta q_ev) + xi``)."""
    B0, k = prm[P_B0], prm[P_TANTH]
    has_prev = state[S_HAS_PREV] != 0.0
    for i in range(3):
        rho, rho_dot, delta, z, guess = sappc_axis_start(prm, tau, coef[C_SIGN, i], coef[C_T1, i], coef[C_A1, i], coef[C_L, i], coef[C_A, i],
                                                         work[W_QBR, i], has_prev, state[S_PREV + i], state[S_PREV + 3 + i],
                                                         state[S_PREV + 6 + i], state[S_PREV + 9 + i], state[S_PREV + 12 + i])
        eps, z0_offset, _ = smetf_solve(z, delta, k, has_prev, guess)  # eqs. Rs, solve, chosenfunction
        P_s, d_eps_d_delta, psi, eta = sappc_axis_end(k, eps, z0_offset, delta, rho, rho_dot)
        state[S_PREV + i] = eps
        state[S_PREV + 3 + i] = P_s
        state[S_PREV + 6 + i] = z
        state[S_PREV + 9 + i] = d_eps_d_delta
        state[S_PREV + 12 + i] = delta
        work[W_EPS, i] = eps
        work[W_PSI, i] = psi
        work[W_ETA, i] = eta
        out[O_RHO, i] = rho
        out[O_BL, i] = rho - B0
        out[O_BU, i] = rho + B0
        out[O_EPS, i] = eps
        out[O_Z, i] = z
    state[S_HAS_PREV] = 1.0


@jit(inline="always")
def sappc_axis_start(prm, tau, sign, t1, a1, l, A, q_ev, has_prev, prev_eps, prev_P_s, prev_z, prev_d_eps_d_delta, prev_delta):
    """One component of :func:`sappc_transform` up to the SMETF's solve: ``rho``, ``rho_dot``
    (eq. RPF, coefficients ``sign, t1, a1, l, A``), ``delta`` (eq. delta_i), ``z`` and the solve's
    warm start (a first-order prediction from the previous sample's ``eps, P_s, z, d eps/d delta,
    delta`` when ``has_prev``, else 0)."""
    rho, rho_dot = rpf_of(prm, tau, sign, t1, a1, l, A)  # eq. RPF
    delta = prm[P_B0] / abs(rho)  # eq. delta_i
    z = q_ev / rho  # z_qi = q_evi / rho_i
    guess = ((prev_eps + prev_P_s * (z - prev_z)) + prev_d_eps_d_delta * (delta - prev_delta)) if has_prev else 0.0
    return rho, rho_dot, delta, z, guess


@jit(inline="always")
def sappc_axis_end(k, eps, z0_offset, delta, rho, rho_dot):
    """One component of :func:`sappc_transform` after the solve: ``P_s``, ``d eps/d delta`` (eq. PS;
    docs/paper_notes.md, error 3), ``psi = P_s / rho`` and ``eta = -rho_dot / rho`` (eq. dEpsilon).
    ``xi_si = (d eps / d delta) delta_dot`` (eq. dEpsilon) enters no term of the law (eq.
    virtualcontrol), so ``delta_dot`` (eq. delta_i) is not computed."""
    P_s, d_eps_d_delta = smetf_derivatives(eps, z0_offset, delta, k)  # eq. PS; docs/paper_notes.md, error 3
    return P_s, d_eps_d_delta, P_s / rho, -rho_dot / rho  # psi_si = P_si / rho_i, eta_si = -rho_dot_i / rho_i


@jit
def trappc_transform(prm, coef, tau, work, out):
    """TraPPC's exponential PF + homeomorphic log transformation (Appendix B; module :mod:`.trappc`):
    ``eps = s f(s z)``, ``f(x) = ln((K + x) / (K (1 - x)))``, ``psi = f'(s z) / rho``, ``eta = -rho_dot / rho``."""
    K = prm[P_KFUN]
    decay = (prm[P_PF_RHO0] - prm[P_PF_RHOINF]) * np.exp(-prm[P_PF_L] * tau)
    rho = decay + prm[P_PF_RHOINF]  # rho(t) = (rho_0 - rho_inf) exp(-l t) + rho_inf
    rho_dot = -prm[P_PF_L] * decay
    eta = -rho_dot / rho  # eta = -rho_dot / rho
    for i in range(3):
        s = coef[C_SIGN, i]
        z = work[W_QBR, i] / rho
        x = min(max(s * z, -K + DOMAIN_MARGIN), 1.0 - DOMAIN_MARGIN)  # singularity guard (module trappc)
        eps = s * np.log((K + x) / (K * (1.0 - x)))  # homeomorphic transformation (Table, row by sign)
        d_eps_dz = 1.0 / (K + x) + 1.0 / (1.0 - x)
        work[W_EPS, i] = eps
        work[W_PSI, i] = d_eps_dz / rho
        work[W_ETA, i] = eta
        out[O_RHO, i] = s * rho
        out[O_BL, i] = -K * rho if s > 0.0 else -rho
        out[O_BU, i] = rho if s > 0.0 else K * rho
        out[O_EPS, i] = eps
        out[O_Z, i] = z


@jit(inline="always")
def backstepping_law(prm, state, dt, work, out):
    """The predefined-time backstepping law of Sec. IV.F, shared by SAPPC and TraPPC (Appendix B),
    from ``eps``, ``psi``, ``eta`` in ``work``; writes the commanded torque and ``V``.

    docs/paper_notes.md, observation 7: ``dV1/dt`` contains ``eps^T psi Gamma (z2 + H_d)``, which the
    paper's analysis drops and the published law does not cancel; this is the published law."""
    cmd, V, S_next = backstepping_of(prm, dt, (work[W_QBR, 0], work[W_QBR, 1], work[W_QBR, 2], work[W_QBR, 3]),
                                     (work[W_WBR, 0], work[W_WBR, 1], work[W_WBR, 2]), (work[W_CWD, 0], work[W_CWD, 1], work[W_CWD, 2]),
                                     (work[W_CWDD, 0], work[W_CWDD, 1], work[W_CWDD, 2]), (work[W_WBN, 0], work[W_WBN, 1], work[W_WBN, 2]),
                                     (work[W_EPS, 0], work[W_EPS, 1], work[W_EPS, 2]), (work[W_PSI, 0], work[W_PSI, 1], work[W_PSI, 2]),
                                     (work[W_ETA, 0], work[W_ETA, 1], work[W_ETA, 2]), state[S_FILTER_ON] != 0.0,
                                     (state[S_SD], state[S_SD + 1], state[S_SD + 2]))
    for i in range(3):
        state[S_SD + i] = S_next[i]
        out[O_CMD, i] = cmd[i]
        out[O_V, i] = V[i]
    state[S_FILTER_ON] = 1.0


@jit(inline="always")
def backstepping_of(prm, dt, q, wbr, cwd, cwdd, wbn, eps, psi, eta, filter_on, S_d):
    """:func:`backstepping_law` of the error state (``q_e`` a 4-tuple, ``omega_e``, ``C_e omega_d``,
    ``C_e omegadot_d``, ``omega_s``), the transformation's ``eps``, ``psi``, ``eta`` and the
    dynamic-surface filter's output ``S_d`` (started when ``filter_on``), each a 3-tuple: returns the
    commanded torque, ``V = (V1, V2, V3)`` and the filter's next output (3-tuples)."""
    e0, e1, e2 = eps[0], eps[1], eps[2]
    V1 = 0.5 * ((e0 * e0 + e1 * e1) + e2 * e2)  # V1 = z1^T z1 / 2, z1 = eps_q
    M_q = predefined_time_gain(V1, prm[P_P], prm[P_T1], prm[P_VFLOOR])
    neg_kq_mq = -(prm[P_KQ] * M_q)
    # eq. (virtualcontrol): alpha = Gamma^-1 [-psi^-1 M_q K_q eps - eta q_ev]
    x0 = neg_kq_mq * e0 / psi[0] - eta[0] * q[0]
    x1 = neg_kq_mq * e1 / psi[1] - eta[1] * q[1]
    x2 = neg_kq_mq * e2 / psi[2] - eta[2] * q[2]
    alpha = gamma_inverse_of(q[0], q[1], q[2], q[3], x0, x1, x2, prm[P_Q0FLOOR])  # q_e0 floored: docs/paper_notes.md, error 5
    V3, S_d, S_d_dot, S_next = filter_update_of(prm, dt, filter_on, S_d, alpha[0], alpha[1], alpha[2])  # eq. (dSd), exact exponential update
    z0 = wbr[0] - S_d[0]  # z2 = omega_e - S_d
    z1 = wbr[1] - S_d[1]
    z2 = wbr[2] - S_d[2]
    Jz2 = matvec3_flat_of(prm, P_J, z0, z1, z2)
    V2 = 0.5 * ((z0 * Jz2[0] + z1 * Jz2[1]) + z2 * Jz2[2])  # V2 = z2^T J z2 / 2
    M_w = predefined_time_gain(V2, prm[P_P], prm[P_T2], prm[P_VFLOOR])
    kw_mw = prm[P_KW] * M_w
    minus_w0 = w0_plus_of(prm, wbr, cwd, cwdd, wbn)
    JSdd = matvec3_flat_of(prm, P_J, S_d_dot[0], S_d_dot[1], S_d_dot[2])
    D_m, mu = prm[P_DM], prm[P_MU]
    # eq. (U): u = -W0 + J dS_d/dt - D_m tanh(z2/mu) - M_omega K_omega J z2
    cmd = (((minus_w0[0] + JSdd[0]) - D_m * libm.tanh(z0 / mu)) - kw_mw * Jz2[0],
           ((minus_w0[1] + JSdd[1]) - D_m * libm.tanh(z1 / mu)) - kw_mw * Jz2[1],
           ((minus_w0[2] + JSdd[2]) - D_m * libm.tanh(z2 / mu)) - kw_mw * Jz2[2])
    return cmd, (V1, V2, V3), S_next


# ============================================================================= BLFPPC


@jit
def blfppc_law(prm, coef, state, tau, dt, work, out):
    """The BLFPPC benchmark law of Appendix C (module :mod:`.blfppc`), with ``Gamma^-1`` in the
    coupling term as the appendix writes it (docs/paper_notes.md, observation 6)."""
    # FTPPF rho(t) = rho_0 (1 - t/T_f)^(1/m) + rho_Tf, t < T_f
    T_f, rho_Tf = prm[P_FT_TF], prm[P_FT_RHOTF]
    if tau >= T_f:
        f, f_dot = rho_Tf, 0.0
    else:
        inv_m = prm[P_FT_INVM]
        rho_0 = prm[P_FT_RHO0] - rho_Tf
        frac = 1.0 - max(tau, 0.0) / T_f
        f = rho_0 * frac**inv_m + rho_Tf
        f_dot = -rho_0 * inv_m * frac ** (inv_m - 1.0) / T_f
    K1 = prm[P_K1]
    x, eps_a = work[W_X], work[W_EPS]
    for i in range(3):
        up = coef[C_SIGN, i] > 0.0
        rho_u = f if up else 0.0
        rho_l = 0.0 if up else -f
        rho_u_dot = f_dot if up else 0.0
        rho_l_dot = 0.0 if up else -f_dot
        q_ev = work[W_QBR, i]
        width = rho_u - rho_l
        P_lu = rho_l + rho_u  # P_lu = rho_l + rho_u
        eps = (2.0 * q_ev - P_lu) / width  # BLF-type transformation
        S_b = rho_l_dot * rho_u - rho_u_dot * rho_l  # S_b = rho_l' rho_u - rho_u' rho_l
        S_v = ((rho_u_dot - rho_l_dot) * q_ev + S_b) / width  # S_v
        x[i] = (-K1 * q_ev + 0.5 * K1 * P_lu) + S_v  # -K1 q_ev + 1/2 K1 P_lu + S_v
        eps_a[i] = eps
        out[O_RHO, i] = rho_u if up else rho_l
        out[O_BL, i] = rho_l
        out[O_BU, i] = rho_u
        out[O_EPS, i] = eps
        out[O_Z, i] = q_ev
        work[W_PSI, i] = width  # kept for D_rho below
    alpha = work[W_ALPHA]
    gamma_inverse_times(work[W_QBR], x, prm[P_Q0FLOOR], alpha)  # alpha = Gamma^-1 [...]
    S_d, S_d_dot = work[W_SD], work[W_SDDOT]
    V3, sd, sdd = filter_update(prm, state, dt, alpha[0], alpha[1], alpha[2])  # eq. (dSd)
    for i in range(3):
        S_d[i] = sd[i]
        S_d_dot[i] = sdd[i]
    z2, Jz2 = work[W_Z2], work[W_JZ2]
    D_rho_eps = work[W_ETA]
    for i in range(3):
        z2[i] = work[W_WBR, i] - S_d[i]
        e = eps_a[i]
        barrier = 1.0 - e * e  # barrier guard: |1 - eps^2| >= BARRIER_MARGIN (module blfppc)
        if abs(barrier) < BARRIER_MARGIN:
            barrier = np.copysign(BARRIER_MARGIN, barrier)
        D_rho_eps[i] = e / (barrier * work[W_PSI, i])  # D_rho eps
    matvec3_flat(prm, P_J, z2, Jz2)
    coupling = work[W_X]
    gamma_inverse_times(work[W_QBR], D_rho_eps, prm[P_Q0FLOOR], coupling)
    minus_w0 = w0_plus(prm, work)
    JSdd = work[W_PSI]  # width no longer needed
    matvec3_flat(prm, P_J, S_d_dot, JSdd)
    K2, two_K3, D_m, mu = prm[P_K2], 2.0 * prm[P_K3], prm[P_DM], prm[P_MU]
    for i in range(3):  # u = -K2 J z2 - 2 K3 Gamma^-1 D_rho eps - W0 + J dS_d/dt - D_m tanh(z2/mu)
        out[O_CMD, i] = (((-K2 * Jz2[i] - two_K3 * coupling[i]) + minus_w0[i]) + JSdd[i]) - D_m * np.tanh(z2[i] / mu)
    out[O_V, 0] = 0.5 * dot3(eps_a, eps_a)
    out[O_V, 1] = 0.5 * dot3(z2, Jz2)
    out[O_V, 2] = V3


# ============================================================================= MRP feedback


@jit
def mrp_feedback_law(prm, state, dt, work, out):
    """Basilisk's ``mrpFeedback`` law (Schaub & Junkins, Analytical Mechanics of Space Systems,
    Example 8.14; module :mod:`.mrp_feedback`), ``controlLawType = 0``, no reaction-wheel terms and
    no known external torque, operation by operation as ``Update_mrpFeedback`` computes it.

    From the error state in ``work``: ``sigma_BR = q_ev / (1 + q_e0)`` (``q_e0 >= 0``, so
    ``|sigma_BR| <= 1``: the short rotation, the set Basilisk's guidance gives after its shadow-set
    switch), ``omega_BR_B = omega_e``, ``omega_RN_B = C_e omega_d``, ``domega_RN_B = C_e omegadot_d``.
    The integral ``int_sigma += K h sigma_BR`` (``h = 0`` at a run's first call, else ``dt``: the
    time since the previous call), each component scaled back to ``integralLimit``, accumulates only
    while ``Ki > 0``; then ``z = int_sigma + J omega_BR_B`` (else ``z = 0``) and

        L_r = K sigma + P dw + P Ki z - (omega_r + Ki z) x (J omega) + J (omega x omega_r - domega_r)
        u   = -L_r

    ``u`` (Basilisk's ``torqueRequestBody``) is the torque to apply.  Writes ``out[O_CMD]``;
    ``eps = sigma_BR``, ``z``, ``rho = 0`` (the law steers the error to zero), an unbounded band
    (the law imposes no constraint) and ``V``: the three terms of the Lyapunov function
    ``2 K ln(1 + sigma^T sigma)``, ``dw^T J dw / 2``, ``Ki z^T z / 2`` (0 when the integral is off)."""
    K, P, Ki, limit = prm[P_MRP_K], prm[P_MRP_P], prm[P_MRP_KI], prm[P_MRP_INT_LIMIT]
    sigma = work[W_EPS]
    for i in range(3):
        sigma[i] = work[W_QBR, i] / (1.0 + work[W_QBR, 3])  # sigma_BR (Basilisk's EP2MRP for b0 >= 0)
    s0, s1, s2 = sigma[0], sigma[1], sigma[2]
    dw0, dw1, dw2 = work[W_WBR, 0], work[W_WBR, 1], work[W_WBR, 2]  # omega_BR_B
    h = dt if state[S_HAS_PRIOR_CALL] != 0.0 else 0.0  # mrpFeedback: no control period at the first call
    state[S_HAS_PRIOR_CALL] = 1.0
    z0 = z1 = z2 = 0.0
    if Ki > 0.0:  # integral feedback on
        k_h = K * h
        for i in range(3):
            acc = k_h * sigma[i] + state[S_INT_SIGMA + i]
            mag = abs(acc)
            if mag > limit:  # keep |int_sigma_i| <= integralLimit, its sign kept
                acc *= limit / mag
            state[S_INT_SIGMA + i] = acc
        Jdw = matvec3_flat_of(prm, P_J, dw0, dw1, dw2)
        z0 = state[S_INT_SIGMA] + Jdw[0]  # z = K int(sigma) + J dw
        z1 = state[S_INT_SIGMA + 1] + Jdw[1]
        z2 = state[S_INT_SIGMA + 2] + Jdw[2]
    kz0, kz1, kz2 = Ki * z0, Ki * z1, Ki * z2
    L0 = (P * dw0 + K * s0) + P * kz0  # +K sigma + P dw + P Ki z
    L1 = (P * dw1 + K * s1) + P * kz1
    L2 = (P * dw2 + K * s2) + P * kz2
    w0, w1, w2 = work[W_WBN, 0], work[W_WBN, 1], work[W_WBN, 2]  # omega_BN_B
    Jw = matvec3_flat_of(prm, P_J, w0, w1, w2)
    r0, r1, r2 = work[W_CWD, 0], work[W_CWD, 1], work[W_CWD, 2]  # omega_RN_B
    a0, a1, a2 = r0 + kz0, r1 + kz1, r2 + kz2  # omega_r + Ki z
    L0 = L0 - (a1 * Jw[2] - a2 * Jw[1])  # -(omega_r + Ki z) x (J omega)
    L1 = L1 - (a2 * Jw[0] - a0 * Jw[2])
    L2 = L2 - (a0 * Jw[1] - a1 * Jw[0])
    b0 = (w1 * r2 - w2 * r1) - work[W_CWDD, 0]  # omega x omega_r - domega_r
    b1 = (w2 * r0 - w0 * r2) - work[W_CWDD, 1]
    b2 = (w0 * r1 - w1 * r0) - work[W_CWDD, 2]
    Jb = matvec3_flat_of(prm, P_J, b0, b1, b2)
    out[O_CMD, 0] = -(Jb[0] + L0)  # u = -L_r, the torque to apply
    out[O_CMD, 1] = -(Jb[1] + L1)
    out[O_CMD, 2] = -(Jb[2] + L2)
    for i in range(3):
        out[O_RHO, i] = 0.0
        out[O_BL, i] = -np.inf
        out[O_BU, i] = np.inf
    out[O_EPS, 0], out[O_EPS, 1], out[O_EPS, 2] = s0, s1, s2
    out[O_Z, 0], out[O_Z, 1], out[O_Z, 2] = z0, z1, z2
    Jdw = matvec3_flat_of(prm, P_J, dw0, dw1, dw2)
    out[O_V, 0] = 2.0 * K * np.log1p((s0 * s0 + s1 * s1) + s2 * s2)
    out[O_V, 1] = 0.5 * ((dw0 * Jdw[0] + dw1 * Jdw[1]) + dw2 * Jdw[2])
    out[O_V, 2] = 0.5 * max(Ki, 0.0) * ((z0 * z0 + z1 * z1) + z2 * z2)


# ============================================================================= the step


@jit(inline="always")
def controller_step(kind, t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm, coef, state, work, out):
    """One sampling instant of one run: error state, law, actuator (see module docstring).

    ``t`` [s] is absolute; the law sees ``tau = t - state[S_T0]``.  The run must have been
    started (:func:`start_coef`, :func:`new_state`).  Results in ``out``.
    """
    error_state(q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, work)
    for i in range(4):
        out[O_QBR, i] = work[W_QBR, i]
    if prm[P_RATE_WC] > 0.0:  # the rate filter (issue 34); off, nothing here runs
        rate_filter(prm, state, dt, work)
    tau = t - state[S_T0]
    if kind == KIND_BLFPPC:
        blfppc_law(prm, coef, state, tau, dt, work, out)
    elif kind == KIND_MRP_FEEDBACK:
        mrp_feedback_law(prm, state, dt, work, out)
    else:
        if kind == KIND_SAPPC:
            sappc_transform(prm, coef, state, tau, work, out)
        else:
            trappc_transform(prm, coef, tau, work, out)
        backstepping_law(prm, state, dt, work, out)
    actuator(prm, state, dt, out)


@jit
def mrp_feedback_step(t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm, coef, state, work, out):
    """:func:`controller_step` of MRP feedback, compiled on its own: the flight modes' HOLD and SAFE
    law (:mod:`sappc_controller.modes`, and the offline loop's, which inlines only the scenario's
    law: each inlined copy of the step costs its compile seconds)."""
    controller_step(KIND_MRP_FEEDBACK, t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm, coef, state, work, out)


@jit
def controller_step_one(kind, t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm, coef, state, work, out, saturated):
    """:func:`controller_step_batch` for a batch of one run given as vectors (``q_BN`` (4,), ...):
    the node's path, without reshaping the inputs in Python; the same :func:`controller_step` call."""
    controller_step(kind, t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm[0], coef[0], state[0], work, out[0])
    for i in range(3):
        saturated[0, i] = out[0, O_SAT, i] != 0.0


@jit
def controller_step_batch(kind, t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, prm, coef, state, work, out, saturated):
    """:func:`controller_step` for every run of a batch, one after another (the path of
    :meth:`.base.AttitudeController.step`, one run being a batch of one).

    ``q_BN`` (N, 4), ``omega_BN_B`` (N, 3), ``prm`` (N, N_PARAMS), ``coef`` (N, N_COEF, 3), ``state``
    (N, N_STATE), ``out`` (N, N_OUT, 4), ``saturated`` (N, 3) bool (``out[:, O_SAT] != 0``); each
    reference input has one row per run or one row shared by all runs.  Every run gets rows of
    C-contiguous arrays, the argument types of the offline loop: run ``k`` of a batch is the run
    alone, and the offline run, bit for bit.
    """
    shared = q_RN.shape[0] == 1
    for n in range(q_BN.shape[0]):
        m = 0 if shared else n
        controller_step(kind, t, dt, q_BN[n], omega_BN_B[n], q_RN[m], omega_RN_R[m], omegadot_RN_R[m], prm[n], coef[n], state[n],
                        work, out[n])
        for i in range(3):
            saturated[n, i] = out[n, O_SAT, i] != 0.0


# ============================================================================= run arrays


@jit
def error_quaternions(q_RN, q_BN):
    """``q_BR`` (N, 4) of states ``q_BN`` (N, 4) against one ``q_RN`` (4,), by the kernel's formula."""
    out = np.empty((q_BN.shape[0], 4))
    for n in range(q_BN.shape[0]):
        error_quaternion(q_RN, q_BN[n], out[n])
    return out


def new_state(n_runs: int = 1, t0: float | np.ndarray = 0.0) -> np.ndarray:
    """Fresh per-run states (n_runs, N_STATE): empty filter, no warm start, time origin ``t0``."""
    state = np.zeros((n_runs, N_STATE))
    state[:, S_T0] = t0
    return state


class ControllerArrays(NamedTuple):
    """The controller of a batch, as the whole-run loop takes it (:mod:`sappc.offline.compiled_loop`):
    ``kind`` (``KIND_*``), ``prm`` (N, N_PARAMS) and ``coef`` (N, N_COEF, 3) each run's parameters
    and start constants, and the node's answer rules: ``stale_ns`` the watchdog's timeout [ns] and
    ``bounds`` the input check's bounds (:meth:`gnc_common.input_check.InputBounds.packed`).  Packed by
    :func:`.packing.pack_controller`; ``coef`` is filled at each run's first valid sample."""

    kind: int
    prm: NDArray[np.float64]
    coef: NDArray[np.float64]
    stale_ns: int
    bounds: NDArray[np.float64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"prm": 0, "coef": 0}

"""Compiled per-run plant kernels: rigid-body RK4 with zero-order hold, the paper's reference
rates, every disturbance kind and the sensor-noise model (numba, see :mod:`gnc_common.compiled`).

These are **the** implementation of the plant models: :class:`.dynamics.RigidBody`,
:class:`.reference.PaperReference` (rates) and the models of :mod:`.disturbance` evaluate through
them (the node, the offline run and a campaign share one code path).  Each works over one run's
small float64 arrays; the ``*_runs`` / ``*_tables`` functions loop over runs or times in compiled
code.  A plain numpy oracle of the same formulas lives in ``tests/sim/oracle.py`` (tests only).

Disturbances
------------
A :class:`~.disturbance.DisturbanceSum` is encoded by :func:`encode_disturbance` as

``kinds`` (M,) int64
    One of ``D_PERIODIC`` (paper_periodic), ``D_CONSTANT``, ``D_STEP``, ``D_PULSE``, ``D_RANDOM``.
``dparams`` (M, 8)
    ``periodic: omega_p``; ``constant: tx, ty, tz``; ``step: tx, ty, tz, start``;
    ``pulse: tx, ty, tz, start, duration``; ``random: sx, sy, sz, hold, r`` (``r``: index of its
    draw table).
``dscale``, ``dphase`` (N, M)
    Per-run scale and phase of each periodic model (Monte Carlo dispersions; 1 and 0 otherwise).
``rand_draws`` (R, N, W, 3), ``rand_win`` (R, T)
    The random kind's Gaussian draws.  ``RandomTorque`` draws window ``k`` of seed ``s`` from
    ``numpy.random.default_rng([s, k])``, which compiled code cannot reproduce; the draws of every
    window of the run's time grid are therefore made **before** the loop, in Python, by the same
    calls (:func:`random_draws`), and the kernel looks them up (``rand_win[r, k]`` is the draw
    index of sample ``k``).  Same values, bit for bit.

:func:`disturbance_sample` evaluates the sum at one time for one run, models in list order
(``((0 + d_1) + d_2) ...``, as :class:`~.disturbance.DisturbanceSum`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit, matvec3, matvec3_flat_of, matvec3_of, quat_multiply, quat_normalize
from gnc_common.validation import ConfigError
from spacecraft_sim.core.sensors import rotate_by_vector


__all__ = [
    "DisturbanceArrays",
    "FaultArrays",
    "PlantArrays",
    "disturbance_at",
    "D_CONSTANT",
    "D_PERIODIC",
    "D_PULSE",
    "D_RANDOM",
    "D_STEP",
    "TIME_TOLERANCE_S",
    "derivative_runs",
    "disturbance_sample",
    "disturbance_table",
    "disturbance_tables",
    "noisy_measurement",
    "propagate",
    "propagate_runs",
    "rate_tables",
    "reference_quaternions",
    "REFERENCE_STEP_SLACK",
    "reference_omega",
    "reference_rates",
    "rk4_step",
]

D_PERIODIC, D_CONSTANT, D_STEP, D_PULSE, D_RANDOM = 0, 1, 2, 3, 4
N_DPARAMS = 8
#: Tolerance of time-window comparisons [s] (step and pulse disturbances, fault windows): far
#: below any control period (>= 1e-4 s), far above the rounding of k * dt over hours (1e-12 s).
#: Re-exported by :mod:`.disturbance`.
TIME_TOLERANCE_S = 1e-9
_TOL = TIME_TOLERANCE_S


# ============================================================================= rigid body


@jit(inline="always")
def flat9(M):
    """The (3, 3) matrix ``M`` as a 9-tuple, row major (what :func:`_rates` and :func:`rk4_of` take)."""
    return (M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2])


@jit(inline="always")
def _rates(s, a0, a1, a2, J, J_inv):
    """``dx/dt`` of the state ``s`` = (q_BN, omega_BN_B), a 7-tuple, given ``J^-1 torque`` =
    (a0, a1, a2) (module dynamics): ``dq/dt = 1/2 q ⊗ (omega, 0)``,
    ``domega/dt = J^-1 torque - J^-1 (omega × J omega)``; a 7-tuple.  ``J`` and ``J_inv`` row major,
    9 entries (:func:`flat9`).  Scalars only (the matrix products by
    :func:`gnc_common.compiled.matvec3_flat_of`, the sums of ``matvec3_of``): no array view, so no
    reference count per call in the loops that inline it (the SIMD lanes' too)."""
    q3 = s[3]
    w0, w1, w2 = s[4], s[5], s[6]
    c0 = s[1] * w2 - s[2] * w1
    c1 = s[2] * w0 - s[0] * w2
    c2 = s[0] * w1 - s[1] * w0
    Jw = matvec3_flat_of(J, 0, w0, w1, w2)  # J omega
    cr0 = w1 * Jw[2] - w2 * Jw[1]  # omega × J omega
    cr1 = w2 * Jw[0] - w0 * Jw[2]
    cr2 = w0 * Jw[1] - w1 * Jw[0]
    Jic = matvec3_flat_of(J_inv, 0, cr0, cr1, cr2)
    return (0.5 * (q3 * w0 + c0), 0.5 * (q3 * w1 + c1), 0.5 * (q3 * w2 + c2), -0.5 * ((s[0] * w0 + s[1] * w1) + s[2] * w2),
            a0 - Jic[0], a1 - Jic[1], a2 - Jic[2])


@jit(inline="always")
def _stage(s, h, k):
    """``s + h k`` for 7-tuples (an RK4 stage's state)."""
    return (s[0] + h * k[0], s[1] + h * k[1], s[2] + h * k[2], s[3] + h * k[3], s[4] + h * k[4], s[5] + h * k[5], s[6] + h * k[6])


@jit(inline="always")
def derivative(x, accel_ext, J, J_inv, out):
    """``dx/dt`` of ``x = (q_BN, omega_BN_B)`` (7,) given ``J^-1 torque`` (3,) into ``out`` (7,)
    (:func:`_rates`)."""
    d = _rates((x[0], x[1], x[2], x[3], x[4], x[5], x[6]), accel_ext[0], accel_ext[1], accel_ext[2], flat9(J), flat9(J_inv))
    for i in range(7):
        out[i] = d[i]


@jit(inline="always")
def rk4_step(x, a0, a1, a2, dt, J, J_inv):
    """One classical RK4 step of ``dt`` in place, ``J^-1 torque`` = (a0, a1, a2) held (ZOH), then
    ``q`` renormalised (:meth:`.dynamics.RigidBody.rk4_step`).  The stages are scalars
    (:func:`_rates`): no scratch array."""
    y = rk4_of((x[0], x[1], x[2], x[3], x[4], x[5], x[6]), a0, a1, a2, dt, flat9(J), flat9(J_inv))
    for i in range(7):
        x[i] = y[i]


@jit(inline="always")
def rk4_of(s, a0, a1, a2, dt, J, J_inv):
    """:func:`rk4_step` of the state ``s`` (a 7-tuple), ``J`` and ``J_inv`` row major (9 entries):
    the next state, a 7-tuple, ``q`` renormalised."""
    h2 = 0.5 * dt
    k1 = _rates(s, a0, a1, a2, J, J_inv)
    k2 = _rates(_stage(s, h2, k1), a0, a1, a2, J, J_inv)
    k3 = _rates(_stage(s, h2, k2), a0, a1, a2, J, J_inv)
    k4 = _rates(_stage(s, dt, k3), a0, a1, a2, J, J_inv)
    c = dt / 6.0
    y0 = s[0] + c * ((k1[0] + 2.0 * (k2[0] + k3[0])) + k4[0])
    y1 = s[1] + c * ((k1[1] + 2.0 * (k2[1] + k3[1])) + k4[1])
    y2 = s[2] + c * ((k1[2] + 2.0 * (k2[2] + k3[2])) + k4[2])
    y3 = s[3] + c * ((k1[3] + 2.0 * (k2[3] + k3[3])) + k4[3])
    n = np.sqrt(((y0 * y0 + y1 * y1) + y2 * y2) + y3 * y3)
    return (y0 / n, y1 / n, y2 / n, y3 / n, s[4] + c * ((k1[4] + 2.0 * (k2[4] + k3[4])) + k4[4]),
            s[5] + c * ((k1[5] + 2.0 * (k2[5] + k3[5])) + k4[5]), s[6] + c * ((k1[6] + 2.0 * (k2[6] + k3[6])) + k4[6]))


@jit(inline="always")
def propagate(x, torque_B, dt, substeps, J, J_inv):
    """Advance ``x`` (7,) in place by ``dt`` in ``substeps`` RK4 steps with ``torque_B`` held
    (zero-order hold, :meth:`.dynamics.RigidBody.propagate`; inputs checked by the caller)."""
    a0, a1, a2 = matvec3_of(J_inv, torque_B[0], torque_B[1], torque_B[2])  # J^-1 torque
    h = dt / substeps
    for _ in range(substeps):
        rk4_step(x, a0, a1, a2, h, J, J_inv)


@jit
def propagate_runs(x, torque_B, dt, substeps, J, J_inv, out):
    """:func:`propagate` for each run ``n`` of ``out`` (N, 7), from ``x`` (Nx, 7) with ``torque_B``
    (Nu, 3) and ``J``, ``J_inv`` (NJ, 3, 3); each of Nx, Nu, NJ is 1 (shared by every run) or N.
    ``x`` is not changed (``out`` may not alias it); inputs checked by the caller
    (:meth:`.dynamics.RigidBody.propagate`)."""
    xs = np.empty(7)
    u = np.empty(3)
    for n in range(out.shape[0]):
        nx = n if x.shape[0] > 1 else 0
        nu = n if torque_B.shape[0] > 1 else 0
        nj = n if J.shape[0] > 1 else 0
        for i in range(7):
            xs[i] = x[nx, i]
        for i in range(3):
            u[i] = torque_B[nu, i]
        propagate(xs, u, dt, substeps, J[nj], J_inv[nj])
        for i in range(7):
            out[n, i] = xs[i]


@jit
def derivative_runs(x, torque_B, J, J_inv, out):
    """:func:`derivative` of each run, ``J^-1 torque`` formed first (shapes of :func:`propagate_runs`)."""
    accel = np.empty(3)
    for n in range(out.shape[0]):
        nx = n if x.shape[0] > 1 else 0
        nu = n if torque_B.shape[0] > 1 else 0
        nj = n if J.shape[0] > 1 else 0
        matvec3(J_inv[nj], torque_B[nu], accel)
        derivative(x[nx], accel, J[nj], J_inv[nj], out[n])


# ============================================================================= reference


@jit
def reference_rates(t, a_rad_s, periods, w_out, wdot_out):
    """Paper reference (Sec. V.A): ``omega_d = A [cos(t/40), sin(t/30), -cos(t/50)]``
    (:func:`reference_omega`) and its derivative, ``A`` in rad/s (:class:`.reference.PaperReference`)."""
    p0, p1, p2 = periods[0], periods[1], periods[2]
    reference_omega(t, a_rad_s, periods, w_out)
    wdot_out[0] = a_rad_s * (-np.sin(t / p0) / p0)
    wdot_out[1] = a_rad_s * (np.cos(t / p1) / p1)
    wdot_out[2] = a_rad_s * (np.sin(t / p2) / p2)


@jit(inline="always")
def reference_omega(t, a_rad_s, periods, w_out):
    """The paper reference's rate alone (Sec. V.A): ``omega_d = A [cos(t/40), sin(t/30), -cos(t/50)]``
    [rad/s] (the reference's kinematics need no derivative)."""
    w_out[0] = a_rad_s * np.cos(t / periods[0])
    w_out[1] = a_rad_s * np.sin(t / periods[1])
    w_out[2] = a_rad_s * -np.cos(t / periods[2])


@jit
def rate_tables(t, a_rad_s, periods):
    """:func:`reference_rates` on every time of ``t`` (T,): ``omega``, ``omegadot`` (T, 3)."""
    w = np.empty((t.shape[0], 3))
    wd = np.empty((t.shape[0], 3))
    for k in range(t.shape[0]):
        reference_rates(t[k], a_rad_s, periods, w[k], wd[k])
    return w, wd


@jit(inline="always")
def _reference_qdot(q, w, out):
    """``dq_RN/dt = 1/2 q_RN ⊗ (omega_RN_R, 0)`` at the rate ``w`` (scalar last; as
    :func:`gnc_common.attitude.quat_kinematics`)."""
    q0 = q[3]
    c0 = q[1] * w[2] - q[2] * w[1]
    c1 = q[2] * w[0] - q[0] * w[2]
    c2 = q[0] * w[1] - q[1] * w[0]
    out[0] = 0.5 * (q0 * w[0] + c0)
    out[1] = 0.5 * (q0 * w[1] + c1)
    out[2] = 0.5 * (q0 * w[2] + c2)
    out[3] = -0.5 * ((q[0] * w[0] + q[1] * w[1]) + q[2] * w[2])


#: How much longer than ``max_step_s`` (relative) an interval of :func:`reference_quaternions` may be
#: and still take one step: a grid's ``k dt`` differences round to a few ulps of ``t`` (up to
#: 7e-12 s at 6 h, 7e-10 of a 10 ms step), and without it 36 % (60 s) to 64 % (6 h) of a 10 ms
#: grid's intervals took two half steps (``ceil(1 + 1e-12) = 2``) where one was meant.  A step
#: 1e-6 longer changes RK4's local error bound by 5e-6 of itself.
REFERENCE_STEP_SLACK = 1e-6


@jit
def reference_quaternions(t, q, t_prev, a_rad_s, periods, max_step_s, out):
    """``q_RN`` (T, 4) at the increasing times ``t`` (T,) >= ``t_prev`` [s] into ``out``, from the
    integrated quaternion ``q`` (4,) at ``t_prev`` (``q_RN0`` and 0 for a run's start), which is
    integrated in place to ``t[-1]`` (so the next block of samples continues from it): classical
    RK4 on the kinematics, each interval between samples (and ``[t_prev, t_0]``) in
    ``ceil(length / max_step_s - REFERENCE_STEP_SLACK)`` equal steps, at least one; the integrated
    quaternion is kept as it is and each
    sample is its normalised copy.  Fixed steps from the sample times alone: the same samples give
    the same bits on every path, in one call or block after block, and, with no BLAS call, on every
    host (docs/parity.md); see :class:`.reference.PaperReference` for the accuracy."""
    qs = np.empty(4)
    k1, k2, k3, k4 = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    w = np.empty(3)
    for j in range(t.shape[0]):
        span = t[j] - t_prev
        n = max(1, int(np.ceil(span / max_step_s - REFERENCE_STEP_SLACK))) if span > 0.0 else 0
        if n > 0:
            h = span / n
            for s in range(n):
                ts = t_prev + s * h
                reference_omega(ts, a_rad_s, periods, w)
                _reference_qdot(q, w, k1)
                for i in range(4):
                    qs[i] = q[i] + 0.5 * h * k1[i]
                reference_omega(ts + 0.5 * h, a_rad_s, periods, w)  # k2's and k3's time: one rate for both
                _reference_qdot(qs, w, k2)
                for i in range(4):
                    qs[i] = q[i] + 0.5 * h * k2[i]
                _reference_qdot(qs, w, k3)
                for i in range(4):
                    qs[i] = q[i] + h * k3[i]
                reference_omega(ts + h, a_rad_s, periods, w)
                _reference_qdot(qs, w, k4)
                c = h / 6.0
                for i in range(4):
                    q[i] = q[i] + c * ((k1[i] + 2.0 * (k2[i] + k3[i])) + k4[i])
        quat_normalize(q, out[j])
        t_prev = t[j]


# ============================================================================= disturbances


@jit(inline="always")
def paper_periodic(t, omega_p, scale, phase, out):
    """The paper's disturbance (Sec. V.A) with ``w t`` shifted by ``phase`` and scaled by ``scale``,
    added to ``out`` (:class:`.disturbance.PaperPeriodic`)."""
    wt = omega_p * t + phase
    d0 = 1e-3 * ((4.0 * np.sin(3.0 * wt) + 3.0 * np.cos(10.0 * wt)) - 20.0)
    d1 = 1e-3 * ((-1.5 * np.sin(2.0 * wt) + 3.0 * np.cos(5.0 * wt)) + 20.0)
    d2 = 1e-3 * ((3.0 * np.sin(10.0 * wt) - 8.0 * np.cos(4.0 * wt)) + 20.0)
    out[0] = out[0] + scale * d0
    out[1] = out[1] + scale * d1
    out[2] = out[2] + scale * d2


@jit(inline="always")
def disturbance_sample(k, t, kinds, dparams, dscale, dphase, rand_draws, rand_win, out):
    """Total disturbance [N m] of one run at sample ``k``, time ``t``, into ``out`` (3,): the models
    in list order (module docstring).  ``dscale``, ``dphase`` (M,), ``rand_draws`` (R, W, 3) are
    this run's."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for m in range(kinds.shape[0]):
        kind = kinds[m]
        p = dparams[m]
        if kind == D_PERIODIC:
            paper_periodic(t, p[0], dscale[m], dphase[m], out)
        elif kind == D_CONSTANT:
            for i in range(3):
                out[i] = out[i] + p[i]
        elif kind == D_STEP:  # on from start_s (TIME_TOLERANCE_S)
            on = 1.0 if t >= p[3] - _TOL else 0.0
            for i in range(3):
                out[i] = out[i] + p[i] * on
        elif kind == D_PULSE:  # on during [start_s, start_s + duration_s)
            on = 1.0 if ((p[3] - _TOL) <= t and t < (p[3] + p[4] - _TOL)) else 0.0
            for i in range(3):
                out[i] = out[i] + p[i] * on
        else:  # D_RANDOM: the draw of this sample's window, times sigma
            r = int(p[4])
            j = rand_win[r, k]
            for i in range(3):
                out[i] = out[i] + rand_draws[r, j, i] * p[i]


@jit
def disturbance_table(t, kinds, dparams, dscale, dphase, rand_draws, rand_win):
    """:func:`disturbance_sample` on every time of ``t`` (T,) for one run: (T, 3)."""
    d = np.empty((t.shape[0], 3))
    for k in range(t.shape[0]):
        disturbance_sample(k, t[k], kinds, dparams, dscale, dphase, rand_draws, rand_win, d[k])
    return d


@jit
def disturbance_tables(t, kinds, dparams, dscale, dphase, rand_draws, rand_win):
    """:func:`disturbance_sample` on every time of ``t`` (T,) for every run of ``dscale`` (N, M):
    (T, N, 3); ``rand_draws`` (R, N, W, 3) (:func:`encode_disturbance`, :func:`random_draws`)."""
    d = np.empty((t.shape[0], dscale.shape[0], 3))
    for n in range(dscale.shape[0]):
        draws = rand_draws[:, n]
        for k in range(t.shape[0]):
            disturbance_sample(k, t[k], kinds, dparams, dscale[n], dphase[n], draws, rand_win, d[k, n])
    return d


# ============================================================================= sensors


@jit
def noisy_measurement(q_BN, omega_BN_B, n, attitude_std_rad, rate_std_rad_s, q_out, omega_out):
    """The white-noise model of one sample: the fault injector's ``sensor_noise`` fault (through
    :func:`spacecraft_sim.core.faults.noisy_measurement`); the sensors' kernel
    :func:`spacecraft_sim.core.sensors.measure` computes the same with its white-noise parameters
    (one rotation, :func:`~spacecraft_sim.core.sensors.rotate_by_vector`).

    The measured attitude is the true one rotated in the body frame by the rotation vector
    ``attitude_std_rad * n[:3]``; the measured rate is the true one plus ``rate_std_rad_s * n[3:]``.
    ``n`` (6,) holds standard normal draws (their source is the caller's); results in ``q_out`` (4,)
    and ``omega_out`` (3,), which may alias the inputs.
    """
    rotate_by_vector(q_BN, attitude_std_rad * n[0], attitude_std_rad * n[1], attitude_std_rad * n[2], q_out)
    for i in range(3):
        omega_out[i] = omega_BN_B[i] + rate_std_rad_s * n[3 + i]


# ============================================================================= faults

#: Fault kinds of :func:`fault_sensor` / :func:`fault_actuator` (``fkind``); see
#: :mod:`.faults` for their meaning and :func:`.faults.encode_faults` for the encoding.
(F_ACT_EFFECTIVENESS, F_ACT_BIAS, F_ACT_STUCK, F_ACT_DROPOUT, F_SENSOR_NOISE, F_SENSOR_BIAS, F_SENSOR_DROPOUT, F_SENSOR_FREEZE,
 F_DELAY_SENSOR, F_DELAY_ACTUATOR, F_REFERENCE_DROPOUT) = range(11)
#: Columns of ``fprm`` (per fault): effectiveness or bias (3); noise sigmas (2); sensor bias:
#: the bias rotation as a quaternion (4) then the rate bias (3).
N_FPARAMS = 7
#: Values of a sample a delay or freeze keeps: the measured state (q, omega and the tracker
#: sample's epoch: 8, so a held or delayed sample keeps its own time) or a torque (3).
N_FVALUE = 8


@jit(inline="always")
def fault_active(fwin, f, t):
    """Whether fault ``f`` acts at ``t``: ``start_s <= t < end_s`` (``fwin[f] = (start, end)``,
    ``end = inf`` when open), with :data:`TIME_TOLERANCE_S`."""
    return fwin[f, 0] - _TOL <= t and t < fwin[f, 1] - _TOL


@jit(inline="always")
def _fault_hold(fcount, fbuf, f, n, value, m):
    """A delay of ``n`` samples (``n = 0``: a freeze, the window's first sample held) through
    fault ``f``'s ring ``fbuf[f]`` (``n + 1`` slots): ``value[:m]`` is replaced in place by the
    value ``n`` samples earlier in the window (the window's first while fewer have passed)."""
    j = fcount[f]
    slots = n + 1
    if n == 0:
        if j == 0:
            for i in range(m):
                fbuf[f, 0, i] = value[i]
        else:
            for i in range(m):
                value[i] = fbuf[f, 0, i]
    else:
        for i in range(m):
            fbuf[f, j % slots, i] = value[i]
        src = j - n if j >= n else 0
        for i in range(m):
            value[i] = fbuf[f, src % slots, i]
    fcount[f] = j + 1


@jit
def fault_sensor(t, fkind, fwin, fprm, fint, fcount, fbuf, draws, y):
    """The measurement delivered for the true sample ``y`` = (q_BN, omega_BN_B, tracker epoch) (8,) at ``t``,
    through the sensor faults in list order, in place; ``False`` when it is dropped (the faults
    after the dropout in the list do not see the sample).

    ``fcount`` (F,) int64 and ``fbuf`` (F, D, N_FVALUE): the delays' and freezes' state (samples
    since the window opened; reset when it closes).  ``draws`` (F, 6): this sample's standard
    normals of each noise fault (their source is the caller's, :func:`.faults.noise_draws`)."""
    tmp = np.empty(4)
    for f in range(fkind.shape[0]):
        kind = fkind[f]
        if kind == F_SENSOR_NOISE:
            if fault_active(fwin, f, t):
                noisy_measurement(y[:4], y[4:7], draws[f], fprm[f, 0], fprm[f, 1], y[:4], y[4:7])
        elif kind == F_SENSOR_BIAS:
            if fault_active(fwin, f, t):
                quat_multiply(y[:4], fprm[f, :4], tmp)
                quat_normalize(tmp, y[:4])
                for i in range(3):
                    y[4 + i] = y[4 + i] + fprm[f, 4 + i]
        elif kind == F_SENSOR_DROPOUT:
            if fault_active(fwin, f, t):
                return False
        elif kind == F_SENSOR_FREEZE or kind == F_DELAY_SENSOR:
            if fault_active(fwin, f, t):
                _fault_hold(fcount, fbuf, f, fint[f], y, N_FVALUE)
            else:
                fcount[f] = 0
    return True


@jit
def fault_rate_bias(t, fkind, fwin, fprm, out):
    """Add to ``out`` (3,) the rate bias [rad/s] of every ``sensor_bias`` fault active at ``t``: the
    share of the faults in the gyro's true bias (what an estimator's bias is judged against),
    whatever the other faults do to the delivered sample."""
    for f in range(fkind.shape[0]):
        if fkind[f] == F_SENSOR_BIAS and fault_active(fwin, f, t):
            for i in range(3):
                out[i] = out[i] + fprm[f, 4 + i]


@jit
def fault_rate_bias_one(t, fkind, fwin, fprm, out):
    """:func:`fault_rate_bias` called from Python (the plant node's ``truth/gyro_bias``)."""
    fault_rate_bias(t, fkind, fwin, fprm, out)


@jit
def fault_reference(t, fkind, fwin):
    """Whether the reference of ``t`` is delivered (no reference dropout acts)."""
    for f in range(fkind.shape[0]):
        if fkind[f] == F_REFERENCE_DROPOUT and fault_active(fwin, f, t):
            return False
    return True


@jit
def fault_actuator(t, fkind, fwin, fprm, fint, fcount, fbuf, u, u_last):
    """The torque delivered to the plant for the command ``u`` (3,) at ``t``, through the actuator
    faults in list order, in place.  A dropped command (``actuator_dropout``) leaves the actuator
    holding the last delivered one: ``u`` becomes ``u_last`` and ``False`` is returned; otherwise
    ``u_last`` becomes ``u``.  State as in :func:`fault_sensor`."""
    for f in range(fkind.shape[0]):
        kind = fkind[f]
        if kind == F_ACT_EFFECTIVENESS:
            if fault_active(fwin, f, t):
                for i in range(3):
                    u[i] = fprm[f, i] * u[i]
        elif kind == F_ACT_BIAS:
            if fault_active(fwin, f, t):
                for i in range(3):
                    u[i] = u[i] + fprm[f, i]
        elif kind == F_ACT_DROPOUT:
            if fault_active(fwin, f, t):
                for i in range(3):
                    u[i] = u_last[i]
                return False
        elif kind == F_ACT_STUCK or kind == F_DELAY_ACTUATOR:
            if fault_active(fwin, f, t):
                _fault_hold(fcount, fbuf, f, fint[f], u, 3)
            else:
                fcount[f] = 0
    for i in range(3):
        u_last[i] = u[i]
    return True


@jit
def fault_sensor_one(t, fkind, fwin, fprm, fint, fcount, fbuf, draws, y):
    """:func:`fault_sensor` called from Python (the injector node, one sample)."""
    return fault_sensor(t, fkind, fwin, fprm, fint, fcount, fbuf, draws, y)


@jit
def fault_actuator_one(t, fkind, fwin, fprm, fint, fcount, fbuf, u, u_last):
    """:func:`fault_actuator` called from Python (the injector node, one sample)."""
    return fault_actuator(t, fkind, fwin, fprm, fint, fcount, fbuf, u, u_last)


@jit
def fault_reference_one(t, fkind, fwin):
    """:func:`fault_reference` called from Python (the injector node, one sample)."""
    return fault_reference(t, fkind, fwin)


# ============================================================================= a batch's arrays (the offline loop)


class PlantArrays(NamedTuple):
    """The rigid body of a batch, as the whole-run loop takes it (:mod:`sappc.offline.compiled_loop`):
    ``x0`` (N, 7 + W) each run's initial state (with W wheel momenta), ``J`` and ``J_inv`` (N, 3, 3)
    each run's inertia and its inverse, ``substeps`` RK4 steps per control period.  Packed by
    :func:`spacecraft_sim.core.dynamics.pack_plant`."""

    x0: NDArray[np.float64]
    J: NDArray[np.float64]
    J_inv: NDArray[np.float64]
    substeps: int

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"x0": 0, "J": 0, "J_inv": 0}


class DisturbanceArrays(NamedTuple):
    """The external torques of a batch (module docstring, "Disturbances"): ``kinds`` (M,) and
    ``params`` (M, N_DPARAMS) the models, ``scale`` and ``phase`` (N, M) each run's, ``draws``
    (R, N, W, 3) and ``windows`` (R, T) the random models' draws; ``use_table``: every run has the
    same torques, tabulated once in ``table`` (T, 3) (else (0, 3)).  Packed by
    :func:`spacecraft_sim.core.disturbance.pack_disturbance`."""

    use_table: bool
    table: NDArray[np.float64]
    kinds: NDArray[np.int64]
    params: NDArray[np.float64]
    scale: NDArray[np.float64]
    phase: NDArray[np.float64]
    draws: NDArray[np.float64]
    windows: NDArray[np.int64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"scale": 0, "phase": 0, "draws": 1}


class FaultArrays(NamedTuple):
    """A batch's faults (:func:`spacecraft_sim.core.faults.encode_faults` per run): ``kind`` (N, F),
    ``window`` (N, F, 2), ``params`` (N, F, N_FPARAMS), ``samples`` (N, F), ``depth`` the delay
    rings' slots, ``draws`` (T or 1, F, 6) the noise faults' draws (shared).  Packed by
    :func:`spacecraft_sim.core.faults.pack_faults`."""

    kind: NDArray[np.int64]
    window: NDArray[np.float64]
    params: NDArray[np.float64]
    samples: NDArray[np.int64]
    depth: int
    draws: NDArray[np.float64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"kind": 0, "window": 0, "params": 0, "samples": 0}


@jit(inline="always")
def disturbance_at(d, n, k, t, out):
    """The external torque of run ``n`` at sample ``k`` (time ``t`` [s]) into ``out`` (3,), from
    :class:`DisturbanceArrays` ``d`` whose runs have disturbances of their own
    (:func:`disturbance_sample`).  A shared disturbance (``d.use_table``) is the row ``k`` of
    ``d.table``, which the loop reads itself: passing the tuple's seven arrays here would cost eight
    reference counts per sample."""
    disturbance_sample(k, t, d.kinds, d.params, d.scale[n], d.phase[n], d.draws[:, n], d.windows, out)

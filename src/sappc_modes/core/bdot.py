"""The B-dot detumbling law, its gain criterion and a detumble-time prediction (issue 49, DETUMBLE).

DETUMBLE damps the tumble after separation with the magnetorquers, from the magnetometer alone:
no gyro, no star tracker, no estimate.  Its pieces:

=========================================  ==================================================================================
:func:`bdot_step` (compiled)               the law, sample by sample: a body dipole command from the magnetometer's field and
                                           its time stamp, held between the magnetometer's updates
:func:`pack_bdot`, :func:`new_bdot_state`  its parameters (the gain) and its state (the previous sample, the held command)
:func:`detumble_gain`                      the gain criterion of Avanzini & Giulietti, eq. (4)
:func:`geomagnetic_inclination_rad`        the angle ``xi_m`` the criterion takes, eq. (5)
:func:`mean_projector_min_eigenvalue`      the orbit-averaged damping of the slowest direction, eq. (7)
:func:`predicted_detumble_time_s`          the averaged time for the rate to fall by a given factor, eq. (8)
=========================================  ==================================================================================

The law
-------
With ``B`` the field the magnetometer measures in the body frame [T] and ``k`` the gain [N m s],
the commanded body dipole [A m^2] is

    Bdot ~= (B_k - B_{k-1}) / (t_k - t_{k-1})                                  (1)
    m_B   = -(k / |B|^2) Bdot                                                  (2)

(``B = B_k``, the newest sample).  The sign: the magnetorquers' torque is ``tau = m x B``.  In a field
constant in the inertial frame N (its own turning along the orbit, about twice the orbital rate,
is slow against a tumble's rate), ``B_B = [BN] B_N`` changes only through the attitude:
``dB_B/dt = -omega x B`` (``omega = omega_BN_B``).  Then, with ``b = B / |B|``,

    tau = -(k/|B|^2) (-(omega x B)) x B = (k/|B|^2) ((omega x B) x B)
        = (k/|B|^2) (B (B . omega) - |B|^2 omega) = -k (I - b b^T) omega        (3)

which is dissipative: ``tau . omega = -k (|omega|^2 - (b . omega)^2) = -k |omega x b|^2 <= 0``.  The
component of ``omega`` along the field gets no torque (a magnetic torque is always normal to ``B``);
the field's turning along the orbit is what eventually damps every axis.  The difference (1) over
one sample, for a rotation by ``theta = |omega| dt`` about a fixed axis, changes (3) by at most a
fraction ``(theta/2) sqrt(1 + theta^2/9)`` of its size, and that error does no work: the law sampled
this way stays exactly dissipative for ``theta < pi`` (``tests/modes/test_bdot.py`` derives both).

The magnetometer updates at 10 Hz while the loop runs at 100 Hz and holds its sample between
updates: :func:`bdot_step` computes a new command only on a sample with a later time stamp, and
returns the held command otherwise.  It does **not** saturate: the loop maps the body dipole onto
the rods with :func:`sappc_momentum.core.law.dipole_mapping`, which clips each rod to its own
limit (Basilisk's ``dipoleMapping``).

The gain
--------
Avanzini & Giulietti, "Magnetic Detumbling of a Rigid Spacecraft", J. Guidance, Control, and
Dynamics 35(4), 2012, and Markley & Crassidis, *Fundamentals of Spacecraft Attitude Determination
and Control*, Springer 2014, sec. 7.5.1, eq. (7.55), give the gain that damps fastest:

    k* = 2 n (1 + sin xi_m) J_min                                               (4)

with ``n`` the orbital rate [rad/s], ``J_min`` the smallest principal moment of inertia [kg m^2] and
``xi_m`` the inclination of the orbit relative to the geomagnetic equator:

    xi_m = arccos |n_hat . m_hat|  in [0, pi/2]                                  (5)

the angle between the orbit's normal ``n_hat`` and the dipole's axis ``m_hat``.  **How (4) was
checked:** the papers' text could not be read from here; the formula was compared with public
implementations instead: one (a Python module written for the ALEASAT cubesat) cites Markley &
Crassidis eq. 7.55 for ``4 pi / T_orb (1 + sin xi_m) J_min``, which is (4); FossaSat-2's flight
software computes the same expression.

The prediction
--------------
For an isotropic inertia ``J`` the angular momentum in the inertial frame, ``H_N = J omega_N``, obeys,
with the torque (3) rotated into N (the gyroscopic term ``omega x J omega`` vanishes),

    dH_N/dt = [NB] tau = -(k/J) (I - b_N b_N^T) H_N                              (6)

exactly, whatever the attitude: the law's torque (3) is that of the B-cross law
``m = (k/|B|) (omega x b)`` whenever ``Bdot = -omega x B``.  ``b_N(t)`` turns with the orbit; averaged
over one orbit, (6) becomes ``dH_N/dt = -(k/J) M H_N`` with

    M = mean_k (I - b_k b_k^T),   lambda_min = its smallest eigenvalue            (7)

and the slowest direction (``M``'s eigenvector of ``lambda_min``) decays at rate ``(k/J) lambda_min``:
the rate falls from ``rate0`` to ``rate_final`` in

    t = J ln(rate0 / rate_final) / (k lambda_min)                                (8)

Exact for the averaged system started along its slowest direction, an upper bound for the
averaged system started along any other.  The averaging holds while ``k/J`` is small against the
field's turning rate ``nu ~ 2 n``: to first order in ``(k/J) T_orb`` the exact time differs from (8)
by a fraction ``(k/J) g / ln(rate0/rate_final)``, ``g`` a periodic integral of size at most
``T_orb / 4``, so by at most ``(k/J) T_orb / (4 ln(rate0/rate_final))``.  The exact integration of
(6) in ``tests/modes/test_bdot.py`` (a 500 km sun-synchronous orbit, ``(k/J) T_orb = 0.95``, a
tenfold fall predicted in 4.7 orbits) takes 0.986 times (8), with the first-order term accounting
for all but 3e-4 of it.  At the gain (4), ``k/J`` is 2 to 4 times ``n``, ``(k/J) T_orb`` 12 to 25: (8)
is then an order of magnitude, not a figure (on the same orbit at ``k = k*``: the exact tenfold
fall takes 1.3 to 2.5 times (8), depending on the initial direction).  For a body that is not
isotropic, (6) no longer holds and (8) is an estimate only.

Flight software: imports numpy, math and the project's ground (``gnc_common``), never the
simulator, the controller, the estimator or momentum management.  The kernel runs compiled
(numba) in loops and interpreted (``bdot_step.py_func``) in a node, the same operations on the
same doubles (no transcendental function): the same commands, bit for bit; it allocates nothing.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.compiled import jit
from gnc_common.validation import ConfigError, InputError, as_finite_array, check_positive, quoted

__all__ = [
    "BD_GAIN",
    "BS_B_PREV",
    "BS_M",
    "BS_T_PREV",
    "N_BDOT_PARAMS",
    "N_BDOT_STATE",
    "bdot_step",
    "detumble_gain",
    "geomagnetic_inclination_rad",
    "mean_projector_min_eigenvalue",
    "new_bdot_state",
    "pack_bdot",
    "reset_bdot_state",
    "predicted_detumble_time_s",
]

Array = NDArray[np.float64]

#: Parameters (:func:`pack_bdot`, :data:`N_BDOT_PARAMS` floats): the gain ``k`` [N m s] of eq. (2).
BD_GAIN = 0
N_BDOT_PARAMS = 1
#: State (:func:`new_bdot_state`, :data:`N_BDOT_STATE` floats): rows ``BS_B_PREV .. BS_B_PREV+2`` the
#: previous magnetometer sample used [T] (NaN: none); ``BS_T_PREV`` its time stamp [s] (NaN: none);
#: rows ``BS_M .. BS_M+2`` the body dipole command held between the magnetometer's updates [A m^2].
BS_B_PREV = 0
BS_T_PREV = 3
BS_M = 4
N_BDOT_STATE = 7


def new_bdot_state() -> Array:
    """A fresh state (:data:`N_BDOT_STATE`,): no previous sample (NaN field and time), zero dipole held."""
    state = np.empty(N_BDOT_STATE)
    reset_bdot_state.py_func(state)
    return state


@jit
def reset_bdot_state(state):  # type: ignore[no-untyped-def]  # a numba kernel
    """``state`` (:data:`N_BDOT_STATE`,) made fresh in place (:func:`new_bdot_state`): the loop's
    entry into DETUMBLE."""
    for i in range(state.shape[0]):
        state[i] = 0.0
    for i in range(3):
        state[BS_B_PREV + i] = math.nan
    state[BS_T_PREV] = math.nan


def _number(name: str, value: object, *, allow_zero: bool = False) -> float:
    """``value`` checked finite and positive (:func:`~gnc_common.validation.check_positive`), one number."""
    x = check_positive(name, value, allow_zero=allow_zero)
    if not isinstance(x, float):
        raise ConfigError(f"{name} must be one number, got {value!r}")
    return x


def pack_bdot(gain_N_m_s: float) -> Array:
    """The parameters as :func:`bdot_step` takes them (:data:`N_BDOT_PARAMS`,).

    Parameters
    ----------
    gain_N_m_s : float
        The gain ``k`` of eq. (2) [N m s], finite and > 0 (e.g. :func:`detumble_gain`).

    Raises
    ------
    ConfigError
        Naming the value, if it is not one finite positive number.
    """
    out = np.zeros(N_BDOT_PARAMS)
    out[BD_GAIN] = _number("gain_N_m_s", gain_N_m_s)
    return out


@jit
def bdot_step(prm, B_meas_B, t_meas_s, state, m_B_out):  # type: ignore[no-untyped-def]  # a numba kernel
    """One call of the loop (module docstring): the body dipole command ``m_B`` [A m^2] into
    ``m_B_out`` (3,).

    On a **new** magnetometer sample (``t_meas_s > state[BS_T_PREV]``, the first one included: a NaN
    previous time), if a previous sample exists, ``Bdot = (B - B_prev) / (t - t_prev)`` (eq. 1) and
    ``m_B = -(k / |B|^2) Bdot`` (eq. 2, ``B`` the new sample); with no previous sample, ``m_B = 0``.  The
    new sample becomes the previous one and ``m_B`` is held in ``state[BS_M:BS_M+3]``.  On the **same**
    sample again (``t_meas_s <= t_prev``: the magnetometer holds its sample between its 10 Hz
    updates while the loop runs at 100 Hz) the held dipole is returned unchanged.

    A non-finite field component, ``|B| == 0`` (``|B|^2`` not finite and positive) or a non-finite
    time stamp: ``m_B = 0``, held, and the previous sample is forgotten (NaN), so the next valid
    sample only primes the law.  A command that overflows (a field below about 1e-154 T, or samples
    about 1e-300 s apart: never a magnetometer's) is zero, the sample kept as the previous one.

    No saturation here: the loop maps ``m_B`` onto the rods with
    :func:`sappc_momentum.core.law.dipole_mapping`, which clips each rod.

    Parameters
    ----------
    prm : ndarray (N_BDOT_PARAMS,)
        :func:`pack_bdot`.
    B_meas_B : ndarray (3,)
        The magnetometer's field in the body frame [T].
    t_meas_s : float
        Its time stamp [s].
    state : ndarray (N_BDOT_STATE,)
        :func:`new_bdot_state`, updated in place.
    m_B_out : ndarray (3,)
        Written: the body dipole command [A m^2].

    Returns
    -------
    bool
        True when a new command was set (a new sample, or an invalid one: its zero), False when
        the held command was returned.
    """
    b0 = B_meas_B[0]
    b1 = B_meas_B[1]
    b2 = B_meas_B[2]
    B_sq = (b0 * b0 + b1 * b1) + b2 * b2  # |B|^2 of eq. (2); NaN or inf when a component is
    if not (math.isfinite(B_sq) and B_sq > 0.0 and math.isfinite(t_meas_s)):
        for i in range(3):
            state[BS_B_PREV + i] = math.nan
            state[BS_M + i] = 0.0
            m_B_out[i] = 0.0
        state[BS_T_PREV] = math.nan
        return True
    t_prev = state[BS_T_PREV]
    if t_meas_s <= t_prev:  # the same sample (a NaN t_prev fails this: the first sample is new)
        for i in range(3):
            m_B_out[i] = state[BS_M + i]
        return False
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    if not math.isnan(t_prev):
        dt = t_meas_s - t_prev
        c = -prm[BD_GAIN] / B_sq  # -(k / |B|^2), eq. (2)
        m0 = c * ((b0 - state[BS_B_PREV]) / dt)  # eq. (2) with Bdot of eq. (1)
        m1 = c * ((b1 - state[BS_B_PREV + 1]) / dt)
        m2 = c * ((b2 - state[BS_B_PREV + 2]) / dt)
        if not (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(m2)):
            m0 = 0.0
            m1 = 0.0
            m2 = 0.0
    state[BS_B_PREV] = b0
    state[BS_B_PREV + 1] = b1
    state[BS_B_PREV + 2] = b2
    state[BS_T_PREV] = t_meas_s
    state[BS_M] = m0
    state[BS_M + 1] = m1
    state[BS_M + 2] = m2
    m_B_out[0] = m0
    m_B_out[1] = m1
    m_B_out[2] = m2
    return True


def detumble_gain(orbit_rate_rad_s: float, geomagnetic_inclination_rad: float, J_min_kg_m2: float) -> float:
    """The gain criterion ``k* = 2 n (1 + sin xi_m) J_min`` [N m s] (eq. 4; Avanzini & Giulietti,
    JGCD 35(4), 2012; Markley & Crassidis 2014, sec. 7.5.1, eq. 7.55; checked against public
    implementations citing eq. 7.55, not against the papers' text: module docstring).

    Parameters
    ----------
    orbit_rate_rad_s : float
        The mean motion ``n`` [rad/s], finite and > 0.
    geomagnetic_inclination_rad : float
        ``xi_m`` [rad], in ``[0, pi]`` (:func:`geomagnetic_inclination_rad` gives it in ``[0, pi/2]``;
        ``sin`` is the same for ``pi - xi_m``).
    J_min_kg_m2 : float
        The smallest principal moment of inertia [kg m^2], finite and > 0.

    Raises
    ------
    ConfigError
        Naming the argument that is not a finite number in its range.
    """
    n = _number("orbit_rate_rad_s", orbit_rate_rad_s)
    xi = _number("geomagnetic_inclination_rad", geomagnetic_inclination_rad, allow_zero=True)
    if xi > math.pi:
        raise ConfigError(f"geomagnetic_inclination_rad must be in [0, pi], got {geomagnetic_inclination_rad!r}")
    J_min = _number("J_min_kg_m2", J_min_kg_m2)
    return 2.0 * n * (1.0 + math.sin(xi)) * J_min  # eq. (4)


def _unit_rows(name: str, value: ArrayLike) -> Array:
    """``value`` (..., 3) checked finite with no zero row, each row divided by its norm."""
    v = as_finite_array(name, value, shape_tail=(3,))
    norms = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(norms == 0.0):
        raise InputError(f"{name} must not contain a zero vector, got {quoted(v.tolist())}")
    return np.asarray(v / norms, dtype=np.float64)


def geomagnetic_inclination_rad(orbit_normal_N: ArrayLike, dipole_axis_N: ArrayLike) -> float:
    """``xi_m = arccos |n_hat . m_hat|`` [rad], in ``[0, pi/2]`` (eq. 5): the acute angle between the
    orbit's plane and the geomagnetic equator, i.e. between the orbit's normal and the dipole's axis.

    Parameters
    ----------
    orbit_normal_N : array_like (3,)
        The orbit's normal (any length, any sense) in N.
    dipole_axis_N : array_like (3,)
        The geomagnetic dipole's axis (any length, any sense) in N.

    Raises
    ------
    InputError
        If a vector is not 3 finite numbers or is zero.
    """
    n_hat = _unit_rows("orbit_normal_N", orbit_normal_N)
    m_hat = _unit_rows("dipole_axis_N", dipole_axis_N)
    if n_hat.shape != (3,) or m_hat.shape != (3,):
        raise InputError(f"orbit_normal_N and dipole_axis_N must be one vector (3,) each, got {n_hat.shape} and {m_hat.shape}")
    c = abs(float(n_hat @ m_hat))
    return math.acos(min(1.0, c))  # eq. (5); rounding can put |n . m| of parallel unit vectors just above 1


def mean_projector_min_eigenvalue(b_N: ArrayLike) -> float:
    """``lambda_min`` of eq. (7): the smallest eigenvalue of ``mean_k (I - b_k b_k^T)``.

    ``(k/J) lambda_min`` is the orbit-averaged decay rate of the slowest direction of eq. (6) (module
    docstring).  In ``[0, 2/3]``: the matrix's trace is 2; 0 when the field keeps one direction
    (a polar orbit's axis cannot be damped along it); 1/2 for a field direction sweeping a great
    circle uniformly; 2/3 for directions spread uniformly over the sphere.

    Parameters
    ----------
    b_N : array_like (K, 3)
        The field's directions in N sampled evenly over (at least) one orbit; any lengths (each row
        is normalised), none zero.

    Raises
    ------
    InputError
        If ``b_N`` is not (K, 3) with K >= 1, finite, with no zero row.
    """
    b = _unit_rows("b_N", b_N)
    if b.ndim != 2 or b.shape[0] < 1:
        raise InputError(f"b_N must be (K, 3) with K >= 1, got shape {b.shape}")
    M = np.eye(3) - (b.T @ b) / b.shape[0]  # eq. (7): mean_k (I - b_k b_k^T)
    return float(np.linalg.eigvalsh(M)[0])


def predicted_detumble_time_s(gain: float, J_kg_m2: float, lambda_min: float, rate0_rad_s: float,
                              rate_final_rad_s: float) -> float:
    """``t = J ln(rate0 / rate_final) / (k lambda_min)`` [s] (eq. 8): the orbit-averaged time for the
    slowest direction's rate to fall from ``rate0`` to ``rate_final``.

    Exact for the averaged system of an isotropic body started along its slowest direction, an
    upper bound for the averaged system started along any other; valid while ``k/J`` is small
    against the field's turning rate (about twice the orbital rate): module docstring.

    Parameters
    ----------
    gain : float
        ``k`` [N m s], finite and > 0.
    J_kg_m2 : float
        The (isotropic) moment of inertia [kg m^2], finite and > 0.
    lambda_min : float
        :func:`mean_projector_min_eigenvalue`, in ``(0, 1]`` (0: that direction is never damped).
    rate0_rad_s, rate_final_rad_s : float
        The initial and the final body-rate magnitudes [rad/s], finite, ``rate0 > rate_final > 0``.

    Raises
    ------
    ConfigError
        Naming the argument that is not a finite number in its range.
    """
    k = _number("gain", gain)
    J = _number("J_kg_m2", J_kg_m2)
    lam = _number("lambda_min", lambda_min)
    if lam > 1.0:
        raise ConfigError(f"lambda_min must be in (0, 1] (an eigenvalue of a mean of projectors), got {lambda_min!r}")
    w0 = _number("rate0_rad_s", rate0_rad_s)
    w1 = _number("rate_final_rad_s", rate_final_rad_s)
    if not w0 > w1:
        raise ConfigError(f"rate0_rad_s ({rate0_rad_s!r}) must be greater than rate_final_rad_s ({rate_final_rad_s!r})")
    return J * math.log(w0 / w1) / (k * lam)  # eq. (8)

"""The flight software's and the plant's shared orbit and field models (issue 36): where a circular
or Keplerian orbit puts the spacecraft, the Earth's rotation, and the centred dipole field.

The plant (:mod:`spacecraft_sim.core.orbit`, :mod:`spacecraft_sim.core.magnetic_field`: the
configuration, the gravity gradient, the docs of each model) computes the truth with these
kernels; the flight software's field-predictive momentum management
(:mod:`sappc_momentum.core.predictive`) predicts the field along the orbit with the same
kernels, as an onboard orbit propagator and field model would (here the truth's own models, with
their parameters: a flight system's onboard models differ from the truth, and the law only needs
them for its plan, the feedback is on the measured momentum).  Both import them from here, the
ground layer, so that the flight software never imports the simulator.

Frames: N the Earth-centred inertial frame (J2000), P the Earth-fixed frame, B the body
(:mod:`spacecraft_sim.core.orbit`).  Pure: no ROS, no clock; the kernels allocate nothing.
"""

from __future__ import annotations

import math

from gnc_common.compiled import jit, quat_rotate_of

__all__ = ["KEPLER_ITERATIONS", "N_ORBIT_PARAMS", "O_A", "O_ARGP", "O_E", "O_I", "O_M0", "O_MU", "O_N", "O_OMEGA_E", "O_RAAN", "O_THETA0",
           "dcm_PN_of", "dipole_field_N", "dipole_field_P_of", "position_N", "position_N_of", "to_body_B", "true_anomaly_of"]

#: Newton iterations on Kepler's equation: from ``E = M`` the iteration converges quadratically for
#: ``e < 0.9`` (the limit :class:`~spacecraft_sim.core.orbit.Orbit` accepts), to the last bit within 6 steps; 12 make sure
#: without a data-dependent loop (every sample costs the same).
KEPLER_ITERATIONS = 12

#: Indices of an orbit's parameters (:meth:`spacecraft_sim.core.orbit.Orbit.params`).
O_A, O_E, O_I, O_RAAN, O_ARGP, O_M0, O_N, O_MU, O_THETA0, O_OMEGA_E = range(10)
N_ORBIT_PARAMS = 10


@jit
def true_anomaly_of(M, e):
    """``f`` [rad] of the mean anomaly ``M`` [rad] and eccentricity ``e`` (:mod:`spacecraft_sim.core.orbit`):
    Kepler's equation by :data:`KEPLER_ITERATIONS` Newton steps, then Schaub & Junkins eq. 9.11."""
    E = M
    for _ in range(KEPLER_ITERATIONS):
        E = E - (E - e * math.sin(E) - M) / (1.0 - e * math.cos(E))  # Vallado, Algorithm 2
    return 2.0 * math.atan2(math.sqrt(1.0 + e) * math.sin(0.5 * E), math.sqrt(1.0 - e) * math.cos(0.5 * E))


@jit
def position_N_of(a, e, inc, raan, argp, f):
    """``r_N`` [m] of the elements and the true anomaly ``f``, as a 3-tuple: Basilisk's
    ``orbitalMotion.elem2rv`` term for term (Schaub & Junkins, eq. 9.105)."""
    p = a * (1.0 - e * e)  # semilatus rectum
    r = p / (1.0 + e * math.cos(f))  # the orbit equation
    theta = argp + f  # argument of latitude
    ct, st, cO, sO, ci = math.cos(theta), math.sin(theta), math.cos(raan), math.sin(raan), math.cos(inc)
    return (r * (ct * cO - ci * st * sO), r * (ct * sO + ci * st * cO), r * (st * math.sin(inc)))


@jit
def position_N(prm, t, out):
    """``r_N`` (3,) [m] at time ``t`` [s] of an orbit's parameters ``prm`` (:meth:`~spacecraft_sim.core.orbit.Orbit.params`)."""
    e = prm[O_E]
    f = true_anomaly_of(prm[O_M0] + prm[O_N] * t, e) if e > 0.0 else prm[O_M0] + prm[O_N] * t  # circular: f = M
    r = position_N_of(prm[O_A], e, prm[O_I], prm[O_RAAN], prm[O_ARGP], f)
    out[0] = r[0]
    out[1] = r[1]
    out[2] = r[2]


@jit
def dcm_PN_of(prm, t):
    """``(cos theta, sin theta)`` of ``[PN] = R3(theta)``, ``theta = theta_0 + omega_E t``: v_P =
    ``(c v0 + s v1, -s v0 + c v1, v2)`` (Schaub & Junkins, eq. 3.32)."""
    theta = prm[O_THETA0] + prm[O_OMEGA_E] * t
    return math.cos(theta), math.sin(theta)



@jit
def dipole_field_P_of(fprm, x, y, z):
    """``B_P`` [T] (3-tuple) at ``r_P = (x, y, z)`` [m] of the dipole ``fprm``
    (:meth:`DipoleField.params`): Basilisk ``MagneticFieldCenteredDipole::evaluateMagneticFieldModel``."""
    r = math.sqrt((x * x + y * y) + z * z)
    rx, ry, rz = x / r, y / r, z / r  # r_hat_P
    m0, m1, m2 = fprm[0], fprm[1], fprm[2]
    k = (fprm[3] / r) ** 3  # (R / |r|)^3, Basilisk's pow(planetRadius / orbitRadius, 3)
    d = 3.0 * ((rx * m0 + ry * m1) + rz * m2)  # 3 (r_hat . m)
    return (k * (rx * d - m0), k * (ry * d - m1), k * (rz * d - m2))


@jit
def dipole_field_N(oprm, fprm, t, r_N, out):
    """``B_N`` (3,) [T] at time ``t`` [s] and position ``r_N`` (3,) [m] into ``out``: ``r_P = [PN] r_N``,
    :func:`dipole_field_P_of`, ``B_N = [PN]^T B_P`` (module docstring; ``oprm`` the orbit's
    parameters, :meth:`~spacecraft_sim.core.orbit.Orbit.params`, for the Earth's rotation)."""
    c, s = dcm_PN_of(oprm, t)
    b = dipole_field_P_of(fprm, c * r_N[0] + s * r_N[1], -s * r_N[0] + c * r_N[1], r_N[2])
    out[0] = c * b[0] - s * b[1]
    out[1] = s * b[0] + c * b[1]
    out[2] = b[2]


@jit
def to_body_B(q_BN, B_N, out):
    """``v_B = [BN] v_N`` (3,) of the attitude ``q_BN`` (scalar last) into ``out`` (the field, or
    any vector): the conjugate rotation of :func:`gnc_common.compiled.quat_rotate`
    (``v_B = q^* ⊗ (v_N, 0) ⊗ q``)."""
    o = quat_rotate_of(-q_BN[0], -q_BN[1], -q_BN[2], q_BN[3], B_N[0], B_N[1], B_N[2])
    out[0] = o[0]
    out[1] = o[1]
    out[2] = o[2]

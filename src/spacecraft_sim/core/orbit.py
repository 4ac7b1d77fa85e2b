"""The orbit and the gravity-gradient torque (issue 36): where the spacecraft is, and what the
Earth's gravity does to its attitude.

Frames
------
- **N**: the Earth-centred inertial frame, the equator and equinox of J2000 (Basilisk's ``N`` for an
  Earth orbit, what ``spiceInterface`` calls ``J2000``); the scenario's attitude ``q_BN`` and its
  reference are attitudes relative to this frame.
- **P**: the Earth-fixed frame, turning about ``N``'s z axis at :data:`EARTH_ROTATION_RATE_RAD_S`;
  at time ``t`` its x axis is ``theta(t) = theta_0 + omega_E t`` east of ``N``'s (``theta_0``: the
  Earth rotation angle, or Greenwich sidereal time, at ``t = 0``).  Precession, nutation and polar
  motion are left out: over a 6 h run they move the pole by under 1e-6 rad.  ``[PN] = R3(theta)``
  is what Basilisk's ``SpicePlanetStateMsgPayload.J20002Pfix`` holds.

The orbit is Keplerian, two-body, about a point Earth (no J2, no drag): elements ``a, e, i, Omega,
omega`` fixed and the mean anomaly ``M = M_0 + n t``, ``n = sqrt(mu / a^3)``.  Kepler's equation
``E - e sin E = M`` is solved by Newton's iteration from ``E = M`` (Vallado, Algorithm 2), the true
anomaly ``f = 2 atan2(sqrt(1 + e) sin(E/2), sqrt(1 - e) cos(E/2))`` (Schaub & Junkins, eq. 9.11),
and the position is Basilisk's ``orbitalMotion.elem2rv`` (Schaub & Junkins, eq. 9.105 with
``r = p / (1 + e cos f)``).  ``e = 0`` is the circular orbit (``f = M``).

Gravity gradient (Basilisk ``GravityGradientEffector``; Schaub & Junkins, eq. 4.41): with ``r``
the spacecraft's centre of mass from the Earth's centre, ``r_hat_B`` its direction in B and ``J``
the spacecraft's inertia about its centre of mass in B,

    L_G_B = 3 mu / |r|^3  r_hat_B x (J r_hat_B)          ( = 3 mu / |r|^5  r_B x J r_B )

Pure: no ROS, no clock; the kernels take the time as an argument and allocate nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.ephemeris import (KEPLER_ITERATIONS, N_ORBIT_PARAMS, O_A, O_ARGP, O_E, O_I, O_M0, O_MU, O_N, O_OMEGA_E, O_RAAN, O_THETA0,  # noqa: F401 (the plant's names)
                                 dcm_PN_of, position_N, position_N_of, true_anomaly_of)
from gnc_common.validation import ConfigError

__all__ = ["EARTH_EQUATORIAL_RADIUS_M", "EARTH_ROTATION_RATE_RAD_S", "KEPLER_ITERATIONS", "MU_EARTH_M3_S2", "Orbit", "dcm_PN_of",
           "gravity_gradient_B", "gravity_gradient_B_of", "position_N", "position_N_of", "true_anomaly_of"]

Array = NDArray[np.float64]

#: The Earth's gravitational parameter GM [m^3/s^2]: IERS Conventions (2010), Table 1.1 (the value
#: WGS 84 and EGM2008 use, the atmosphere included).
MU_EARTH_M3_S2 = 3.986004418e14
#: The Earth's equatorial radius [m]: WGS 84 (NIMA TR8350.2, Table 3.1); an orbit's altitude is
#: its radius above it.
EARTH_EQUATORIAL_RADIUS_M = 6378137.0
#: The Earth's rotation rate relative to the stars [rad/s]: IERS Conventions (2010), Table 1.1
#: (the nominal mean angular velocity of WGS 84, 7.292115e-5).
EARTH_ROTATION_RATE_RAD_S = 7.292115e-5
#: The largest eccentricity accepted: beyond it Newton's iteration from ``E = M`` needs a better
#: start (Vallado, Algorithm 2), and a low Earth orbit is nearly circular anyway.
MAX_ECCENTRICITY = 0.9


@dataclass(frozen=True)
class Orbit:
    """A Keplerian orbit about the Earth and the Earth's orientation at ``t = 0`` (module docstring).

    Attributes
    ----------
    altitude_m : float
        ``a - R_E`` with ``R_E`` = :data:`EARTH_EQUATORIAL_RADIUS_M` (a circular orbit's altitude).
    inclination_deg, raan_deg, arg_periapsis_deg, mean_anomaly_deg : float
        ``i``, ``Omega`` (right ascension of the ascending node), ``omega`` and ``M_0`` at ``t = 0``;
        for a circular orbit ``omega + M_0`` is the argument of latitude (the phase).
    eccentricity : float
        ``e`` in [0, :data:`MAX_ECCENTRICITY`] (0: circular).
    earth_rotation_angle_deg : float
        ``theta_0``, the angle of P's x axis (Greenwich) east of N's at ``t = 0``.
    """

    altitude_m: float = 500e3
    inclination_deg: float = 97.4
    raan_deg: float = 0.0
    eccentricity: float = 0.0
    arg_periapsis_deg: float = 0.0
    mean_anomaly_deg: float = 0.0
    earth_rotation_angle_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("altitude_m", "inclination_deg", "raan_deg", "eccentricity", "arg_periapsis_deg", "mean_anomaly_deg",
                     "earth_rotation_angle_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if not 0.0 <= self.eccentricity <= MAX_ECCENTRICITY:
            raise ConfigError(f"eccentricity must be in [0, {MAX_ECCENTRICITY}], got {self.eccentricity!r}")
        perigee = self.semi_major_axis_m * (1.0 - self.eccentricity)
        if perigee <= EARTH_EQUATORIAL_RADIUS_M:
            raise ConfigError(f"altitude_m = {self.altitude_m!r} with eccentricity = {self.eccentricity!r} puts the perigee "
                              f"{perigee - EARTH_EQUATORIAL_RADIUS_M:.6g} m below the Earth's equatorial radius")
        if not 0.0 <= self.inclination_deg <= 180.0:
            raise ConfigError(f"inclination_deg must be in [0, 180], got {self.inclination_deg!r}")

    @property
    def semi_major_axis_m(self) -> float:
        return EARTH_EQUATORIAL_RADIUS_M + float(self.altitude_m)

    @property
    def mean_motion_rad_s(self) -> float:
        """``n = sqrt(mu / a^3)``."""
        return math.sqrt(MU_EARTH_M3_S2 / self.semi_major_axis_m ** 3)

    @property
    def period_s(self) -> float:
        """``2 pi / n``."""
        return 2.0 * math.pi / self.mean_motion_rad_s

    def params(self) -> Array:
        """The kernels' parameters (:data:`N_ORBIT_PARAMS`,): ``a, e, i, Omega, omega, M_0, n, mu,
        theta_0, omega_E`` (angles in rad)."""
        d = math.radians
        return np.array([self.semi_major_axis_m, float(self.eccentricity), d(self.inclination_deg), d(self.raan_deg),
                         d(self.arg_periapsis_deg), d(self.mean_anomaly_deg), self.mean_motion_rad_s, MU_EARTH_M3_S2,
                         d(self.earth_rotation_angle_deg), EARTH_ROTATION_RATE_RAD_S], dtype=np.float64)




@jit
def gravity_gradient_B_of(mu, J, r0, r1, r2):
    """``L_G_B`` [N m] (3-tuple) of the Earth's ``mu`` [m^3/s^2] on a body of inertia ``J`` (3, 3)
    [kg m^2] about its centre of mass, at ``r_B = (r0, r1, r2)`` [m] from the Earth's centre in B
    components: Basilisk ``GravityGradientEffector::computeForceTorque`` (module docstring)."""
    r = math.sqrt((r0 * r0 + r1 * r1) + r2 * r2)
    x, y, z = r0 / r, r1 / r, r2 / r  # r_hat_B
    k = 3.0 * mu / r / r / r  # the effector's 3 mu / rMag / rMag / rMag
    j0 = k * ((J[0, 0] * x + J[0, 1] * y) + J[0, 2] * z)
    j1 = k * ((J[1, 0] * x + J[1, 1] * y) + J[1, 2] * z)
    j2 = k * ((J[2, 0] * x + J[2, 1] * y) + J[2, 2] * z)
    return (y * j2 - z * j1, z * j0 - x * j2, x * j1 - y * j0)  # r_hat_B x (k J r_hat_B)


@jit
def gravity_gradient_B(mu, J, r_B, out):
    """:func:`gravity_gradient_B_of` of ``r_B`` (3,) into ``out`` (3,)."""
    o = gravity_gradient_B_of(mu, J, r_B[0], r_B[1], r_B[2])
    out[0] = o[0]
    out[1] = o[1]
    out[2] = o[2]

"""The Earth's magnetic field as a centred, tilted dipole (issue 36): Basilisk's
``magneticFieldCenteredDipole`` model.

With ``R`` the reference radius, ``r_P`` the spacecraft's position in the Earth-fixed frame P
(:mod:`spacecraft_sim.core.orbit`), ``r_hat_P = r_P / |r_P|`` and ``m = (g_1^1, h_1^1, g_1^0)`` the
first three IGRF Gauss coefficients [T] (Markley & Crassidis, eq. 3.171 to 3.173; Basilisk cites
p. 405 of the same book, doi:10.1007/978-1-4939-0802-8):

    B_P = (R / |r|)^3 (3 r_hat_P (r_hat_P . m) - m)           [T]
    B_N = [PN]^T B_P                                           (the module's m33tMultV3)
    B_B = [BN] B_N                                             (the attitude q_BN)

Defaults: the coefficients and the radius Basilisk's ``simSetPlanetEnvironment.centeredDipoleMagField
(module, "earth")`` sets, which its source calls "the 2020 IGRF model": ``g_1^0 = -30926 nT``,
``g_1^1 = -2318 nT``, ``h_1^1 = 5817 nT``, ``R = 6371.2 km``.  Those three numbers are the IGRF's
coefficients of epoch **1925.0**, not 2020.0 (IGRF-13, 2020.0: -29404.8, -1450.9, 4652.5 nT; the
dipole 5.5 % weaker and tilted 9.4 deg instead of 11.4 deg from the pole): the defaults keep
Basilisk's numbers so that the two simulators fly the same field, and a scenario states the
epoch it wants (``orbit.magnetic_field``; docs/how-to/momentum.md).

Pure: no ROS, no clock; the kernels allocate nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError
from gnc_common.ephemeris import dipole_field_N, dipole_field_P_of, to_body_B  # noqa: F401 (the plant's names)

__all__ = ["BASILISK_EARTH_DIPOLE", "IGRF13_2020_DIPOLE", "DipoleField", "dipole_field_N", "dipole_field_P_of", "to_body_B"]

Array = NDArray[np.float64]

#: Nanotesla per tesla.
_NT_PER_T = 1e9


@dataclass(frozen=True)
class DipoleField:
    """A centred dipole (module docstring).

    Attributes
    ----------
    g10_nT, g11_nT, h11_nT : float
        The IGRF coefficients ``g_1^0``, ``g_1^1``, ``h_1^1`` [nT].
    reference_radius_m : float
        ``R`` [m] (the IGRF's 6371.2 km).
    epoch : str
        What the coefficients are (documentation only: the model has no secular variation).
    """

    g10_nT: float = -30926.0
    g11_nT: float = -2318.0
    h11_nT: float = 5817.0
    reference_radius_m: float = 6371.2e3
    epoch: str = "Basilisk's default (IGRF 1925.0 coefficients, labelled 2020 in Basilisk)"

    def __post_init__(self) -> None:
        for name in ("g10_nT", "g11_nT", "h11_nT", "reference_radius_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if not self.reference_radius_m > 0.0:
            raise ConfigError(f"reference_radius_m must be > 0, got {self.reference_radius_m!r}")
        if self.g10_nT == 0.0 and self.g11_nT == 0.0 and self.h11_nT == 0.0:
            raise ConfigError("g10_nT, g11_nT and h11_nT are all zero: no field (magnetorquers would do nothing)")

    def params(self) -> Array:
        """The kernels' parameters (4,): ``g_1^1, h_1^1, g_1^0`` [T] (Basilisk's ``dipoleCoefficients``
        order) and ``R`` [m]."""
        return np.array([self.g11_nT / _NT_PER_T, self.h11_nT / _NT_PER_T, self.g10_nT / _NT_PER_T, float(self.reference_radius_m)],
                        dtype=np.float64)


#: Basilisk's Earth dipole (module docstring).
BASILISK_EARTH_DIPOLE = DipoleField()
#: IGRF-13 at epoch 2020.0 (Alken et al. 2021, Earth Planets Space 73:49, Table 2).
IGRF13_2020_DIPOLE = DipoleField(g10_nT=-29404.8, g11_nT=-1450.9, h11_nT=4652.5, epoch="IGRF-13, 2020.0")

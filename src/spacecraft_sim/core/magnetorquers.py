"""Magnetorquers (torque rods): the actuator that trades torque with the Earth's field (issue 36);
Basilisk's ``MtbEffector``.

``M`` rods, rod ``j`` along the unit axis ``t_j`` (in B) with the dipole limit ``m_max,j``; with
``G_t = [t_1 .. t_M]`` (3, M) and the commanded dipoles ``m_cmd`` (M,) [A m^2], the plant applies
(Basilisk ``MtbEffector::computeForceTorque``; Markley & Crassidis, eq. 3.159)

    m_j = min(max(m_cmd,j, -m_max,j), m_max,j)        (each rod saturated)
    L_mtb_B = (G_t m) x B_B = -[B_B x] G_t m          [N m]

with ``B_B`` the true field in B (:mod:`spacecraft_sim.core.magnetic_field`).  The rods have no
dynamics (their current follows the command within a control period) and no residual dipole.

Pure: no ROS, no clock; the kernel allocates nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.validation import ConfigError, from_mapping
from spacecraft_sim.core.wheels import allocation_matrix

__all__ = ["ROD_PRESETS", "Magnetorquers", "magnetorquers_from_mapping", "mtb_torque_B", "saturate_dipoles"]

Array = NDArray[np.float64]

#: Rod layouts by name: three rods along the body axes (the usual set).
ROD_PRESETS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "orthogonal": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
}


@dataclass(frozen=True)
class Magnetorquers:
    """A rod set (module docstring).

    Attributes
    ----------
    axes_B : str or sequence of 3-vectors
        A preset name (:data:`ROD_PRESETS`) or one axis per rod, in B (normalised; they must span 3-D).
    max_dipole_Am2 : float or sequence
        ``m_max`` of each rod [A m^2] (one number for every rod, or one per rod).
    """

    axes_B: str | tuple[tuple[float, float, float], ...] = "orthogonal"
    max_dipole_Am2: float | tuple[float, ...] = 0.0
    Gt: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        axes = ROD_PRESETS.get(self.axes_B) if isinstance(self.axes_B, str) else self.axes_B
        if axes is None:
            raise ConfigError(f"axes_B must be one of {', '.join(ROD_PRESETS)} or a list of 3-vectors, got {self.axes_B!r}")
        a = np.asarray(axes, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3 or not np.all(np.isfinite(a)):
            raise ConfigError(f"axes_B must be 3 or more finite 3-vectors, got {axes!r}")
        norms = np.sqrt((a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1]) + a[:, 2] * a[:, 2])
        if np.any(norms < 1e-9):
            raise ConfigError(f"axes_B has a zero axis: {axes!r}")
        Gt = (a / norms[:, None]).T  # (3, M)
        if np.linalg.matrix_rank(Gt, tol=1e-9) < 3:
            raise ConfigError(f"axes_B must span three dimensions (a dipole along every axis), got {axes!r}")
        object.__setattr__(self, "Gt", np.ascontiguousarray(Gt))
        m = self.max_dipoles()
        if m.shape != (self.n,) or not np.all(np.isfinite(m)) or not np.all(m > 0):
            raise ConfigError(f"max_dipole_Am2 must be one number > 0 or {self.n} (one per rod), got {self.max_dipole_Am2!r}")

    @property
    def n(self) -> int:
        return int(self.Gt.shape[1])

    def max_dipoles(self) -> Array:
        """``m_max`` (M,) [A m^2]."""
        v = np.asarray(self.max_dipole_Am2, dtype=np.float64)
        return np.full(self.Gt.shape[1], float(v)) if v.ndim == 0 else v.copy()

    def steering_matrix(self) -> Array:
        """``G_t^+ = G_t^T (G_t G_t^T)^-1`` (M, 3): the minimum-norm map from a body dipole to the rods'
        dipoles (Basilisk ``dipoleMapping.steeringMatrix``, which its examples set to ``pinv(G_t)``;
        for three orthogonal rods ``G_t^T``)."""
        return allocation_matrix(self.Gt)  # the wheels' written-out pseudo-inverse (docs/parity.md)


def magnetorquers_from_mapping(data: Any, prefix: str) -> Magnetorquers:
    """A rod set from a parsed mapping (a scenario's ``magnetorquers``), strictly; errors name
    ``<prefix>.<key>``."""
    if isinstance(data, dict) and isinstance(data.get("axes_B"), list):
        data = {**data, "axes_B": tuple(tuple(a) if isinstance(a, list) else a for a in data["axes_B"])}
    try:
        rods: Magnetorquers = from_mapping(Magnetorquers, data, prefix)
    except ConfigError as exc:
        msg = str(exc)
        if msg.startswith(f"{prefix}: "):
            msg = f"{prefix}.{msg[len(prefix) + 2:]}"
        raise ConfigError(msg) from None
    return rods


@jit
def saturate_dipoles(m_max, m_cmd, out):
    """``out_j = min(max(m_cmd,j, -m_max,j), m_max,j)`` (M,): Basilisk ``MtbEffector``'s and
    ``dipoleMapping``'s per-rod saturation."""
    for j in range(out.shape[0]):
        out[j] = min(max(m_cmd[j], -m_max[j]), m_max[j])


@jit
def mtb_torque_B(Gt, m_max, m_cmd, B_B, out):
    """``L_mtb_B = (G_t sat(m_cmd)) x B_B`` (3,) [N m] into ``out`` (module docstring): ``Gt`` (3, M),
    ``m_max`` and ``m_cmd`` (M,) [A m^2], ``B_B`` (3,) [T]."""
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for j in range(m_cmd.shape[0]):
        m = min(max(m_cmd[j], -m_max[j]), m_max[j])
        m0 += Gt[0, j] * m
        m1 += Gt[1, j] * m
        m2 += Gt[2, j] * m
    out[0] = m1 * B_B[2] - m2 * B_B[1]
    out[1] = m2 * B_B[0] - m0 * B_B[2]
    out[2] = m0 * B_B[1] - m1 * B_B[0]

"""Reaction wheels: the actuator of a flight-like plant (issue 16, first part: the model).

A rigid body B with ``N`` wheels, wheel ``i`` spinning about the unit axis ``g_i`` (in B) with
spin inertia ``Js_i``.  **Convention: the scenario's inertia ``J`` is what the body presents to
a torque**, the spacecraft's inertia with the wheels locked minus their spin inertia
(``J = J_locked - sum Js_i g_i g_i^T``), so that with wheels at rest an ideal wheel set behaves as
the ideal actuator does to first order.  (Basilisk's hub inertia is then ``J`` minus the wheels'
transverse inertia; the issue's feasibility check set it to ``J + sum Js g g^T`` for the same
effect in its own convention.)

State: ``x = (q_BN, omega_BN_B, h)`` (7 + N), with ``h_i = Js_i (g_i . omega + Omega_i)`` the
wheel's spin angular momentum about its axis (``Omega_i``: its speed relative to the body, what a
tachometer reads and what the speed limit applies to).  With ``G = [g_1 .. g_N]`` (3, N), ``u``
the motor torques on the wheels and ``f`` their bearing friction (opposing ``Omega``):

    dh/dt = u - f(Omega)
    J domega/dt = L_ext - G (u - f) - omega x (J omega + G h)
    dq/dt = 1/2 q ⊗ (omega, 0)

so the total angular momentum ``H = J omega + G h`` (in B) obeys ``dH/dt + omega x H = L_ext``:
without an external torque it is constant in the inertial frame whatever the motors and the
friction do (tested).  Friction ``f_i = c_i sat(Omega_i / Omega_c) + b_i Omega_i``: Coulomb with
a linear region of half-width :attr:`ReactionWheels.coulomb_speed_rad_s` around zero speed (a
discontinuous sign would make a fixed-step integrator chatter), plus viscous.

The torque path (:func:`wheel_torques`), once per sample (zero-order hold, as the plant holds a
command): the commanded body torque ``tau`` is allocated by the minimum-norm inverse,
``u = -G^+ tau`` (``G^+ = G^T (G G^T)^-1``: the body receives ``-G u = tau``), then each motor is
clipped to its torque limit, and a wheel at its speed limit gets no torque that would speed it up
further.  What the wheels could not deliver is ``tau + G u``.

Pure: no ROS, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.compiled import inverse3, jit, matvec3, quat_normalize
from gnc_common.validation import ConfigError, check_spd_inertia, from_mapping

__all__ = ["PRESETS", "ActuatorArrays", "ReactionWheels", "pack_actuator", "allocation_matrix", "angular_momentum_B", "propagate_wheels", "propagate_wheels_into", "wheel_speeds", "wheel_speeds_into",
           "wheel_torques", "wheels_from_mapping"]

Array = NDArray[np.float64]

#: Cant angle of the four-wheel pyramid [deg]: each axis 54.74 deg from the z axis
#: (arctan(sqrt(2))), the angle at which the pyramid's torque envelope is the same about x, y and z.
PYRAMID_CANT_DEG = math.degrees(math.atan(math.sqrt(2.0)))


def _pyramid() -> tuple[tuple[float, float, float], ...]:
    s, c = math.sin(math.radians(PYRAMID_CANT_DEG)), math.cos(math.radians(PYRAMID_CANT_DEG))
    return tuple((s * math.cos(a), s * math.sin(a), c) for a in (math.pi / 4, 3 * math.pi / 4, 5 * math.pi / 4, 7 * math.pi / 4))


#: Spin-axis layouts by name: three orthogonal wheels along the body axes, and the four-wheel
#: pyramid (axes at :data:`PYRAMID_CANT_DEG` from z, 90 deg apart in azimuth, starting at 45 deg).
PRESETS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "orthogonal": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "pyramid": _pyramid(),
}


@dataclass(frozen=True)
class ReactionWheels:
    """A wheel set (module docstring).  Per-wheel values are one number for every wheel or one
    per wheel.

    Attributes
    ----------
    spin_axes_B : str or sequence of 3-vectors
        A preset name (:data:`PRESETS`) or one axis per wheel, in B (normalised; they must span 3-D).
    spin_inertia_kg_m2 : float or sequence
        ``Js`` of each wheel about its axis.
    max_torque_Nm : float or sequence
        Motor torque limit of each wheel.
    max_speed_rad_s : float or sequence
        Speed limit of each wheel relative to the body: a wheel at it gets no torque that would speed it up.
    coulomb_friction_Nm, viscous_friction_Nm_s : float or sequence
        Bearing friction ``c sat(Omega / Omega_c) + b Omega`` (0: none).
    coulomb_speed_rad_s : float
        ``Omega_c``, the half-width of Coulomb friction's linear region around zero speed.
    initial_speed_rad_s : float or sequence
        ``Omega`` at the start, relative to the body.
    """

    spin_axes_B: str | tuple[tuple[float, float, float], ...] = "pyramid"
    spin_inertia_kg_m2: float | tuple[float, ...] = 0.0
    max_torque_Nm: float | tuple[float, ...] = 0.0
    max_speed_rad_s: float | tuple[float, ...] = 0.0
    coulomb_friction_Nm: float | tuple[float, ...] = 0.0
    viscous_friction_Nm_s: float | tuple[float, ...] = 0.0
    coulomb_speed_rad_s: float = 0.1
    initial_speed_rad_s: float | tuple[float, ...] = 0.0
    G: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        axes = PRESETS.get(self.spin_axes_B) if isinstance(self.spin_axes_B, str) else self.spin_axes_B
        if axes is None:
            raise ConfigError(f"spin_axes_B must be one of {', '.join(PRESETS)} or a list of 3-vectors, got {self.spin_axes_B!r}")
        a = np.asarray(axes, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3 or not np.all(np.isfinite(a)):
            raise ConfigError(f"spin_axes_B must be 3 or more finite 3-vectors, got {axes!r}")
        norms = np.sqrt((a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1]) + a[:, 2] * a[:, 2])  # written out (docs/parity.md)
        if np.any(norms < 1e-9):
            raise ConfigError(f"spin_axes_B has a zero axis: {axes!r}")
        G = (a / norms[:, None]).T  # (3, N)
        if np.linalg.matrix_rank(G, tol=1e-9) < 3:
            raise ConfigError(f"spin_axes_B must span three dimensions (a torque about every axis), got {axes!r}")
        object.__setattr__(self, "G", np.ascontiguousarray(G))  # one array layout for the kernels
        n = G.shape[1]
        for name, positive in (("spin_inertia_kg_m2", True), ("max_torque_Nm", True), ("max_speed_rad_s", True),
                               ("coulomb_friction_Nm", False), ("viscous_friction_Nm_s", False), ("initial_speed_rad_s", None)):
            v = self.per_wheel(name)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ConfigError(f"{name} must be one finite number or {n} (one per wheel), got {getattr(self, name)!r}")
            if positive is True and not np.all(v > 0):
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)!r}")
            if positive is False and not np.all(v >= 0):
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not (math.isfinite(self.coulomb_speed_rad_s) and self.coulomb_speed_rad_s > 0):
            raise ConfigError(f"coulomb_speed_rad_s must be > 0, got {self.coulomb_speed_rad_s!r}")
        if np.any(np.abs(self.per_wheel("initial_speed_rad_s")) > self.per_wheel("max_speed_rad_s")):
            raise ConfigError("initial_speed_rad_s must be within max_speed_rad_s")

    @property
    def n(self) -> int:
        return int(self.G.shape[1])

    def per_wheel(self, name: str) -> Array:
        """A per-wheel attribute as an (N,) array (one number broadcast to every wheel)."""
        v = np.asarray(getattr(self, name), dtype=np.float64)
        n = self.G.shape[1]
        return np.full(n, float(v)) if v.ndim == 0 else v.copy()

    def params(self) -> Array:
        """The kernels' per-wheel parameters (N, 6): ``Js, u_max, Omega_max, c, b, Omega_c``."""
        cols = [self.per_wheel(k) for k in ("spin_inertia_kg_m2", "max_torque_Nm", "max_speed_rad_s", "coulomb_friction_Nm", "viscous_friction_Nm_s")]
        return np.ascontiguousarray(np.stack([*cols, np.full(self.n, self.coulomb_speed_rad_s)], axis=1))

    def initial_momentum(self, omega_BN_B: ArrayLike) -> Array:
        """``h`` (N,) of wheels at their initial speeds on a body turning at ``omega_BN_B``."""
        w = np.asarray(omega_BN_B, dtype=np.float64)
        G = self.G
        g_dot_w = (G[0] * w[0] + G[1] * w[1]) + G[2] * w[2]  # G^T omega, written out (docs/parity.md)
        out: Array = self.per_wheel("spin_inertia_kg_m2") * (g_dot_w + self.per_wheel("initial_speed_rad_s"))
        return out


def wheels_from_mapping(data: Any, prefix: str) -> ReactionWheels:
    """A wheel set from a parsed mapping (a scenario's ``actuator.wheels``, the plant node's
    ``wheels`` parameter), strictly; every error names ``<prefix>.<key>``."""
    if isinstance(data, dict) and isinstance(data.get("spin_axes_B"), list):
        data = {**data, "spin_axes_B": [tuple(a) if isinstance(a, list) else a for a in data["spin_axes_B"]]}
    try:
        wheels: ReactionWheels = from_mapping(ReactionWheels, data, prefix)
    except ConfigError as exc:  # the model's own checks name the bare key: name it in full
        msg = str(exc)
        if msg.startswith(f"{prefix}: "):
            msg = f"{prefix}.{msg[len(prefix) + 2:]}"
        raise ConfigError(msg) from None
    return wheels


@jit
def _allocation_into(G, GGt, GGt_inv, out):
    n = G.shape[1]
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for i in range(n):
                acc += G[r, i] * G[c, i]
            GGt[r, c] = acc
    inverse3(GGt, GGt_inv)
    for i in range(n):
        for c in range(3):
            out[i, c] = (G[0, i] * GGt_inv[0, c] + G[1, i] * GGt_inv[1, c]) + G[2, i] * GGt_inv[2, c]


def allocation_matrix(G: ArrayLike) -> Array:
    """The minimum-norm allocation ``G^+ = G^T (G G^T)^-1`` (N, 3) of spin axes ``G`` (3, N).

    Sums written out in a fixed order and the 3 x 3 inverse by its adjugate
    (:func:`gnc_common.compiled.inverse3`): no BLAS/LAPACK call, whose kernels (chosen by the CPU
    at run time) give other last bits on another host (docs/parity.md)."""
    Ga = np.ascontiguousarray(G, dtype=np.float64)
    out: Array = np.empty((Ga.shape[1], 3))
    _allocation_into(Ga, np.empty((3, 3)), np.empty((3, 3)), out)
    return out


# Columns of the kernels' per-wheel parameters (ReactionWheels.params).
_JS, _UMAX, _WMAX, _COUL, _VISC, _WC = 0, 1, 2, 3, 4, 5


@jit(inline="always")
def _speed(h, g0, g1, g2, Js, w0, w1, w2):
    """``Omega`` of a wheel: ``h / Js - g . omega``."""
    return h / Js - ((g0 * w0 + g1 * w1) + g2 * w2)


@jit
def wheel_torques(tau_cmd_B, G_pinv, G, prm, x, u_out):
    """The motor torques ``u_out`` (N,) for the commanded body torque ``tau_cmd_B`` (3,) at state
    ``x`` (7 + N): ``-G^+ tau``, clipped to each motor's limit, and zero for a wheel at its speed
    limit that it would speed up (module docstring)."""
    w0, w1, w2 = x[4], x[5], x[6]
    for i in range(u_out.shape[0]):
        u = -((G_pinv[i, 0] * tau_cmd_B[0] + G_pinv[i, 1] * tau_cmd_B[1]) + G_pinv[i, 2] * tau_cmd_B[2])
        umax = prm[i, _UMAX]
        u = min(max(u, -umax), umax)
        Om = _speed(x[7 + i], G[0, i], G[1, i], G[2, i], prm[i, _JS], w0, w1, w2)
        if (Om >= prm[i, _WMAX] and u > 0.0) or (Om <= -prm[i, _WMAX] and u < 0.0):
            u = 0.0
        u_out[i] = u


@jit(inline="always")
def _q_dot_of(x0, x1, x2, q0, w0, w1, w2):
    """``dq/dt = 1/2 q ⊗ (omega, 0)`` of ``q = (x0, x1, x2, q0)`` (scalar last), a 4-tuple."""
    c0 = x1 * w2 - x2 * w1
    c1 = x2 * w0 - x0 * w2
    c2 = x0 * w1 - x1 * w0
    return 0.5 * (q0 * w0 + c0), 0.5 * (q0 * w1 + c1), 0.5 * (q0 * w2 + c2), -0.5 * ((x0 * w0 + x1 * w1) + x2 * w2)


@jit(inline="always")
def _h_dot_of(h, g0, g1, g2, Js, coulomb, speed_c, viscous, u, w0, w1, w2):
    """``dh/dt = u - f(Omega)`` of one wheel (module docstring's friction)."""
    Om = _speed(h, g0, g1, g2, Js, w0, w1, w2)
    f = coulomb * min(max(Om / speed_c, -1.0), 1.0) + viscous * Om
    return u - f


@jit(inline="always")
def _rate_rhs_of(L0, L1, L2, n0, n1, n2, H0, H1, H2, w0, w1, w2):
    """``L_ext - G (u - f) - omega x H`` (``J domega/dt``), with ``n = G (u - f)``, a 3-tuple."""
    return L0 - n0 - (w1 * H2 - w2 * H1), L1 - n1 - (w2 * H0 - w0 * H2), L2 - n2 - (w0 * H1 - w1 * H0)


@jit(inline="always")
def _derivative(x, u, L, J, J_inv, G, prm, out, tmp):
    """``dx/dt`` (7 + N) of the body with wheels (module docstring); ``tmp`` (3, 3) scratch."""
    n = u.shape[0]
    w0, w1, w2 = x[4], x[5], x[6]
    out[0], out[1], out[2], out[3] = _q_dot_of(x[0], x[1], x[2], x[3], w0, w1, w2)
    H = tmp[0]
    matvec3(J, x[4:7], H)  # J omega + G h, and the net wheel torque G (u - f) on the body
    net = tmp[1]
    net[0] = 0.0
    net[1] = 0.0
    net[2] = 0.0
    for i in range(n):
        hdot = _h_dot_of(x[7 + i], G[0, i], G[1, i], G[2, i], prm[i, _JS], prm[i, _COUL], prm[i, _WC], prm[i, _VISC], u[i], w0, w1, w2)
        out[7 + i] = hdot
        for k in range(3):
            H[k] += G[k, i] * x[7 + i]
            net[k] += G[k, i] * hdot
    rhs = tmp[2]
    rhs[0], rhs[1], rhs[2] = _rate_rhs_of(L[0], L[1], L[2], net[0], net[1], net[2], H[0], H[1], H[2], w0, w1, w2)
    matvec3(J_inv, rhs, out[4:7])


@jit(inline="always")
def _rk4_sum_of(x, c, k1, k2, k3, k4):
    """RK4's step of one state: ``x + c ((k1 + 2 (k2 + k3)) + k4)`` with ``c = h / 6``."""
    return x + c * ((k1 + 2.0 * (k2 + k3)) + k4)


@jit
def propagate_wheels_into(x, u, L, dt, substeps, J, J_inv, G, prm, work, tmp):
    """Advance ``x`` (7 + N) in place by ``dt`` in ``substeps`` RK4 steps with the motor torques
    ``u`` (N,) and the external torque ``L`` (3,) held (zero-order hold); ``q`` renormalised
    after each step, as the rigid body's :func:`~spacecraft_sim.core.kernels.rk4_step`.
    Scratch: ``work`` (5, 7 + N), ``tmp`` (3, 3) (the compiled loop reuses them every step)."""
    m = x.shape[0]
    k1, k2, k3, k4, xs = work[0], work[1], work[2], work[3], work[4]
    h = dt / substeps
    for _ in range(substeps):
        _derivative(x, u, L, J, J_inv, G, prm, k1, tmp)
        for i in range(m):
            xs[i] = x[i] + 0.5 * h * k1[i]
        _derivative(xs, u, L, J, J_inv, G, prm, k2, tmp)
        for i in range(m):
            xs[i] = x[i] + 0.5 * h * k2[i]
        _derivative(xs, u, L, J, J_inv, G, prm, k3, tmp)
        for i in range(m):
            xs[i] = x[i] + h * k3[i]
        _derivative(xs, u, L, J, J_inv, G, prm, k4, tmp)
        c = h / 6.0
        for i in range(m):
            x[i] = _rk4_sum_of(x[i], c, k1[i], k2[i], k3[i], k4[i])
        quat_normalize(x[:4], x[:4])


#: The most wheels :func:`propagate_wheels_lanes` takes (its rows are laid out for this many:
#: constant offsets, which let LLVM vectorise its lane loops; a batch with more runs per run).
MAX_LANE_WHEELS = 8
_LANE_M = 7 + MAX_LANE_WHEELS
#: Rows of :func:`propagate_wheels_lanes`' array (rows, W), one run a column: the state ``x``,
#: the motor torques ``u`` and the external torque ``L`` (the caller's, every step), ``J`` and
#: ``J^-1`` row major and the wheels' constants (:func:`wheel_lane_params`, once a block), then
#: scratch (the RK4 stage state, its four slopes, ``J omega + G h`` and ``G (u - f)``).
LANE_X, LANE_U, LANE_L, LANE_J, LANE_J_INV = 0, _LANE_M, _LANE_M + MAX_LANE_WHEELS, _LANE_M + MAX_LANE_WHEELS + 3, _LANE_M + MAX_LANE_WHEELS + 12
#: Rows of one wheel among the constants: its axis g (3), Js, the Coulomb friction, the Coulomb
#: speed and the viscous friction.
_WHEEL_ROWS = 7
_LANE_WP = LANE_J_INV + 9
_LANE_XS = _LANE_WP + _WHEEL_ROWS * MAX_LANE_WHEELS
_LANE_K = _LANE_XS + _LANE_M  # k1 .. k4, _LANE_M rows each
_LANE_HN = _LANE_K + 4 * _LANE_M
N_WHEEL_LANE_ROWS = _LANE_HN + 6


@jit(inline="always")
def wheel_lane_params(J, J_inv, G, prm, F, w):
    """Lane ``w``'s constants into its column of ``F`` (:data:`N_WHEEL_LANE_ROWS`, W)
    (:func:`propagate_wheels_lanes`): the inertia ``J`` and its inverse (3, 3), the wheels' axes
    ``G`` (3, N) and parameters; once a block."""
    for i in range(3):
        for j in range(3):
            F[LANE_J + 3 * i + j, w] = J[i, j]
            F[LANE_J_INV + 3 * i + j, w] = J_inv[i, j]
    for i in range(G.shape[1]):
        b = _LANE_WP + _WHEEL_ROWS * i
        F[b, w], F[b + 1, w], F[b + 2, w] = G[0, i], G[1, i], G[2, i]
        F[b + 3, w], F[b + 4, w], F[b + 5, w], F[b + 6, w] = prm[i, _JS], prm[i, _COUL], prm[i, _WC], prm[i, _VISC]


@jit(inline="always")
def _derivative_lanes(F, x0, out, n, nl):
    """:func:`_derivative` of the state at rows ``x0 ..`` of ``F`` (:data:`N_WHEEL_LANE_ROWS`, W)
    into rows ``out ..``, lanes ``0 .. nl - 1``, ``n`` wheels: each lane's sums in
    :func:`_derivative`'s order, so its bits; the lane loops innermost, so that they vectorise."""
    hn = _LANE_HN
    for w in range(nl):
        w0, w1, w2 = F[x0 + 4, w], F[x0 + 5, w], F[x0 + 6, w]
        F[out, w], F[out + 1, w], F[out + 2, w], F[out + 3, w] = _q_dot_of(F[x0, w], F[x0 + 1, w], F[x0 + 2, w], F[x0 + 3, w], w0, w1, w2)
        F[hn, w] = (F[LANE_J, w] * w0 + F[LANE_J + 1, w] * w1) + F[LANE_J + 2, w] * w2  # matvec3's sums
        F[hn + 1, w] = (F[LANE_J + 3, w] * w0 + F[LANE_J + 4, w] * w1) + F[LANE_J + 5, w] * w2
        F[hn + 2, w] = (F[LANE_J + 6, w] * w0 + F[LANE_J + 7, w] * w1) + F[LANE_J + 8, w] * w2
        F[hn + 3, w] = 0.0
        F[hn + 4, w] = 0.0
        F[hn + 5, w] = 0.0
    for i in range(n):
        b = _LANE_WP + _WHEEL_ROWS * i
        for w in range(nl):
            h = F[x0 + 7 + i, w]
            g0, g1, g2 = F[b, w], F[b + 1, w], F[b + 2, w]
            hdot = _h_dot_of(h, g0, g1, g2, F[b + 3, w], F[b + 4, w], F[b + 5, w], F[b + 6, w], F[LANE_U + i, w], F[x0 + 4, w], F[x0 + 5, w],
                             F[x0 + 6, w])
            F[out + 7 + i, w] = hdot
            F[hn, w] += g0 * h  # (written out: a loop here would be the innermost, not the lanes')
            F[hn + 1, w] += g1 * h
            F[hn + 2, w] += g2 * h
            F[hn + 3, w] += g0 * hdot
            F[hn + 4, w] += g1 * hdot
            F[hn + 5, w] += g2 * hdot
    for w in range(nl):
        r0, r1, r2 = _rate_rhs_of(F[LANE_L, w], F[LANE_L + 1, w], F[LANE_L + 2, w], F[hn + 3, w], F[hn + 4, w], F[hn + 5, w], F[hn, w], F[hn + 1, w],
                                  F[hn + 2, w], F[x0 + 4, w], F[x0 + 5, w], F[x0 + 6, w])
        F[out + 4, w] = (F[LANE_J_INV, w] * r0 + F[LANE_J_INV + 1, w] * r1) + F[LANE_J_INV + 2, w] * r2
        F[out + 5, w] = (F[LANE_J_INV + 3, w] * r0 + F[LANE_J_INV + 4, w] * r1) + F[LANE_J_INV + 5, w] * r2
        F[out + 6, w] = (F[LANE_J_INV + 6, w] * r0 + F[LANE_J_INV + 7, w] * r1) + F[LANE_J_INV + 8, w] * r2


@jit(inline="always")
def propagate_wheels_lanes(F, n, dt, substeps, nl):
    """:func:`propagate_wheels_into` of lanes ``0 .. nl - 1`` with ``n`` (at most
    :data:`MAX_LANE_WHEELS`) wheels (the SIMD lanes' flight stack), on the rows of ``F``
    (:data:`N_WHEEL_LANE_ROWS`, W): the state at :data:`LANE_X` (7 + n rows) advanced in place,
    the motor torques at :data:`LANE_U` and the external torque at :data:`LANE_L` held, the
    constants of :func:`wheel_lane_params`; each lane's bits those of
    :func:`propagate_wheels_into` (the same pieces in the same order, no libm).  One array, the
    rows at constant offsets: LLVM vectorises the lane loops (separate arrays it would have to
    check against each other for overlap)."""
    m = 7 + n
    xs, k1, k2, k3, k4 = _LANE_XS, _LANE_K, _LANE_K + _LANE_M, _LANE_K + 2 * _LANE_M, _LANE_K + 3 * _LANE_M
    h = dt / substeps
    a = 0.5 * h
    for _ in range(substeps):
        _derivative_lanes(F, LANE_X, k1, n, nl)
        for i in range(m):
            for w in range(nl):
                F[xs + i, w] = F[LANE_X + i, w] + a * F[k1 + i, w]
        _derivative_lanes(F, xs, k2, n, nl)
        for i in range(m):
            for w in range(nl):
                F[xs + i, w] = F[LANE_X + i, w] + a * F[k2 + i, w]
        _derivative_lanes(F, xs, k3, n, nl)
        for i in range(m):
            for w in range(nl):
                F[xs + i, w] = F[LANE_X + i, w] + h * F[k3 + i, w]
        _derivative_lanes(F, xs, k4, n, nl)
        c = h / 6.0
        for i in range(m):
            for w in range(nl):
                F[LANE_X + i, w] = _rk4_sum_of(F[LANE_X + i, w], c, F[k1 + i, w], F[k2 + i, w], F[k3 + i, w], F[k4 + i, w])
        for w in range(nl):  # quat_normalize's sums and divisions
            norm = np.sqrt(((F[LANE_X, w] * F[LANE_X, w] + F[LANE_X + 1, w] * F[LANE_X + 1, w]) + F[LANE_X + 2, w] * F[LANE_X + 2, w])
                           + F[LANE_X + 3, w] * F[LANE_X + 3, w])
            F[LANE_X, w] = F[LANE_X, w] / norm
            F[LANE_X + 1, w] = F[LANE_X + 1, w] / norm
            F[LANE_X + 2, w] = F[LANE_X + 2, w] / norm
            F[LANE_X + 3, w] = F[LANE_X + 3, w] / norm


@jit
def propagate_wheels(x, u, L, dt, substeps, J, J_inv, G, prm):
    """:func:`propagate_wheels_into` with its own scratch arrays."""
    propagate_wheels_into(x, u, L, dt, substeps, J, J_inv, G, prm, np.empty((5, x.shape[0])), np.empty((3, 3)))


@jit
def wheel_speeds_into(x, G, prm, out):
    """``Omega`` (N,) of state ``x`` (7 + N) into ``out`` (the compiled loop's record)."""
    for i in range(out.shape[0]):
        out[i] = _speed(x[7 + i], G[0, i], G[1, i], G[2, i], prm[i, _JS], x[4], x[5], x[6])


def wheel_speeds(wheels: ReactionWheels, x: ArrayLike) -> Array:
    """``Omega`` (N,) relative to the body, of state ``x`` (7 + N)."""
    out: Array = np.empty(wheels.n)
    wheel_speeds_into(np.ascontiguousarray(x, dtype=np.float64), wheels.G, wheels.params(), out)  # the loop's kernel
    return out


def angular_momentum_B(J: ArrayLike, wheels: ReactionWheels, x: ArrayLike) -> Array:
    """The total angular momentum ``J omega + G h`` (3,) in B [N m s]."""
    x = np.asarray(x, dtype=np.float64)
    Jm = np.asarray(check_spd_inertia("J", J))
    w, h, G = x[4:7], x[7:], wheels.G
    # written out in a fixed order (docs/parity.md): J omega, then the wheels' momenta one by one
    out: Array = (Jm[:, 0] * w[0] + Jm[:, 1] * w[1]) + Jm[:, 2] * w[2]
    for i in range(wheels.n):
        out = out + G[:, i] * h[i]
    return out


# ============================================================================= a batch's arrays (the offline loop)


class ActuatorArrays(NamedTuple):
    """The actuator of a batch, as the whole-run loop takes it: ``max_torque_Nm`` the ideal
    actuator's per-axis limit [N m]; with W reaction wheels, ``G`` (N, 3, W) their spin axes,
    ``G_pinv`` (N, W, 3) the minimum-norm allocation, ``params`` (N, W, 6)
    (:meth:`ReactionWheels.params`) for each run (W = 0: the ideal actuator).  Packed by
    :func:`pack_actuator`."""

    max_torque_Nm: float
    G: NDArray[np.float64]
    G_pinv: NDArray[np.float64]
    params: NDArray[np.float64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"G": 0, "G_pinv": 0, "params": 0}


def pack_actuator(max_torque_Nm: float, wheel_sets: list[ReactionWheels], n_runs: int) -> ActuatorArrays:
    """A batch's actuator: the ideal one clipped at ``max_torque_Nm`` (``wheel_sets`` empty), or one
    wheel set per run (the same number of wheels)."""
    if wheel_sets and (len(wheel_sets) != n_runs or any(w.n != wheel_sets[0].n for w in wheel_sets)):
        raise ValueError(f"wheels must hold one wheel set per run ({n_runs}), each with the same number of wheels")
    W = wheel_sets[0].n if wheel_sets else 0
    G = np.array([w.G for w in wheel_sets], dtype=np.float64).reshape(n_runs, 3, W)
    G_pinv = np.array([allocation_matrix(w.G) for w in wheel_sets], dtype=np.float64).reshape(n_runs, W, 3)
    prm = np.array([w.params() for w in wheel_sets], dtype=np.float64).reshape(n_runs, W, 6)
    return ActuatorArrays(float(max_torque_Nm), np.ascontiguousarray(G), np.ascontiguousarray(G_pinv), np.ascontiguousarray(prm))

"""The spacecraft's orbital environment in the plant (issue 36): the orbit, the Earth's field, the
gravity-gradient torque and the magnetorquers, as the whole-run loop takes them.

Each sample ``t_k`` the loop asks :func:`environment_field` for the position ``r_N``
(:mod:`~spacecraft_sim.core.orbit`) and the true field ``B_N``, ``B_B``
(:mod:`~spacecraft_sim.core.magnetic_field`); the flight software measures ``B_B`` and commands the
rods; :func:`environment_torque_B` then gives the external torque of the environment and the rods,

    L_env_B = L_G_B (if gravity_gradient) + (G_t sat(m_cmd)) x B_B

held over ``[t_k, t_k+1]`` beside the scenario's disturbance (zero-order hold, as the disturbance and
the wheels' command: over 10 ms the orbit moves 0.07 mrad and the attitude less, so the held torque
differs from the continuous one by under 1e-4 of itself).

The gravity gradient acts on the whole spacecraft: with reaction wheels its inertia is the locked
one, ``J + sum J_s g g^T`` (:mod:`spacecraft_sim.core.wheels`: the scenario's ``J`` excludes the
wheels' spin inertia), the inertia Basilisk's hub and wheels present together
(:mod:`spacecraft_sim.basilisk_plant`).

Pure: no ROS, no clock.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.ephemeris import N_ORBIT_PARAMS, O_MU, dipole_field_N, position_N, to_body_B
from gnc_common.validation import ConfigError, from_mapping
from spacecraft_sim.core.magnetic_field import DipoleField
from spacecraft_sim.core.magnetometer import Magnetometer, magnetometer_draws, measure_field
from spacecraft_sim.core.magnetorquers import Magnetorquers, magnetorquers_from_mapping, mtb_torque_B
from spacecraft_sim.core.orbit import Orbit, gravity_gradient_B_of

__all__ = ["Environment", "EnvironmentArrays", "environment_field", "environment_from_mapping", "environment_measure_field", "environment_torque_B",
           "field_of", "locked_inertia", "measured_field_of", "pack_environment", "torque_of"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Environment:
    """The plant's orbital environment (module docstring).

    Attributes
    ----------
    orbit : Orbit
    magnetic_field : DipoleField
    gravity_gradient : bool
        Whether the gravity-gradient torque acts (an optional disturbance beside the scenario's).
    magnetorquers : Magnetorquers or None
    magnetometer : Magnetometer or None
        What the flight software reads the field with (``None``: the true field, exactly).
    """

    orbit: Orbit
    magnetic_field: DipoleField = DipoleField()
    gravity_gradient: bool = False
    magnetorquers: Magnetorquers | None = None
    magnetometer: Magnetometer | None = None


def _named(prefix: str, exc: ConfigError) -> ConfigError:
    """``exc`` with a model's bare key (``<prefix>: key ...``) named in full (``<prefix>.key ...``)."""
    msg = str(exc)
    return ConfigError(f"{prefix}.{msg[len(prefix) + 2:]}" if msg.startswith(f"{prefix}: ") else msg)


def environment_from_mapping(orbit: Any, rods: Any, magnetometer: Any = None, control_period_s: float = 0.01) -> Environment | None:
    """The scenario's ``orbit`` section (:class:`~spacecraft_sim.core.orbit.Orbit` keys, with
    ``magnetic_field``: :class:`~spacecraft_sim.core.magnetic_field.DipoleField` keys, default
    Basilisk's Earth dipole, and ``gravity_gradient``: true or false, default false), its
    ``magnetorquers`` section (:class:`~spacecraft_sim.core.magnetorquers.Magnetorquers` keys) and
    its ``magnetometer`` section (:class:`~spacecraft_sim.core.magnetometer.Magnetometer` keys; its
    rate must divide the control rate), which need an orbit: what the scenario loader and the plant
    node (its ``orbit``, ``magnetorquers`` and ``magnetometer`` parameters) both read.  All absent:
    ``None`` (every scenario without them runs as before).  Errors name the key."""
    if orbit is None:
        if rods is not None:
            raise ConfigError("magnetorquers needs an orbit section (the Earth's field they act against)")
        if magnetometer is not None:
            raise ConfigError("magnetometer needs an orbit section (the Earth's field it measures)")
        return None
    if not isinstance(orbit, dict):
        raise ConfigError(f"orbit must be a mapping, got {orbit!r}")
    rest = dict(orbit)
    field_raw = rest.pop("magnetic_field", None)
    gg = rest.pop("gravity_gradient", False)
    if not isinstance(gg, bool):
        raise ConfigError(f"orbit.gravity_gradient must be true or false, got {gg!r}")
    try:
        orbit_cfg: Orbit = from_mapping(Orbit, rest, "orbit")
    except ConfigError as exc:
        raise _named("orbit", exc) from None
    try:
        dipole: DipoleField = DipoleField() if field_raw is None else from_mapping(DipoleField, field_raw, "orbit.magnetic_field")
    except ConfigError as exc:
        raise _named("orbit.magnetic_field", exc) from None
    mag: Magnetometer | None = None
    if magnetometer is not None:
        try:
            mag = from_mapping(Magnetometer, magnetometer, "magnetometer")
        except ConfigError as exc:
            raise _named("magnetometer", exc) from None
        try:
            mag.stride(control_period_s)
        except ConfigError as exc:
            raise ConfigError(f"magnetometer.{exc}") from None
    return Environment(orbit=orbit_cfg, magnetic_field=dipole, gravity_gradient=gg,
                       magnetorquers=None if rods is None else magnetorquers_from_mapping(rods, "magnetorquers"), magnetometer=mag)


def locked_inertia(J: Array, spin_inertia_kg_m2: Array | None = None, G: Array | None = None) -> Array:
    """The spacecraft's inertia with its wheels locked (3, 3) [kg m^2], ``J + sum_i J_s,i g_i g_i^T``
    (module docstring; ``J`` alone without wheels): what the gravity gradient acts on, for the
    offline loop and the plant node alike."""
    J = np.asarray(J, dtype=np.float64)
    if spin_inertia_kg_m2 is None or G is None:
        return J
    out: Array = J + np.einsum("i,ji,ki->jk", np.asarray(spin_inertia_kg_m2, dtype=np.float64), G, G)
    return out


class EnvironmentArrays(NamedTuple):
    """A batch's environment (:func:`pack_environment`): ``orbit`` (N, 10 or 0)
    (:meth:`~spacecraft_sim.core.orbit.Orbit.params`; 0 columns: no orbit, the paper's inertial
    setting), ``field`` (N, 4) (:meth:`~spacecraft_sim.core.magnetic_field.DipoleField.params`),
    ``gravity`` (N, 3, 3) the inertia the gravity gradient acts on (all zero: none), ``Gt``
    (N, 3, M) and ``m_max`` (N, M) the rods (M = 0: none), ``mag`` (N, 7 or 0)
    (:meth:`~spacecraft_sim.core.magnetometer.Magnetometer.params`; 0 columns: the field read
    exactly) and ``mag_draws`` (N, U, 3) its draws."""

    orbit: Array
    field: Array
    gravity: Array
    Gt: Array
    m_max: Array
    mag: Array
    mag_draws: Array

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field."""
        return {"orbit": 0, "field": 0, "gravity": 0, "Gt": 0, "m_max": 0, "mag": 0, "mag_draws": 0}


def pack_environment(env: Environment | None, n_runs: int, locked_inertia_kg_m2: Array | None = None, n_samples: int = 0,
                     control_period_s: float = 0.0, run_keys: Sequence[Sequence[int]] | None = None) -> EnvironmentArrays:
    """A batch's environment, the same for every run but the magnetometer's draws (``None``: none,
    empty arrays); ``locked_inertia_kg_m2`` (3, 3) the spacecraft's inertia with the wheels locked
    (module docstring), needed with ``gravity_gradient``; ``n_samples`` and ``control_period_s``
    the run's samples and period, needed with a magnetometer; ``run_keys`` each run's key of the
    magnetometer's stream (:func:`~spacecraft_sim.core.magnetometer.magnetometer_draws`: a
    campaign's ``(run, seed)``, the same whichever chunk the run is in), ``None``: ``(k,)`` for
    run ``k`` of the batch."""
    if run_keys is not None and len(run_keys) != n_runs:
        raise ValueError(f"run_keys must hold one key per run ({n_runs}), got {len(run_keys)}")
    n = n_runs
    if env is None:
        return EnvironmentArrays(np.zeros((n, 0)), np.zeros((n, 4)), np.zeros((n, 3, 3)), np.zeros((n, 3, 0)), np.zeros((n, 0)),
                                 np.zeros((n, 0)), np.zeros((n, 0, 3)))
    if env.gravity_gradient and locked_inertia_kg_m2 is None:
        raise ValueError("the gravity-gradient torque needs the spacecraft's inertia")
    J = np.zeros((3, 3)) if not env.gravity_gradient else np.asarray(locked_inertia_kg_m2, dtype=np.float64)
    rods = env.magnetorquers
    Gt = np.zeros((3, 0)) if rods is None else rods.Gt
    m_max = np.zeros(0) if rods is None else rods.max_dipoles()

    def rep(a: Array) -> Array:  # a writable C-contiguous copy per run: one argument type for every call (no recompiles)
        return np.array(np.broadcast_to(np.asarray(a, dtype=np.float64), (n, *np.shape(a))), dtype=np.float64, order="C", copy=True)

    mag = env.magnetometer
    if mag is None:
        mprm, draws = np.zeros((n, 0)), np.zeros((n, 0, 3))
    else:
        mprm = rep(mag.params(control_period_s))
        keys = [(k,) for k in range(n)] if run_keys is None else run_keys
        draws = np.ascontiguousarray(np.stack([magnetometer_draws(mag, n_samples, control_period_s, key) for key in keys]))
    return EnvironmentArrays(rep(env.orbit.params()), rep(env.magnetic_field.params()), rep(J), rep(Gt), rep(m_max), mprm, draws)


# Each model has a kernel on one run's arrays (``*_of``: what the whole-run loop calls, with the
# run's rows taken once before its samples: a row taken per call costs a view and its reference
# count, which measured 0.2 to 0.3 us a sample, a third of the orbit's cost) and the batch's
# entry point of run ``n`` (what the plant node calls); the same arithmetic, the same bits.
@jit
def field_of(orbit, field, t, q_BN, r_N, B_N, B_B):
    """:func:`environment_field` on one run's rows ``orbit`` (10 or 0,) and ``field`` (4,)."""
    if orbit.shape[0] < N_ORBIT_PARAMS:
        return
    position_N(orbit, t, r_N)
    dipole_field_N(orbit, field, t, r_N, B_N)
    to_body_B(q_BN, B_N, B_B)


@jit
def environment_field(env, n, t, q_BN, r_N, B_N, B_B):
    """The position ``r_N`` [m] and the true field ``B_N``, ``B_B`` [T] (each (3,)) of run ``n`` at
    time ``t`` [s] and attitude ``q_BN`` (module docstring); nothing when the batch has no orbit."""
    field_of(env.orbit[n], env.field[n], t, q_BN, r_N, B_N, B_B)


@jit
def measured_field_of(mag, mag_draws, k, row0, B_B, B_meas):
    """:func:`environment_measure_field` on one run's rows ``mag`` (7 or 0,) and ``mag_draws`` (U, 3),
    the update rows from ``row0`` (:func:`~spacecraft_sim.core.magnetometer.measure_field`)."""
    if mag.shape[0] > 0:
        measure_field(mag, mag_draws, k, row0, B_B, B_meas)
    else:
        for j in range(3):
            B_meas[j] = B_B[j]


@jit
def environment_measure_field(env, n, k, B_B, B_meas):
    """The flight software's field ``B_meas`` (3,) at sample ``k``: the magnetometer's
    (:func:`~spacecraft_sim.core.magnetometer.measure_field`), or the true ``B_B`` without one."""
    measured_field_of(env.mag[n], env.mag_draws[n], k, 0, B_B, B_meas)


@jit
def torque_of(orbit, gravity, Gt, m_max, q_BN, r_N, B_B, m_cmd, r_B, L_mtb, out):
    """:func:`environment_torque_B` on one run's rows (``orbit``, ``gravity`` (3, 3), ``Gt`` (3, M),
    ``m_max`` (M,)); ``r_B`` and ``L_mtb`` (3,) scratch."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    if orbit.shape[0] < N_ORBIT_PARAMS:
        return
    if gravity[0, 0] != 0.0:  # an inertia is positive definite: a zero diagonal means no gravity gradient
        to_body_B(q_BN, r_N, r_B)
        g = gravity_gradient_B_of(orbit[O_MU], gravity, r_B[0], r_B[1], r_B[2])
        out[0] = g[0]
        out[1] = g[1]
        out[2] = g[2]
    if m_max.shape[0] > 0:
        mtb_torque_B(Gt, m_max, m_cmd, B_B, L_mtb)
        out[0] += L_mtb[0]
        out[1] += L_mtb[1]
        out[2] += L_mtb[2]


@jit
def environment_torque_B(env, n, q_BN, r_N, B_B, m_cmd, tmp, out):
    """``L_env_B`` (3,) [N m] into ``out``: the gravity gradient at ``r_N`` (when on) plus the rods'
    ``(G_t sat(m_cmd)) x B_B`` (when there are rods); ``tmp`` (2, 3) scratch (module docstring)."""
    torque_of(env.orbit[n], env.gravity[n], env.Gt[n], env.m_max[n], q_BN, r_N, B_B, m_cmd, tmp[0], tmp[1], out)

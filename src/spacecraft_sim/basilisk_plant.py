"""A plant backed by Basilisk (issue 16): its spacecraft hub, with its reaction-wheel effector when
the scenario has wheels, behind the same step interface as the native plant.

Basilisk (``pip install .[basilisk]``, ``bsk==2.12.1``) is the reference open-source spacecraft
simulator; the plant node runs this class with ``backend: basilisk`` (``python -m spacecraft_sim
--backend basilisk``, ``sappc run --plant basilisk``), so the controller flies against Basilisk's
dynamics on exactly the topics of the native plant.

Conventions and how the two plants are made the same body:

- **State.** Basilisk integrates the hub's MRPs ``sigma_BN`` and ``omega_BN_B`` (and each wheel's
  speed ``Omega`` relative to the body); :meth:`BasiliskPlant.state` returns the native layout,
  ``(q_BN scalar last, omega_BN_B)`` and, with wheels, the wheels' spin momenta
  ``h_i = Js_i (g_i . omega + Omega_i)`` (:mod:`spacecraft_sim.core.wheels`).  The MRP-to-quaternion
  map takes the sign that continues the previous quaternion (an MRP and its shadow set are one
  attitude).
- **Inertia.** The scenario's ``J`` is what the body presents to a torque (wheel spin inertia
  excluded).  Basilisk's rotational equation for balanced wheels takes ``Js g g^T`` of each
  wheel out of the spacecraft's inertia, so the hub gets ``J + sum Js g g^T`` (massless wheels at
  the centre of mass, transverse inertia ``Jt = 0``): measured, the other choice (``J``) leaves
  1e-3 between the two plants after 5 s of torque-free gyroscopic motion, this one 2e-15.
- **Timing.** The wheels' effector runs before the hub in Basilisk's task (a higher priority), so
  the motor command written for the period is the one integrated over it; in the other order
  Basilisk applies each command one period late (measured: the wheel momenta then match a
  one-period-delayed native run to 3e-15).
- **Integration.** Basilisk's default RK4 at ``dt / substeps``, the native plant's step; the hub
  integrates MRPs where the native plant integrates the quaternion (renormalised each step), so
  the two agree to the RK4 truncation error of two parametrisations (measured below).
- **Actuators.** Ideal: the commanded torque, clipped per axis to ``max_torque_Nm``, plus the
  disturbance, as Basilisk's external torque (``extForceTorque``), held over the period.
  Wheels: the project's own torque path (:func:`~spacecraft_sim.core.wheels.wheel_torques`:
  minimum-norm allocation, motor and speed limits) makes the motor torques, which Basilisk's
  wheels receive as their motor command with Basilisk's own limits off; the disturbance is the
  external torque.  Friction: Basilisk's Coulomb friction with its linear region of half-width
  ``omegaLimitCycle`` set to ``coulomb_speed_rad_s``, and its viscous friction; Stribeck off.

Imports Basilisk only when a plant is built; without it :class:`BasiliskPlant` raises an
``ImportError`` naming the install command.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import check_spd_inertia
from spacecraft_sim.core.wheels import ReactionWheels, allocation_matrix, wheel_torques

__all__ = ["BASILISK_INSTALL", "BasiliskPlant"]

Array = NDArray[np.float64]

#: What to run when Basilisk is missing.
BASILISK_INSTALL = "pip install '.[basilisk]' (bsk==2.12.1)"
#: Task priority of the wheels' effector: above the spacecraft's (default -1), so that at each
#: task time it reads the motor command before the hub integrates the period with it.
_BEFORE_THE_HUB = 10
#: Basilisk's time unit [ns per s].
_NS = 1_000_000_000


def _import_basilisk() -> tuple[Any, Any, Any, Any, Any]:
    try:
        from Basilisk.architecture import messaging
        from Basilisk.simulation import extForceTorque, reactionWheelStateEffector, spacecraft
        from Basilisk.utilities import SimulationBaseClass
    except ImportError as exc:
        raise ImportError(f"the Basilisk plant needs Basilisk, which is not installed here: {BASILISK_INSTALL} ({exc})") from None
    return SimulationBaseClass, spacecraft, extForceTorque, reactionWheelStateEffector, messaging


class BasiliskPlant:
    """One spacecraft in Basilisk, stepped one control period at a time (module docstring).

    Parameters
    ----------
    inertia_kg_m2 : (3, 3)
        ``J`` as the body presents it.
    q_BN0, omega_BN_B0 : (4,), (3,)
        Initial attitude (scalar last) and rate.
    dt_s : float
        The control period: each :meth:`step` advances it, the inputs held.
    substeps : int
        Basilisk's integration steps per period.
    wheels : ReactionWheels or None
        The wheel set (``None``: the ideal actuator).
    max_torque_Nm : float
        The ideal actuator's per-axis limit.
    """

    def __init__(self, inertia_kg_m2: ArrayLike, q_BN0: ArrayLike, omega_BN_B0: ArrayLike, dt_s: float, substeps: int = 1, *,
                 wheels: ReactionWheels | None = None, max_torque_Nm: float = np.inf) -> None:
        sim_base, spacecraft, ext_force_torque, rw_effector, messaging = _import_basilisk()
        self.J = check_spd_inertia("inertia_kg_m2", inertia_kg_m2)
        self.dt_ns = int(round(dt_s * _NS))
        if self.dt_ns % substeps:
            raise ValueError(f"dt_s = {dt_s!r} is not a whole number of nanoseconds per substep ({substeps})")
        self.wheels, self.max_torque = wheels, float(max_torque_Nm)
        q0 = np.asarray(q_BN0, dtype=np.float64) / np.linalg.norm(q_BN0)
        w0 = np.asarray(omega_BN_B0, dtype=np.float64)
        self._q_prev = q0.copy()
        self._messaging = messaging
        self.sim = sim_base.SimBaseClass()
        proc = self.sim.CreateNewProcess("plant")
        proc.addTask(self.sim.CreateNewTask("dynamics", self.dt_ns // substeps))
        self.sc = spacecraft.Spacecraft()
        self.sc.ModelTag = "spacecraft"
        self.sc.hub.mHub = 1.0  # translation is not modelled; any mass will do
        hub_J = self.J if wheels is None else self.J + np.einsum("i,ji,ki->jk", wheels.per_wheel("spin_inertia_kg_m2"), wheels.G, wheels.G)
        self.sc.hub.IHubPntBc_B = hub_J.tolist()
        sigma0 = q0[:3] / (1.0 + q0[3]) if q0[3] >= 0.0 else -q0[:3] / (1.0 - q0[3])
        self.sc.hub.sigma_BNInit = [[float(v)] for v in sigma0]
        self.sc.hub.omega_BN_BInit = [[float(v)] for v in w0]
        self.sim.AddModelToTask("dynamics", self.sc)
        self.ext = ext_force_torque.ExtForceTorque()
        self.ext.ModelTag = "external_torque"
        self.sc.addDynamicEffector(self.ext)
        self.sim.AddModelToTask("dynamics", self.ext)
        self.rw: Any = None
        if wheels is not None:
            self.rw = rw_effector.ReactionWheelStateEffector()
            self.rw.ModelTag = "reaction_wheels"
            prm = wheels.params()
            speeds0 = wheels.per_wheel("initial_speed_rad_s")
            for i in range(wheels.n):
                cfg = rw_effector.RWConfigPayload()
                cfg.RWModel = messaging.BalancedWheels
                cfg.gsHat_B = [[float(v)] for v in wheels.G[:, i]]
                cfg.Js, cfg.Jt, cfg.Jg, cfg.mass = float(prm[i, 0]), 0.0, 0.0, 0.0
                cfg.rWB_B = [[0.0], [0.0], [0.0]]
                cfg.Omega = float(speeds0[i])
                cfg.u_max, cfg.u_min, cfg.Omega_max = -1.0, 0.0, -1.0  # the project's torque path applies the limits
                cfg.fCoulomb, cfg.cViscous, cfg.fStatic, cfg.betaStatic = float(prm[i, 3]), float(prm[i, 4]), 0.0, -1.0
                cfg.omegaLimitCycle = float(prm[i, 5])
                self.rw.addReactionWheel(cfg)
            self._G, self._Gp, self._prm = wheels.G, allocation_matrix(wheels.G), prm
            self._cmd = messaging.ArrayMotorTorqueMsgPayload()
            self._cmd_msg = messaging.ArrayMotorTorqueMsg().write(self._cmd)
            self.rw.rwMotorCmdInMsg.subscribeTo(self._cmd_msg)
            self.sc.addStateEffector(self.rw)
            self.sim.AddModelToTask("dynamics", self.rw, _BEFORE_THE_HUB)  # reads its command before the hub integrates
            self.motor_torques = np.zeros(wheels.n)
        self.sim.InitializeSimulation()
        self.k = 0

    def motor_command(self, torque_B: ArrayLike) -> Array:
        """The wheels' motor torques (N,) for the commanded body torque at the current state
        (:func:`~spacecraft_sim.core.wheels.wheel_torques`), into :attr:`motor_torques`."""
        wheel_torques(np.ascontiguousarray(torque_B, dtype=np.float64), self._Gp, self._G, self._prm, self.state(), self.motor_torques)
        return self.motor_torques

    def step(self, torque_B: ArrayLike, disturbance_B: ArrayLike) -> None:
        """Advance one control period with the commanded body torque and the disturbance held."""
        tau = np.asarray(torque_B, dtype=np.float64)
        d = np.asarray(disturbance_B, dtype=np.float64)
        if self.rw is None:
            ext = np.minimum(np.maximum(tau, -self.max_torque), self.max_torque) + d
        else:
            self.motor_command(tau)
            cmd = [0.0] * len(self._cmd.motorTorque)
            cmd[: self.motor_torques.size] = self.motor_torques.tolist()
            self._cmd.motorTorque = cmd
            self._cmd_msg.write(self._cmd, self.k * self.dt_ns)
            ext = d
        self.ext.extTorquePntB_B = [[float(v)] for v in ext]
        self.k += 1
        self.sim.ConfigureStopTime(self.k * self.dt_ns)
        self.sim.ExecuteSimulation()

    def wheel_speeds_rad_s(self) -> Array:
        """Each wheel's speed relative to the body (empty without wheels)."""
        if self.rw is None:
            return np.zeros(0)
        assert self.wheels is not None
        speeds: Array = np.asarray(self.rw.rwSpeedOutMsg.read().wheelSpeeds[: self.wheels.n], dtype=np.float64)
        return speeds

    def state(self) -> Array:
        """``(q_BN, omega_BN_B)`` (7,), with wheels ``(q_BN, omega_BN_B, h)`` (7 + N,): the native layout."""
        out = self.sc.scStateOutMsg.read()
        sigma = np.asarray(out.sigma_BN, dtype=np.float64)
        s2 = float(sigma @ sigma)
        q = np.concatenate((2.0 * sigma, [1.0 - s2])) / (1.0 + s2)
        if float(q @ self._q_prev) < 0.0:  # the same attitude; keep the quaternion continuous
            q = -q
        self._q_prev = q
        w = np.asarray(out.omega_BN_B, dtype=np.float64)
        if self.rw is None or self.wheels is None:
            return np.concatenate((q, w))
        h = self.wheels.per_wheel("spin_inertia_kg_m2") * (self._G.T @ w + self.wheel_speeds_rad_s())
        return np.concatenate((q, w, h))

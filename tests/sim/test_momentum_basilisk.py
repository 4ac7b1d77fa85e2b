"""The orbit environment, the magnetorquers and the momentum-management law against Basilisk's own
modules (issue 36), each driven by its messages (or its state, for the effectors) on random
inputs: ``magneticFieldCenteredDipole``, ``GravityGradientEffector``, ``MtbEffector``,
``mtbMomentumManagementSimple``, ``torque2Dipole``, ``dipoleMapping``, ``mtbFeedforward`` and the
orbit's ``orbitalMotion.elem2rv``.  Runs where Basilisk is installed (``./sappcw`` installs it),
skipped elsewhere, as tests/sim/test_basilisk_parity.py.

Tolerance: the issue's, 1e-12 relative (``|ours - Basilisk| <= 1e-12 |Basilisk|``, the norm of the
vector).  Both sides evaluate the same formulas in double precision, in orders that differ only
where Eigen groups a product otherwise (``-[B x] G_t m`` against ``(G_t m) x B``) or Basilisk turns
an MRP into a matrix where this project rotates by a quaternion: a few 1e-16 relative each.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from sappc_momentum.core.law import (N_MM_WORK, dipole_mapping, dumping_scale, feedforward_torque_B, gyroscopic_torque_B,
                                     momentum_management_step, momentum_torque_request_B, torque_to_dipole_B)
from sappc_momentum.core.predictive import N_MM_PARAMS, new_state
from spacecraft_sim.core.magnetic_field import BASILISK_EARTH_DIPOLE, DipoleField, dipole_field_N, to_body_B
from spacecraft_sim.core.magnetorquers import Magnetorquers, mtb_torque_B
from spacecraft_sim.core.orbit import MU_EARTH_M3_S2, Orbit, gravity_gradient_B, position_N, position_N_of, true_anomaly_of

#: The issue's bound on every comparison with Basilisk (module docstring).
REL = 1e-12
#: Random cases per comparison.
CASES = 200
rng_seed = 36


def _close(ours: np.ndarray, theirs: np.ndarray) -> float:
    """``|ours - theirs| / |theirs|``."""
    return float(np.linalg.norm(np.asarray(ours) - np.asarray(theirs)) / np.linalg.norm(theirs))


#: The onboard orbit and field the cross-product law does not read (zeros, as pack_momentum packs them).
NO_ORBIT = (np.zeros(10), np.zeros(4))


def cross_product_prm(gain_per_s: float, gyroscopic: float) -> np.ndarray:
    """The law's parameter row for the cross-product law (:class:`~sappc_momentum.core.law.MomentumArrays`)."""
    prm = np.zeros(N_MM_PARAMS)
    prm[0], prm[4] = gain_per_s, gyroscopic
    return prm


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _quaternion(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q  # the MRP of a quaternion with w >= 0 is the short one (|sigma| <= 1)


def _sigma(q: np.ndarray) -> list[float]:
    """The MRP of ``q_BN`` (scalar last)."""
    return [float(v) for v in q[:3] / (1.0 + q[3])]


def _dcm_BN(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)],
                     [2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)],
                     [2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)]])


@pytest.fixture(scope="module")
def bsk() -> Any:
    return pytest.importorskip("Basilisk")


def test_the_orbit_position_equals_basilisk_elem2rv(bsk: Any) -> None:
    from Basilisk.utilities import orbitalMotion

    rng = np.random.default_rng(rng_seed)
    worst = 0.0
    for _ in range(CASES):
        a, e = 6.6e6 + rng.uniform(0, 3e6), rng.uniform(0.0, 0.3)
        inc, raan, argp, f = rng.uniform(0, math.pi), rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi), rng.uniform(-math.pi, math.pi)
        oe = orbitalMotion.ClassicElements()
        oe.a, oe.e, oe.i, oe.Omega, oe.omega, oe.f = a, e, inc, raan, argp, f
        r_ref, _ = orbitalMotion.elem2rv(MU_EARTH_M3_S2, oe)
        worst = max(worst, _close(np.array(position_N_of(a, e, inc, raan, argp, f)), r_ref))
    assert worst <= REL, worst


def test_keplers_equation_is_solved_as_basilisk_does(bsk: Any) -> None:
    """The true anomaly of a mean anomaly: Basilisk's ``M2E`` then ``E2f``."""
    from Basilisk.utilities import orbitalMotion

    rng = np.random.default_rng(rng_seed + 1)
    worst = 0.0
    for _ in range(CASES):
        e, M = rng.uniform(0.0, 0.9), rng.uniform(-math.pi, math.pi)
        f_ref = orbitalMotion.E2f(orbitalMotion.M2E(M, e), e)
        worst = max(worst, abs(math.remainder(true_anomaly_of(M, e) - f_ref, 2 * math.pi)) / max(abs(f_ref), 1e-3))
    assert worst <= REL, worst


def test_a_circular_orbit_keeps_its_radius_and_period() -> None:
    """No Basilisk needed: ``|r| = a`` at every time, back where it started after a period."""
    orbit = Orbit(altitude_m=500e3, inclination_deg=97.4, raan_deg=30.0, mean_anomaly_deg=10.0)
    prm, r0, r = orbit.params(), np.empty(3), np.empty(3)
    position_N(prm, 0.0, r0)
    for t in np.linspace(0.0, orbit.period_s, 97):
        position_N(prm, float(t), r)
        assert abs(np.linalg.norm(r) - orbit.semi_major_axis_m) <= 1e-9 * orbit.semi_major_axis_m
    assert np.linalg.norm(r - r0) <= 1e-6  # [m] after one period
    assert 5660.0 < orbit.period_s < 5680.0  # 94.5 min at 500 km (Vallado's tables)


@pytest.mark.parametrize("dipole", [BASILISK_EARTH_DIPOLE, DipoleField(g10_nT=-29404.8, g11_nT=-1450.9, h11_nT=4652.5)], ids=["basilisk", "igrf2020"])
def test_the_dipole_field_equals_basilisk_centred_dipole(bsk: Any, dipole: DipoleField) -> None:
    """``B_N`` of Basilisk's ``magneticFieldCenteredDipole`` fed the spacecraft's position and the
    Earth's orientation ``[PN]`` (its planet message's ``J20002Pfix``), at random times and
    positions; then ``B_B`` against ``[BN] B_N`` of the attitude."""
    from Basilisk.architecture import messaging
    from Basilisk.simulation import magneticFieldCenteredDipole

    rng = np.random.default_rng(rng_seed + 2)
    orbit = Orbit(earth_rotation_angle_deg=37.0)
    oprm, fprm = orbit.params(), dipole.params()
    module = magneticFieldCenteredDipole.MagneticFieldCenteredDipole()
    module.ModelTag = "dipole"
    module.g10, module.g11, module.h11 = dipole.g10_nT / 1e9, dipole.g11_nT / 1e9, dipole.h11_nT / 1e9
    module.planetRadius = dipole.reference_radius_m
    sc = messaging.SCStatesMsgPayload()
    sc_msg = messaging.SCStatesMsg().write(sc)
    planet = messaging.SpicePlanetStateMsgPayload()
    planet_msg = messaging.SpicePlanetStateMsg().write(planet)
    module.addSpacecraftToModel(sc_msg)
    module.planetPosInMsg.subscribeTo(planet_msg)
    module.Reset(0)
    worst_N = worst_B = 0.0
    B_N, B_B = np.empty(3), np.empty(3)
    for _ in range(CASES):
        t = rng.uniform(0.0, 86400.0)
        r_N = _unit(rng) * rng.uniform(6.6e6, 4.2e7)
        theta = oprm[8] + oprm[9] * t  # [PN] = R3(theta) (orbit module docstring)
        c, s = math.cos(theta), math.sin(theta)
        planet.J20002Pfix = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]
        planet_msg.write(planet)
        sc.r_BN_N = r_N.tolist()
        sc_msg.write(sc)
        module.UpdateState(0)
        ref = np.array(module.envOutMsgs[0].read().magField_N)
        dipole_field_N(oprm, fprm, t, r_N, B_N)
        worst_N = max(worst_N, _close(B_N, ref))
        q = _quaternion(rng)
        to_body_B(q, ref, B_B)
        worst_B = max(worst_B, _close(B_B, _dcm_BN(q) @ ref))
    assert worst_N <= REL, worst_N
    assert worst_B <= REL, worst_B


def _spacecraft(sim: Any, J: np.ndarray, q: np.ndarray, r_N: np.ndarray) -> Any:
    from Basilisk.simulation import spacecraft

    sc = spacecraft.Spacecraft()
    sc.ModelTag = "spacecraft"
    sc.hub.mHub = 100.0
    sc.hub.r_BcB_B = [[0.0], [0.0], [0.0]]
    sc.hub.IHubPntBc_B = J.tolist()
    sc.hub.sigma_BNInit = [[v] for v in _sigma(q)]
    sc.hub.omega_BN_BInit = [[0.0], [0.0], [0.0]]
    sc.hub.r_CN_NInit = [[float(v)] for v in r_N]
    sc.hub.v_CN_NInit = [[0.0], [0.0], [0.0]]
    sim.AddModelToTask("task", sc)
    return sc


def _random_inertia(rng: np.random.Generator) -> np.ndarray:
    """A physical inertia (the triangle inequality of its principal moments, which Basilisk checks):
    the second moments ``a, b, c`` of a mass distribution give ``(b + c, a + c, a + b)``, turned by
    a random rotation."""
    a, b, c = rng.uniform(0.5, 5.0, size=3)
    R = _dcm_BN(_quaternion(rng))
    return R @ np.diag([b + c, a + c, a + b]) @ R.T


def test_the_gravity_gradient_torque_equals_basilisk_effector(bsk: Any) -> None:
    """``GravityGradientEffector::computeForceTorque`` on a hub of random inertia, attitude and
    position (the Earth as its planet, with this project's ``mu``)."""
    from Basilisk.simulation import GravityGradientEffector
    from Basilisk.utilities import SimulationBaseClass, simIncludeGravBody
    from Basilisk.simulation import spacecraft

    rng = np.random.default_rng(rng_seed + 3)
    worst = 0.0
    out = np.empty(3)
    for _ in range(20):  # a simulation per case (the state is set at initialisation)
        sim = SimulationBaseClass.SimBaseClass()
        sim.CreateNewProcess("p").addTask(sim.CreateNewTask("task", 1_000_000))
        J, q, r_N = _random_inertia(rng), _quaternion(rng), _unit(rng) * rng.uniform(6.6e6, 4.2e7)
        sc = _spacecraft(sim, J, q, r_N)
        grav = simIncludeGravBody.gravBodyFactory()
        earth = grav.createEarth()
        earth.isCentralBody = True
        earth.mu = MU_EARTH_M3_S2
        sc.gravField.gravBodies = spacecraft.GravBodyVector(list(grav.gravBodies.values()))
        gg = GravityGradientEffector.GravityGradientEffector()
        gg.ModelTag = "gg"
        gg.addPlanetName(earth.planetName)
        sc.addDynamicEffector(gg)
        sim.AddModelToTask("task", gg)
        sim.InitializeSimulation()
        gg.computeForceTorque(0.0, 0.0)
        ref = np.array(gg.torqueExternalPntB_B).reshape(3)
        gravity_gradient_B(MU_EARTH_M3_S2, J, _dcm_BN(q) @ r_N, out)
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst


def test_the_magnetorquer_torque_equals_basilisk_mtb_effector(bsk: Any) -> None:
    """``MtbEffector::computeForceTorque``: random rods (axes, limits), commands beyond the limits
    and fields; the field given in N, the hub at a random attitude."""
    from Basilisk.architecture import messaging
    from Basilisk.simulation import MtbEffector
    from Basilisk.utilities import SimulationBaseClass

    rng = np.random.default_rng(rng_seed + 4)
    worst, clipped = 0.0, 0
    out, B_B = np.empty(3), np.empty(3)
    for _ in range(20):
        sim = SimulationBaseClass.SimBaseClass()
        sim.CreateNewProcess("p").addTask(sim.CreateNewTask("task", 1_000_000))
        q = _quaternion(rng)
        sc = _spacecraft(sim, np.diag([5.0, 6.0, 7.0]), q, np.array([7e6, 0.0, 0.0]))
        M = int(rng.integers(3, 6))
        rods = Magnetorquers(axes_B=tuple(tuple(_unit(rng)) for _ in range(M)), max_dipole_Am2=tuple(rng.uniform(1.0, 500.0, size=M)))
        cmd = rng.uniform(-1.5, 1.5, size=M) * rods.max_dipoles()
        clipped += int(np.any(np.abs(cmd) > rods.max_dipoles()))
        B_N = _unit(rng) * rng.uniform(2e-5, 6e-5)
        cfg = messaging.MTBArrayConfigMsgPayload()
        cfg.numMTB = M
        cfg.GtMatrix_B = rods.Gt.reshape(-1).tolist()  # row major (3, M), as the effector reads it
        cfg.maxMtbDipoles = rods.max_dipoles().tolist()
        cfg_msg = messaging.MTBArrayConfigMsg().write(cfg)
        cmd_pl = messaging.MTBCmdMsgPayload()
        cmd_pl.mtbDipoleCmds = cmd.tolist()
        cmd_msg = messaging.MTBCmdMsg().write(cmd_pl)
        mag = messaging.MagneticFieldMsgPayload()
        mag.magField_N = B_N.tolist()
        mag_msg = messaging.MagneticFieldMsg().write(mag)
        mtb = MtbEffector.MtbEffector()
        mtb.ModelTag = "mtb"
        mtb.mtbCmdInMsg.subscribeTo(cmd_msg)
        mtb.mtbParamsInMsg.subscribeTo(cfg_msg)
        mtb.magInMsg.subscribeTo(mag_msg)
        sc.addDynamicEffector(mtb)
        sim.AddModelToTask("task", mtb)
        sim.InitializeSimulation()
        mtb.computeForceTorque(0.0, 0.0)
        ref = np.array(mtb.torqueExternalPntB_B).reshape(3)
        B_B[:] = _dcm_BN(q) @ B_N
        mtb_torque_B(rods.Gt, rods.max_dipoles(), cmd, B_B, out)
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst
    assert clipped > 5  # the saturation was exercised


#: Messages a module is subscribed to: Basilisk keeps a pointer to each, so each must outlive the
#: module's update (a message collected by Python leaves the module reading freed memory).
_KEPT: list[Any] = []


def _kept(msg: Any) -> Any:
    _KEPT.append(msg)
    return msg


def _fsw(module: Any) -> Any:
    """A flight-software module ready to be reset and updated by hand: its output messages made
    (``SelfInit``, which a simulation's task would call; without it the update writes nowhere)."""
    module.ModelTag = type(module).__name__
    module.SelfInit()
    return module


def test_the_momentum_torque_request_equals_basilisk_mtb_momentum_management_simple(bsk: Any) -> None:
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import mtbMomentumManagementSimple

    rng = np.random.default_rng(rng_seed + 5)
    worst = 0.0
    out = np.empty(3)
    for _ in range(CASES):
        W = int(rng.integers(3, 7))
        Gs = np.array([_unit(rng) for _ in range(W)]).T  # (3, W)
        Js, Omega, kp = rng.uniform(0.01, 0.2, size=W), rng.uniform(-600.0, 600.0, size=W), rng.uniform(1e-4, 0.1)
        cfg = messaging.RWArrayConfigMsgPayload()
        cfg.GsMatrix_B = Gs.T.reshape(-1).tolist()  # (W, 3) row major: one spin axis per row
        cfg.JsList = Js.tolist()
        cfg.numRW = W
        speeds = messaging.RWSpeedMsgPayload()
        speeds.wheelSpeeds = Omega.tolist()
        module = _fsw(mtbMomentumManagementSimple.mtbMomentumManagementSimple())
        module.Kp = kp
        module.rwParamsInMsg.subscribeTo(_kept(messaging.RWArrayConfigMsg().write(cfg)))
        speeds_msg = messaging.RWSpeedMsg().write(speeds)
        module.rwSpeedsInMsg.subscribeTo(speeds_msg)
        module.Reset(0)
        module.UpdateState(0)
        ref = np.array(module.tauMtbRequestOutMsg.read().torqueRequestBody)
        momentum_torque_request_B(Gs, Js, Omega, kp, np.zeros(3), out)
        assert np.array_equal(out, ref) or _close(out, ref) <= REL
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst


def test_a_target_momentum_shifts_the_request() -> None:
    """``-K_p (h - h*)``: the request of wheels holding exactly ``h*`` is zero, and a target adds
    ``K_p h*``."""
    Gs, Js, Omega = np.eye(3), np.full(3, 0.1), np.array([10.0, -20.0, 30.0])
    out, zero = np.empty(3), np.empty(3)
    momentum_torque_request_B(Gs, Js, Omega, 0.01, np.array([1.0, -2.0, 3.0]), out)
    assert np.array_equal(out, np.zeros(3))
    momentum_torque_request_B(Gs, Js, Omega, 0.01, np.zeros(3), zero)
    assert np.allclose(out - zero, 0.01 * np.array([1.0, -2.0, 3.0]), rtol=0, atol=1e-15)


def test_the_body_dipole_equals_basilisk_torque2dipole(bsk: Any) -> None:
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import torque2Dipole

    rng = np.random.default_rng(rng_seed + 6)
    worst = 0.0
    out = np.empty(3)
    for _ in range(CASES):
        B = _unit(rng) * rng.uniform(1e-6, 6e-5)
        tau = rng.normal(size=3) * 1e-3
        tam = messaging.TAMSensorBodyMsgPayload()
        tam.tam_B = B.tolist()
        req = messaging.CmdTorqueBodyMsgPayload()
        req.torqueRequestBody = tau.tolist()
        module = _fsw(torque2Dipole.torque2Dipole())
        module.tamSensorBodyInMsg.subscribeTo(_kept(messaging.TAMSensorBodyMsg().write(tam)))
        module.tauRequestInMsg.subscribeTo(_kept(messaging.CmdTorqueBodyMsg().write(req)))
        module.Reset(0)
        module.UpdateState(0)
        ref = np.array(module.dipoleRequestOutMsg.read().dipole_B)
        torque_to_dipole_B(B, tau, out)
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst
    torque_to_dipole_B(np.full(3, 1e-16), np.ones(3), out)  # |B|^2 below DB0_EPS: no dipole, as Basilisk
    assert np.array_equal(out, np.zeros(3))


def test_the_rod_dipoles_equal_basilisk_dipole_mapping(bsk: Any) -> None:
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import dipoleMapping

    rng = np.random.default_rng(rng_seed + 7)
    worst, clipped = 0.0, 0
    for _ in range(CASES):
        M = int(rng.integers(3, 6))
        rods = Magnetorquers(axes_B=tuple(tuple(_unit(rng)) for _ in range(M)), max_dipole_Am2=tuple(rng.uniform(1.0, 500.0, size=M)))
        S = rods.steering_matrix()
        m_B = rng.normal(size=3) * 300.0
        cfg = messaging.MTBArrayConfigMsgPayload()
        cfg.numMTB = M
        cfg.GtMatrix_B = rods.Gt.reshape(-1).tolist()
        cfg.maxMtbDipoles = rods.max_dipoles().tolist()
        req = messaging.DipoleRequestBodyMsgPayload()
        req.dipole_B = m_B.tolist()
        module = _fsw(dipoleMapping.dipoleMapping())
        module.steeringMatrix = S.reshape(-1).tolist()  # (M, 3) row major
        module.mtbArrayConfigParamsInMsg.subscribeTo(_kept(messaging.MTBArrayConfigMsg().write(cfg)))
        module.dipoleRequestBodyInMsg.subscribeTo(_kept(messaging.DipoleRequestBodyMsg().write(req)))
        module.Reset(0)
        module.UpdateState(0)
        ref = np.array(module.dipoleRequestMtbOutMsg.read().mtbDipoleCmds[:M])
        out = np.empty(M)
        dipole_mapping(S, m_B, rods.max_dipoles(), out)
        clipped += int(np.any(np.abs(ref) == rods.max_dipoles()))
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst
    assert clipped > 20


def test_the_wheel_feedforward_equals_basilisk_mtb_feedforward(bsk: Any) -> None:
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import mtbFeedforward

    rng = np.random.default_rng(rng_seed + 8)
    worst = 0.0
    out = np.empty(3)
    for _ in range(CASES):
        M = int(rng.integers(3, 6))
        Gt = np.array([_unit(rng) for _ in range(M)]).T
        m, B, tau = rng.normal(size=M) * 200.0, _unit(rng) * rng.uniform(2e-5, 6e-5), rng.normal(size=3) * 1e-2
        cfg = messaging.MTBArrayConfigMsgPayload()
        cfg.numMTB = M
        cfg.GtMatrix_B = Gt.reshape(-1).tolist()
        cmd = messaging.MTBCmdMsgPayload()
        cmd.mtbDipoleCmds = m.tolist()
        tam = messaging.TAMSensorBodyMsgPayload()
        tam.tam_B = B.tolist()
        veh = messaging.CmdTorqueBodyMsgPayload()
        veh.torqueRequestBody = tau.tolist()
        module = _fsw(mtbFeedforward.mtbFeedforward())
        module.mtbArrayConfigParamsInMsg.subscribeTo(_kept(messaging.MTBArrayConfigMsg().write(cfg)))
        module.dipoleRequestMtbInMsg.subscribeTo(_kept(messaging.MTBCmdMsg().write(cmd)))
        module.tamSensorBodyInMsg.subscribeTo(_kept(messaging.TAMSensorBodyMsg().write(tam)))
        module.vehControlInMsg.subscribeTo(_kept(messaging.CmdTorqueBodyMsg().write(veh)))
        module.Reset(0)
        module.UpdateState(0)
        ref = np.array(module.vehControlOutMsg.read().torqueRequestBody)
        feedforward_torque_B(Gt, m, B, tau, out)
        worst = max(worst, _close(out, ref))
    assert worst <= REL, worst


def test_the_whole_law_is_the_chain_of_the_four_kernels() -> None:
    """:func:`momentum_management_step` is the four steps in order (each tested against Basilisk
    above), and the rods' torque it asks for is normal to the field and opposes the momentum."""
    rng = np.random.default_rng(rng_seed + 9)
    rods = Magnetorquers(max_dipole_Am2=1e4)
    Gs = np.array([_unit(rng) for _ in range(4)]).T
    Js, Omega, B, tau_c = np.full(4, 0.08), rng.uniform(-100, 100, size=4), _unit(rng) * 3e-5, rng.normal(size=3) * 1e-2
    prm = cross_product_prm(0.01, 0.0)
    m, tau_w, tmp = np.empty(3), np.empty(3), np.empty((N_MM_WORK, 3))
    momentum_management_step(prm, Gs, Js, np.linalg.pinv(Gs), np.full(4, 0.2), rods.Gt, rods.steering_matrix(), rods.max_dipoles(), *NO_ORBIT,
                             0.0, Omega, B, np.array([0.0, 0.0, 0.0, 1.0]), np.ones(3), tau_c, m, tau_w, tmp, new_state())
    req, m_B, m_ref, tau_ref = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    momentum_torque_request_B(Gs, Js, Omega, 0.01, np.zeros(3), req)
    torque_to_dipole_B(B, req, m_B)
    dipole_mapping(rods.steering_matrix(), m_B, rods.max_dipoles(), m_ref)
    feedforward_torque_B(rods.Gt, m_ref, B, tau_c, tau_ref)
    assert np.array_equal(m, m_ref) and np.array_equal(tau_w, tau_ref)
    tau_mtb = np.cross(rods.Gt @ m, B)
    h_B = Gs @ (Js * Omega)
    assert abs(tau_mtb @ B) <= 1e-12 * np.linalg.norm(tau_mtb) * np.linalg.norm(B)
    assert tau_mtb @ h_B < 0.0  # dumps: the rods' torque opposes the wheels' momentum
    assert np.allclose(tau_mtb, req - (req @ B) * B / (B @ B), rtol=1e-12, atol=0)  # the part of the request normal to B


def test_the_gyroscopic_term_is_omega_cross_the_wheels_momentum() -> None:
    """``omega x (G_s h_s)``, ``h_s = J_s (G_s^T omega + Omega)``: the closed form in numpy."""
    rng = np.random.default_rng(rng_seed + 10)
    out = np.empty(3)
    for _ in range(CASES):
        Gs = np.array([_unit(rng) for _ in range(4)]).T
        Js, Omega, w = rng.uniform(0.01, 0.1, size=4), rng.uniform(-600, 600, size=4), rng.normal(size=3) * 0.01
        gyroscopic_torque_B(Gs, Js, Omega, w, out)
        ref = np.cross(w, Gs @ (Js * (Gs.T @ w + Omega)))
        assert _close(out, ref) <= REL


def test_the_attitude_first_budget_keeps_every_motor_within_its_limit() -> None:
    """Step 6: the scaled rods' torque keeps the minimum-norm motor torques within their limits,
    with a motor at its limit whenever the scale is below 1 (the largest scale), and 0 when the
    base torque alone passes a limit."""
    rng = np.random.default_rng(rng_seed + 11)
    rods = Magnetorquers(max_dipole_Am2=3000.0)
    wheels_G = np.array([[0.5773502691896258, -0.5773502691896258, -0.5773502691896258, 0.5773502691896258],
                         [0.5773502691896258, 0.5773502691896258, -0.5773502691896258, -0.5773502691896258],
                         [0.5773502691896258] * 4])
    Gp, u_max = np.linalg.pinv(wheels_G), np.full(4, 0.2)
    scaled = 0
    for _ in range(CASES):
        base, mtb = rng.normal(size=3) * 0.08, rng.normal(size=3) * 0.15
        s = dumping_scale(Gp, u_max, base, mtb)
        u = -Gp @ (base - s * mtb)
        if np.all(np.abs(Gp @ base) <= u_max):
            assert 0.0 <= s <= 1.0 and np.all(np.abs(u) <= u_max * (1 + 1e-12))
            if s < 1.0:
                scaled += 1
                assert np.isclose(np.abs(u).max(), 0.2, rtol=1e-12, atol=0)
        else:
            assert s == 0.0
    assert scaled > 20
    prm = cross_product_prm(0.05, 1.0)
    m, tau_w, tmp = np.empty(3), np.empty(3), np.empty((N_MM_WORK, 3))
    B, Omega = np.array([2e-5, -3e-5, 1e-5]), np.array([300.0, -200.0, 100.0, 50.0])
    momentum_management_step(prm, wheels_G, np.full(4, 0.08), Gp, u_max, rods.Gt, rods.steering_matrix(), rods.max_dipoles(), *NO_ORBIT, 0.0,
                             Omega, B, np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.01, -0.01, 0.005]), np.array([0.05, 0.0, -0.05]), m, tau_w,
                             tmp, new_state())
    assert np.all(np.abs(Gp @ tau_w) <= u_max * (1 + 1e-12))

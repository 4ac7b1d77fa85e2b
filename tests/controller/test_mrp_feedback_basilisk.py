"""The MRP feedback controller against Basilisk's ``mrpFeedback`` flight module (issue 34).

Basilisk is the oracle (STYLE.md, 13): a real Basilisk process and task run ``attTrackingError``
(the guidance that turns the navigation and reference messages into ``AttGuidMsg``: ``sigma_BR``
in the inner set, ``omega_BR_B``, ``omega_RN_B``, ``domega_RN_B``) and ``mrpFeedback`` on it, fed
by messages written with random attitudes, rates, accelerations and gains at every step; this
project's controller gets the same states as its quaternion inputs, through its public
:meth:`~sappc_controller.core.base.AttitudeController.step`, and its commanded torque (before the
actuator model) must equal Basilisk's ``cmdTorqueOutMsg.torqueRequestBody``.  Several steps per
run, so the integral ``int_sigma`` accumulates (and, in one case, reaches ``integralLimit``).
Runs where Basilisk is installed (``./sappcw`` installs it), skipped elsewhere, as the plant's
Basilisk tests.

Tolerance: :data:`RTOL` relative to the torque's largest component.  The two sides compute the same
law from the same states by different roads: Basilisk converts quaternions to MRPs and subtracts
them (``subMRP``), rotates the reference rate with ``[BN]`` from ``sigma_BN``; this project forms
the error quaternion and rotates with ``C_BR``, then divides by ``1 + q_e0``.  Each road is a few
dozen double operations, each rounding by half an ulp (1.1e-16), so the inputs of the law differ
by ~1e-15 relative and the torque, a sum of a few products of them, by ~1e-14 of its terms;
measured 1.5e-15 at most over the three cases.  1e-12 leaves the margin for terms that partly
cancel, and is 8 orders below the modelling slips it must catch (a time step one call late, or the
first call's: 2e-3 here; a missing term or a wrong sign: larger).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from sappc_controller.core.common import ActuatorConfig
from sappc_controller.core.mrp_feedback import MrpFeedbackConfig, MrpFeedbackController, MrpFeedbackGains

#: Agreement of the torques, relative to their largest component (module docstring).
RTOL = 1e-12
#: Control period of the task [ns]: 50 ms, an odd multiple so that it is not a round number of seconds.
DT_NS = 50_000_000
#: First call of the task [ns]: one period after 0, because ``mrpFeedback`` takes a prior call time
#: of 0 for "no call yet", so a task starting at 0 would skip the integral at its first *two*
#: calls; from a start after 0 it skips it at the first call only, which is what this controller
#: does.  A whole period, because a task's later calls fall on multiples of its period.
FIRST_NS = DT_NS
#: Steps of each run: enough for the integral to grow over many calls.
STEPS = 25
J = np.array([[4.0, 0.1, -0.05], [0.1, 3.5, 0.02], [-0.05, 0.02, 4.5]])
#: Actuator limits that never act: the comparison is of the law's command.
NO_ACTUATOR = ActuatorConfig(max_torque_Nm=1e6, min_torque_Nm=0.0)


@dataclass(frozen=True)
class Case:
    K: float
    P: float
    Ki: float  # this project's value; Basilisk gets -1 for 0 (its default "off")
    integral_limit: float
    expect_limited: bool


CASES = {
    "proportional-derivative (Ki = 0 here, -1 in Basilisk)": Case(K=3.7, P=11.0, Ki=0.0, integral_limit=1.0, expect_limited=False),
    "integral": Case(K=2.3, P=7.5, Ki=0.013, integral_limit=100.0, expect_limited=False),
    "integral at its limit": Case(K=5.1, P=9.0, Ki=0.021, integral_limit=0.4, expect_limited=True),
}


def _unit(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _basilisk(case: Case) -> tuple[Any, Any, Any, Any, Any]:
    """A Basilisk simulation with attTrackingError feeding mrpFeedback; returns the simulation, the
    two input messages (navigation, reference), the feedback module and its payload types."""
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import attTrackingError, mrpFeedback
    from Basilisk.utilities import SimulationBaseClass

    sim = SimulationBaseClass.SimBaseClass()
    process = sim.CreateNewProcess("fsw")
    process.addTask(sim.CreateNewTask("control", DT_NS, FirstStart=FIRST_NS))
    tracking = attTrackingError.attTrackingError()
    tracking.ModelTag = "attTrackingError"
    feedback = mrpFeedback.mrpFeedback()
    feedback.ModelTag = "mrpFeedback"
    feedback.K, feedback.P = case.K, case.P
    feedback.Ki = case.Ki if case.Ki > 0.0 else -1.0
    feedback.integralLimit = case.integral_limit
    sim.AddModelToTask("control", tracking, 10)  # higher priority: the guidance first
    sim.AddModelToTask("control", feedback, 5)
    nav, ref = messaging.NavAttMsg(), messaging.AttRefMsg()
    vehicle = messaging.VehicleConfigMsgPayload()
    vehicle.ISCPntB_B = J.reshape(-1).tolist()
    vehicle_msg = messaging.VehicleConfigMsg().write(vehicle)
    tracking.attNavInMsg.subscribeTo(nav)
    tracking.attRefInMsg.subscribeTo(ref)
    feedback.guidInMsg.subscribeTo(tracking.attGuidOutMsg)
    feedback.vehConfigInMsg.subscribeTo(vehicle_msg)
    return sim, nav, ref, feedback, (messaging.NavAttMsgPayload, messaging.AttRefMsgPayload, vehicle_msg)


@pytest.mark.parametrize("name", list(CASES))
def test_mrp_feedback_equals_basilisk_mrpFeedback(name: str) -> None:
    pytest.importorskip("Basilisk")
    from Basilisk.utilities import RigidBodyKinematics as rbk

    case = CASES[name]
    sim, nav, ref, feedback, (NavPayload, RefPayload, _vehicle) = _basilisk(case)
    sim.InitializeSimulation()
    controller = MrpFeedbackController(MrpFeedbackConfig(
        inertia_kg_m2=tuple(map(tuple, J)), actuator=NO_ACTUATOR,
        gains=MrpFeedbackGains(K_Nm=case.K, P_Nms=case.P, Ki_per_kg_m2=case.Ki, integralLimit_Nms=case.integral_limit)))
    rng = np.random.default_rng(list(CASES).index(name) + 34)
    dt_s = DT_NS / 1e9
    worst, limited, integral_moved = 0.0, False, False
    for k in range(STEPS):
        q_BN, q_RN = _unit(rng), _unit(rng)  # scalar last (x, y, z, w)
        omega_BN_B = rng.uniform(-0.3, 0.3, 3)
        omega_RN_R = rng.uniform(-0.05, 0.05, 3)
        omegadot_RN_R = rng.uniform(-0.01, 0.01, 3)
        sigma_RN = np.asarray(rbk.EP2MRP([q_RN[3], *q_RN[:3]]))  # Basilisk's Euler parameters are scalar first
        C_RN = np.asarray(rbk.MRP2C(sigma_RN))
        n = NavPayload()
        n.sigma_BN = list(rbk.EP2MRP([q_BN[3], *q_BN[:3]]))
        n.omega_BN_B = omega_BN_B.tolist()
        r = RefPayload()
        r.sigma_RN = sigma_RN.tolist()
        r.omega_RN_N = (C_RN.T @ omega_RN_R).tolist()  # omega_RN has the same derivative seen from R and N
        r.domega_RN_N = (C_RN.T @ omegadot_RN_R).tolist()
        nav.write(n)
        ref.write(r)
        sim.ConfigureStopTime(FIRST_NS + k * DT_NS)
        sim.ExecuteSimulation()
        expected = np.asarray(feedback.cmdTorqueOutMsg.read().torqueRequestBody)
        got = controller.step(k * dt_s, dt_s, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R).torque_cmd_B
        worst = max(worst, float(np.max(np.abs(got - expected)) / np.max(np.abs(expected))))
        int_sigma = np.asarray(feedback.int_sigma)
        integral_moved |= bool(np.any(int_sigma != 0.0))
        limited |= bool(np.any(np.abs(int_sigma) >= case.integral_limit * (1.0 - 1e-15)))
    assert worst <= RTOL, worst
    assert integral_moved == (case.Ki > 0.0)  # the integral ran, or stayed off
    assert limited == case.expect_limited


def test_the_first_call_integrates_nothing_and_later_calls_integrate_dt() -> None:
    """The integral's time step, stated without Basilisk: 0 at a run's first call (mrpFeedback's
    prior call time), ``dt`` at each later one, whatever ``t`` says."""
    K, P, Ki = 2.0, 5.0, 0.01
    gains = MrpFeedbackGains(K_Nm=K, P_Nms=P, Ki_per_kg_m2=Ki, integralLimit_Nms=1e3)
    controller = MrpFeedbackController(MrpFeedbackConfig(inertia_kg_m2=tuple(map(tuple, J)), gains=gains, actuator=NO_ACTUATOR))
    q_RN = np.array([0.0, 0.0, 0.0, 1.0])
    q_BN = np.array([0.1, 0.0, 0.0, np.sqrt(1 - 0.01)])  # a pure rotation about x, no rate error
    zero = np.zeros(3)
    sigma_x = 0.1 / (1.0 + np.sqrt(1 - 0.01))
    out = controller.step(5.0, 0.2, q_BN, zero, q_RN, zero, zero)
    assert out.z[0] == 0.0  # z = K int(sigma) + J dw: nothing integrated yet, dw = 0
    out = controller.step(5.3, 0.2, q_BN, zero, q_RN, zero, zero)  # t moved 0.3 s, dt says 0.2
    assert out.z[0] == pytest.approx(K * 0.2 * sigma_x, rel=1e-15)
    # u = -(K sigma + P Ki z) on x (no rates): the integral's torque
    assert out.torque_cmd_B[0] == pytest.approx(-(K * sigma_x + P * Ki * out.z[0]), rel=1e-15)
    controller.reset()  # a new run: its first call integrates nothing again
    assert controller.step(9.0, 0.2, q_BN, zero, q_RN, zero, zero).z[0] == 0.0

"""The compiled laws' set-up and the parameters the parity test's scenario leaves equal.

``test_kernels_parity.py`` checks the kernels against the numpy oracle on ``paper_comparison.yaml``,
whose gains coincide (``T1_s = T2_s``, BLFPPC's ``m = 1/2``) and whose runs stay near the
reference: a kernel reading one parameter for another, or ``Gamma^-1``'s ``q_e0`` floor, would
pass it.  Here the same comparison (1e-12 relative, the parity test's bound: libm against numpy's
transcendental functions) with every gain distinct and errors beyond 150 deg, and the Python-side
set-up (:func:`~sappc_controller.core.packing.pack_params`, ``start_coef``, ``new_state``) against
what their docstrings state.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import SCENARIOS
from controller.oracle import OracleController
from gnc_common.attitude import quat_multiply
from sappc.scenario import load_scenario
from sappc_controller.core import kernels as K
from sappc_controller.core import packing as KP

#: The parity test's bound (test_kernels_parity._close): libm vs numpy's SIMD functions, ~1e-16 per call.
RTOL = 1e-12
FIELDS = ("torque_cmd_B", "rho", "band_lower", "band_upper", "eps", "z", "V")


def _distinct(name: str):  # type: ignore[no-untyped-def]
    """The scenario's config of ``name`` with every gain different from the others (and BLFPPC's
    m = 3/4, so that 1/m = m_even / m_odd is not m_even m_odd)."""
    cfg = load_scenario(SCENARIOS / "paper_comparison.yaml").controller_config(name)
    g = cfg.gains
    # mu = 0.05 rad/s: tanh(z2 / mu) in its linear range (with the scenario's 7e-5 it is +-1 to the last bit)
    if name == "blfppc":
        gains = dataclasses.replace(g, K1=0.31, K2=0.37, K3=0.043, T3_s=2.3, q0_floor=2e-3, mu_rad_s=0.05, D_m_Nm=0.04)
        return dataclasses.replace(cfg, gains=gains, ftppf=dataclasses.replace(cfg.ftppf, m_odd=3, m_even=4))
    return dataclasses.replace(cfg, gains=dataclasses.replace(g, K_q=0.31, K_omega=0.37, T1_s=3.3, T2_s=2.7, T3_s=2.3, q0_floor=2e-3,
                                                              mu_rad_s=0.05, D_m_Nm=0.04))


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))


@pytest.mark.parametrize("name", ["sappc", "trappc", "blfppc"])
def test_the_law_equals_the_oracle_with_distinct_gains_and_far_from_the_reference(name: str) -> None:
    """Each step equals the oracle's: 10 samples near the reference, then 10 with the error's
    scalar part between the floor and 0.3 (150 to 177 deg), where ``Gamma^-1`` uses ``q_e0`` itself;
    BLFPPC also at ``t = T_f`` exactly, where its funnel reaches ``rho_Tf`` with zero slope."""
    cfg = _distinct(name)
    ctrl = load_scenario(SCENARIOS / "paper_comparison.yaml").build_controller(name, config=cfg)
    rng = np.random.default_rng(20261125)
    q_d = np.array([0.1, -0.2, 0.3, 0.9])
    q_d /= np.linalg.norm(q_d)
    q_err = np.array([0.2, -0.15, 0.1, 1.0])
    q_err /= np.linalg.norm(q_err)
    q_BN = quat_multiply(q_d[None], q_err[None])[0]
    oracle = OracleController(cfg, K.error_quaternions(q_d, q_BN[None]))
    worst = 0.0
    times = [0.5 + 0.01 * k for k in range(20)] + ([0.5 + cfg.ftppf.T_f_s] if name == "blfppc" else [])
    for k, t in enumerate(times):
        if k >= 10:  # far: q_e = (v, q0) with q0 in (0.002, 0.3)
            q0 = rng.uniform(0.01, 0.3)
            v = rng.standard_normal(3)
            q_err = np.concatenate((np.sqrt(1.0 - q0 * q0) * v / np.linalg.norm(v), [q0]))
            q_BN = quat_multiply(q_d[None], q_err[None])[0]
        w, w_d, wdot_d = 0.02 * rng.standard_normal(3), 0.01 * rng.standard_normal(3), 1e-3 * rng.standard_normal(3)
        out = ctrl.step(t, 0.01, q_BN, w, q_d, w_d, wdot_d)
        ref = {f: v[0] for f, v in oracle.step(t - 0.5, 0.01, q_BN, w, q_d, w_d, wdot_d).items()}
        assert np.array_equal(out.q_BR, ref["q_BR"]) and np.array_equal(out.saturated, ref["saturated"])
        for field in FIELDS:
            worst = max(worst, _rel(getattr(out, field), ref[field]))
    assert worst <= RTOL, worst


def test_pack_params_takes_per_run_gains() -> None:
    """``gains`` gives per-run ``K_q``, ``K_omega``, ``D_m_Nm``, ``mu_rad_s`` (Monte Carlo
    dispersions); the others stay the config's."""
    cfg = _distinct("sappc")
    gains = {"K_q": np.array([0.2, 0.4]), "K_omega": np.array([0.5, 0.6]), "D_m_Nm": np.array([0.01, 0.02]), "mu_rad_s": np.array([1e-4, 2e-4])}
    prm = KP.pack_params(cfg, 2, gains)
    assert prm.shape == (2, K.N_PARAMS)
    for name, col in (("K_q", K.P_KQ), ("K_omega", K.P_KW), ("D_m_Nm", K.P_DM), ("mu_rad_s", K.P_MU)):
        assert prm[:, col].tolist() == gains[name].tolist(), name
    assert prm[:, K.P_T1].tolist() == [3.3, 3.3] and prm[:, K.P_T2].tolist() == [2.7, 2.7] and prm[:, K.P_Q0FLOOR].tolist() == [2e-3] * 2
    np.testing.assert_array_equal(KP.pack_params(cfg, 2), KP.pack_params(cfg, 1).repeat(2, axis=0))


def test_start_coef_flags_and_options() -> None:
    """``start_coef`` returns the RPF's ``flat`` and ``clamped`` flags, (N, 3) per component, all
    False for the benchmarks (no RPF); ``on_infeasible`` is keyword-only; a component starting at 0
    has sign +1."""
    q_BR0 = np.array([[0.0, -0.1, 0.2, 0.97467943448]])
    for name in ("trappc", "blfppc"):
        coef, flags = KP.start_coef(_distinct(name), q_BR0)
        assert coef[0, K.C_SIGN].tolist() == [1.0, -1.0, 1.0]
        assert {k: (v.shape, bool(v.any())) for k, v in flags.items()} == {"flat": ((1, 3), False), "clamped": ((1, 3), False)}
    with pytest.raises(TypeError):
        KP.start_coef(_distinct("sappc"), q_BR0, "raise")  # type: ignore[call-arg]


@pytest.mark.parametrize("name", ["trappc", "blfppc"])
def test_a_benchmark_refuses_an_initial_error_on_its_funnel(name: str) -> None:
    """The funnel's initial width "must exceed the largest initial error": an error equal to it
    (0.5 here) is refused, one just inside accepted."""
    from gnc_common.validation import ConfigError

    cfg = _distinct(name)
    assert (cfg.pf.rho_0 if name == "trappc" else cfg.ftppf.rho_initial) == 0.5
    with pytest.raises(ConfigError, match="must start inside its funnel"):
        KP.start_coef(cfg, np.array([[0.5, 0.0, 0.0, np.sqrt(0.75)]]))
    KP.start_coef(cfg, np.array([[np.nextafter(0.5, 0.0), 0.0, 0.0, np.sqrt(0.75)]]))


def test_new_state_starts_empty_at_its_time_origin() -> None:
    """A fresh state: filter off, no warm start, time origin ``t0`` (default 0)."""
    assert K.new_state().tolist() == [[0.0] * K.N_STATE]  # one run by default
    assert K.new_state(2).tolist() == [[0.0] * K.N_STATE] * 2
    state = K.new_state(2, t0=np.array([1.5, 2.5]))
    assert state[:, K.S_T0].tolist() == [1.5, 2.5] and not np.any(np.delete(state, K.S_T0, axis=1))

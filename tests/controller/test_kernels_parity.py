"""Parity of the compiled core (numba kernels) with the numpy core.

(a) each controller's compiled step equals the numpy core's step on random valid inputs, sample
after sample (filter and SMETF warm start carried), to 1e-12 relative;
(b) the whole-run compiled loop reproduces the numpy core's experiment 1-3 histories
(``tests/data/golden_numpy_core.npz``) to 1e-12 N m in torque;
(c) run k of a ``prange`` batch is the same run alone, bit for bit;
plus the plant kernels (RK4, reference rates, every disturbance kind) against the numpy models.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from conftest import ROOT, SCENARIOS, random_unit_quaternions
from gnc_common.attitude import quat_multiply
from sappc.offline.compiled_loop import prepare, run_batch, run_single, simulate_compiled
from sappc.scenario import load_scenario, scenario_from_mapping
from sappc_controller.core import kernels as K
from spacecraft_sim.core import kernels as PK
from spacecraft_sim.core.disturbance import disturbances_from_list
from spacecraft_sim.core.dynamics import RigidBody, initial_state

GOLDEN = ROOT / "tests" / "data" / "golden_numpy_core.npz"
GOLDEN_RUNS = [("paper_tracking", c) for c in ("sappc", "trappc", "blfppc")] + [
    ("paper_comparison", c) for c in ("sappc", "trappc", "blfppc")
] + [("paper_fault", c) for c in ("sappc", "blfppc")]
KINDS = {"sappc": K.KIND_SAPPC, "trappc": K.KIND_TRAPPC, "blfppc": K.KIND_BLFPPC}
DIAG = (("torque_cmd_B", K.O_CMD), ("rho", K.O_RHO), ("band_lower", K.O_BL), ("band_upper", K.O_BU), ("eps", K.O_EPS),
        ("z", K.O_Z), ("V", K.O_V))


def _close(a: np.ndarray, b: np.ndarray, rtol: float = 1e-12) -> float:
    """Largest |a - b| relative to max(|b|, 1e-300); the test bound is ``rtol``."""
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))


@pytest.mark.parametrize("name", ["sappc", "trappc", "blfppc"])
def test_step_kernel_equals_numpy_step(name: str) -> None:
    sc = load_scenario(SCENARIOS / "paper_comparison.yaml")
    rng = np.random.default_rng(20261123 + KINDS[name])
    cfg = sc.controller_config(name)
    worst = 0.0
    for trial in range(6):
        ctrl = sc.build_controller(name)
        # start inside every funnel (|q_ev,i(0)| < 0.5) and away from 180 deg
        q = np.concatenate((0.25 * rng.uniform(-1, 1, 3), [1.0]))
        q /= np.linalg.norm(q)
        q_d = random_unit_quaternions(rng, 1)[0] if trial % 2 else np.array([0.0, 0.0, 0.0, 1.0])
        q_BN = quat_multiply(q_d[None], q[None])[0]  # q_BR = q at the first sample
        w = 0.02 * rng.standard_normal(3)
        prm = K.pack_params(cfg)[0]
        coef = K.start_coef(cfg, K.error_quaternions(q_d, q_BN[None]))[0][0]
        state = K.new_state(1, t0=0.3)[0]
        work, out = np.zeros((K.N_WORK, 4)), np.zeros((K.N_OUT, 4))
        for k in range(40):
            t = 0.3 + 0.01 * k + (25.0 if k >= 30 else 0.0)  # also beyond t2 and T_f
            w_d, wdot_d = 0.01 * rng.standard_normal(3), 1e-3 * rng.standard_normal(3)
            ref = ctrl.step(t, 0.01, q_BN, w, q_d, w_d, wdot_d)
            K.controller_step(KINDS[name], t, 0.01, q_BN, w, q_d, w_d, wdot_d, prm, coef, state, work, out)
            assert np.array_equal(out[K.O_QBR], ref.q_BR)
            for field, row in DIAG:
                worst = max(worst, _close(out[row, :3], getattr(ref, field)))
            assert np.array_equal(out[K.O_TORQUE, :3] == 0.0, ref.torque_B == 0.0)
            assert np.array_equal(out[K.O_SAT, :3] != 0.0, ref.saturated)
            worst = max(worst, _close(out[K.O_TORQUE, :3], ref.torque_B))
            q_BN = q_BN + 0.002 * rng.standard_normal(4)
            q_BN /= np.linalg.norm(q_BN)
            w = w + 0.002 * rng.standard_normal(3)
    assert worst <= 1e-12, worst


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize(("scenario", "controller"), GOLDEN_RUNS)
def test_compiled_run_reproduces_numpy_golden(scenario: str, controller: str, golden: dict[str, np.ndarray]) -> None:
    run = simulate_compiled(load_scenario(SCENARIOS / f"{scenario}.yaml"), controller)
    torque = run.out[0, :, K.O_TORQUE, :3]
    q_ev = run.out[0, :, K.O_QBR, :3]
    ref_torque, ref_qev = golden[f"{scenario}.{controller}.torque_B"], golden[f"{scenario}.{controller}.q_ev"]
    assert torque.shape == ref_torque.shape
    assert np.max(np.abs(torque - ref_torque)) <= 1e-12
    assert np.max(np.abs(q_ev - ref_qev)) <= 1e-12


def _dispersed_batch(n: int = 5, duration: float = 3.0):  # type: ignore[no-untyped-def]
    """A short SAPPC batch exercising per-run paths: dispersed attitudes, rates, inertias, gains,
    disturbance scale and phase, a random disturbance and a pulse."""
    raw = copy.deepcopy(load_scenario(SCENARIOS / "paper_montecarlo.yaml").raw)
    raw["duration_s"] = duration
    raw["disturbances"] = [
        {"kind": "paper_periodic", "omega_p_rad_s": 0.01},
        {"kind": "random", "sigma_Nm": [1e-3, 2e-3, 3e-3], "hold_s": 0.05, "seed": 3},
        {"kind": "pulse", "start_s": 1.0, "duration_s": 0.5, "torque_Nm": [0.1, -0.1, 0.2]},
    ]
    sc = scenario_from_mapping(raw)
    rng = np.random.default_rng(7)
    from gnc_common.attitude import euler_to_quaternion
    from spacecraft_sim.core.disturbance import DisturbanceSum, PaperPeriodic
    import dataclasses

    q0 = euler_to_quaternion(np.radians(rng.uniform(-85, 85, (n, 3))), "ZYX")
    S = np.sqrt(1.0 + rng.uniform(-0.05, 0.05, (n, 3)))
    J = S[:, :, None] * sc.inertia_kg_m2[None] * S[:, None, :]
    models = tuple(
        dataclasses.replace(m, scale=tuple(rng.uniform(0.8, 1.2, n)), phase_rad=tuple(rng.uniform(0, 6.28, n)))
        if isinstance(m, PaperPeriodic) else m for m in sc.disturbance.models
    )
    gains = {"K_q": rng.uniform(0.25, 0.35, n), "mu_rad_s": rng.uniform(6e-5, 8e-5, n)}
    return prepare(sc, q_BN0=q0, omega_BN_B0=1e-3 * rng.standard_normal((n, 3)), inertia_kg_m2=J,
                   disturbance=DisturbanceSum(models), gains=gains, on_infeasible="clamp")


def test_batch_run_equals_run_alone_bit_for_bit() -> None:
    inp = _dispersed_batch()
    assert not inp.use_table
    batch = run_batch(inp, stride=1)
    for n in range(inp.n_runs):
        alone = run_single(inp, n, stride=1)
        assert np.array_equal(batch.out[n], alone.out[0])
        assert np.array_equal(batch.x[n], alone.x[0])
        assert np.array_equal(batch.d[n], alone.d[0])
        assert np.array_equal(batch.x_final[n], alone.x_final[0])
    # without histories the final states are the same too
    assert np.array_equal(run_batch(inp, stride=0).x_final, batch.x_final)
    assert np.all(np.isfinite(batch.out))


def test_every_disturbance_kind_equals_numpy_model() -> None:
    model = disturbances_from_list([
        {"kind": "paper_periodic", "omega_p_rad_s": 0.01, "scale": [0.9, 1.1], "phase_rad": [0.0, 1.3]},
        {"kind": "constant", "torque_Nm": [1e-3, -2e-3, 3e-3]},
        {"kind": "step", "start_s": 0.5, "torque_Nm": [0.1, 0.2, -0.3]},
        {"kind": "pulse", "start_s": 1.0, "duration_s": 0.5, "torque_Nm": [1.0, 1.0, 1.0]},
        {"kind": "random", "sigma_Nm": [1e-3, 2e-3, 3e-3], "hold_s": 0.03, "seed": 11},
        {"kind": "random", "sigma_Nm": [4e-3, 0.0, 1e-3], "hold_s": 0.01, "seeds": [5, 9]},
    ])
    t = np.arange(301) * 0.01
    ref = model.torque_B(t, 2)  # (T, 2, 3)
    kinds, dparams, dscale, dphase = PK.encode_disturbance(model, 2)
    draws, win = PK.random_draws(model, t, 2)
    for n in range(2):
        d = PK.disturbance_table(t, kinds, dparams, dscale[n], dphase[n], draws[:, n], win)
        assert np.max(np.abs(d - ref[:, n])) <= 1e-15
        on = np.abs(ref[:, n]) > 0
        assert np.array_equal(np.abs(d) > 0, on)  # windows switch on the same samples


def test_plant_and_reference_kernels_equal_numpy() -> None:
    rng = np.random.default_rng(3)
    J = np.array([[4.0, 0.1, -0.2], [0.1, 5.0, 0.3], [-0.2, 0.3, 6.0]])
    body = RigidBody(J)
    q = random_unit_quaternions(rng, 20)
    w = 0.1 * rng.standard_normal((20, 3))
    torque = 0.3 * rng.standard_normal((20, 3))
    ref = body.propagate(initial_state(q, w), torque, 0.01, 3)
    work = np.zeros((PK.N_PLANT_WORK, 7))
    J_inv = np.linalg.inv(J)
    for n in range(20):
        x = np.concatenate((q[n], w[n]))
        PK.propagate(x, torque[n], 0.01, 3, J, J_inv, work)
        assert np.max(np.abs(x - ref[n])) <= 1e-15
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    t = np.arange(6001) * 0.01
    w_k, wd_k = PK.reference_rate_tables(sc.reference, t)
    assert _close(w_k, sc.reference.omega_RN_R(t)) <= 1e-13
    assert _close(wd_k, sc.reference.omegadot_RN_R(t)) <= 1e-13


def test_start_checks_apply() -> None:
    from gnc_common.validation import ConfigError, InputError

    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    with pytest.raises(InputError, match="180 deg singularity"):
        prepare(sc, "sappc", q_BN0=np.array([1.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ConfigError, match="must start inside its funnel"):
        prepare(sc, "trappc", q_BN0=np.array([0.6, 0.0, 0.0, 0.8]))


def test_cache_dir_falls_back_to_user_dir_when_install_is_read_only(monkeypatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from gnc_common import compiled

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(compiled.os, "access", lambda path, mode: False)
    chosen = compiled._choose_cache_dir()
    assert chosen == str(tmp_path / "sappc" / "numba")
    assert (tmp_path / "sappc" / "numba").is_dir()
    assert compiled.os.environ["NUMBA_CACHE_DIR"] == chosen
    # a directory the user chose wins
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert compiled._choose_cache_dir() == str(tmp_path / "mine")

"""Parity of the compiled law (the one implementation) with the numpy oracle and with itself on every path.

(a) each controller's step (``AttitudeController.step``, the compiled kernel) equals the numpy
oracle (``tests/controller/oracle.py``) on random valid inputs, sample after sample (filter and
SMETF warm start carried), to 1e-12 relative;
(b) the whole-run compiled loop reproduces the numpy core's experiment 1-3 histories
(``tests/data/golden_numpy_core.npz``, recorded before the numpy core was removed) to 1e-12 N m;
(c) run k of a ``prange`` batch is the same run alone, bit for bit;
(d) the node's path (``AttitudeController.step``, sample by sample) gives the offline compiled
run's outputs bit for bit;
plus the plant kernels (RK4, reference rates, every disturbance kind) against the numpy models.
"""

from __future__ import annotations

import copy

from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, SCENARIOS, random_unit_quaternions
from gnc_common.attitude import quat_multiply
from controller.oracle import OracleController
from sim import oracle as sim_oracle
from sappc.offline.compiled_loop import prepare, run_batch, run_single, simulate_compiled
from sappc.scenario import load_scenario, scenario_from_mapping
from sappc_controller.core import kernels as K
from sappc_controller.inputs import ControlSample, step_sample
from sappc_controller.params import CONTROLLER_CLASSES, config_from_parameters, parameters_from_config
from spacecraft_sim.core import kernels as PK
from spacecraft_sim.core.disturbance import disturbances_from_list, encode_disturbance, random_draws
from spacecraft_sim.core.dynamics import RigidBody, initial_state

GOLDEN = ROOT / "tests" / "data" / "golden_numpy_core.npz"
GOLDEN_RUNS = [("paper_tracking", c) for c in ("sappc", "trappc", "blfppc")] + [
    ("paper_comparison", c) for c in ("sappc", "trappc", "blfppc")
] + [("paper_fault", c) for c in ("sappc", "blfppc")]
KINDS = {"sappc": K.KIND_SAPPC, "trappc": K.KIND_TRAPPC, "blfppc": K.KIND_BLFPPC}
DIAG = ("torque_cmd_B", "rho", "band_lower", "band_upper", "eps", "z", "V")
ROWS = {"torque_B": K.O_TORQUE, "torque_cmd_B": K.O_CMD, "q_BR": K.O_QBR, "rho": K.O_RHO, "band_lower": K.O_BL,
        "band_upper": K.O_BU, "eps": K.O_EPS, "z": K.O_Z, "V": K.O_V}


def _close(a: np.ndarray, b: np.ndarray, rtol: float = 1e-12) -> float:
    """Largest |a - b| relative to max(|b|, 1e-300); the test bound is ``rtol``."""
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))


@pytest.mark.parametrize("name", ["sappc", "trappc", "blfppc"])
def test_step_equals_the_numpy_oracle(name: str) -> None:
    """The compiled step against the oracle: equal to 1e-12 relative (libm vs numpy's SIMD
    transcendental functions differ in the last bit, gnc_common.compiled; the error quaternion,
    free of them, is equal bit for bit)."""
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
        oracle = OracleController(cfg, K.error_quaternions(q_d, q_BN[None]))
        for k in range(40):
            t = 0.3 + 0.01 * k + (25.0 if k >= 30 else 0.0)  # also beyond t2 and T_f
            w_d, wdot_d = 0.01 * rng.standard_normal(3), 1e-3 * rng.standard_normal(3)
            out = ctrl.step(t, 0.01, q_BN, w, q_d, w_d, wdot_d)
            ref = {f: v[0] for f, v in oracle.step(t - 0.3, 0.01, q_BN, w, q_d, w_d, wdot_d).items()}
            assert np.array_equal(out.q_BR, ref["q_BR"])
            for field in DIAG:
                worst = max(worst, _close(getattr(out, field), ref[field]))
            assert np.array_equal(out.torque_B == 0.0, ref["torque_B"] == 0.0)
            assert np.array_equal(out.saturated, ref["saturated"])
            worst = max(worst, _close(out.torque_B, ref["torque_B"]))
            q_BN = q_BN + 0.002 * rng.standard_normal(4)
            q_BN /= np.linalg.norm(q_BN)
            w = w + 0.002 * rng.standard_normal(3)
    assert worst <= 1e-12, worst


@pytest.mark.parametrize("name", ["sappc", "trappc", "blfppc"])
def test_the_node_step_gives_the_offline_run_bit_for_bit(name: str) -> None:
    """Experiment 1 (paper_tracking.yaml): the offline compiled run's states and references fed
    sample by sample to the controller the node builds (from its ROS parameters) through the node's
    call (:func:`sappc_controller.inputs.step_sample`, i.e. ``AttitudeController.step``) give the
    offline run's torques and diagnostics bit for bit.  The sample time is the stamp's seconds on
    both paths (``t_ns / 1e9``: the offline loop gives the controller its input's stamp, as the node
    does; ``k dt`` would differ from it in the last bit at 1 sample in 7)."""
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    inp = prepare(sc, name)
    run = run_single(inp, 0, stride=1)
    config = config_from_parameters(name, parameters_from_config(name, sc.controller_config(name)))
    assert config == sc.controller_config(name)
    ctrl = CONTROLLER_CLASSES[name](config)

    outs = {f: np.empty((inp.t.size, 4 if f == "q_BR" else 3)) for f in ROWS}
    saturated = np.empty((inp.t.size, 3), dtype=bool)
    for k in range(inp.t.size):
        x = run.x[0, k]
        ns = int(inp.grid.t_ns[k])  # the plant's stamp of sample k, as the node receives it
        sample = ControlSample(ns, (ns,) * 5, (x[:4].copy(), x[4:].copy(), inp.grid.ref_q[k], inp.grid.ref_w[k], inp.grid.ref_wd[k]))
        out = step_sample(ctrl, inp.grid.dt, sample)
        for f in ROWS:
            outs[f][k] = getattr(out, f)
        saturated[k] = out.saturated
    for f, row in ROWS.items():
        width = 4 if f == "q_BR" else 3
        assert np.array_equal(outs[f], run.out[0, :, row, :width]), f
    assert np.array_equal(saturated, run.out[0, :, K.O_SAT, :3] != 0.0)
    assert np.any(outs["torque_B"] != 0.0)


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize(("scenario", "controller"), GOLDEN_RUNS)
def test_compiled_run_reproduces_numpy_golden(scenario: str, controller: str, golden: dict[str, np.ndarray]) -> None:
    """Different code paths (docs/parity.md, "bounded"): the compiled loop against the numpy core's
    histories, fed the reference those were recorded with (scipy's DOP853 at rtol 1e-12, rebuilt
    by the oracle; the product's reference is now a more accurate RK4, 5e-13 away from it, and
    this test is about the controller and plant code, not the reference's integration error).

    Bounds, 1e-12 N m and 1e-12 in q_ev: the two paths differ by one or two rounding units per
    transcendental call (libm against numpy's SIMD routines, about 20 calls per step), and by
    BLAS's last bits in the rebuilt reference; summed without any contraction of the closed loop
    over 6000 steps, 6000 x 2 x 2^-53 x 0.5 N m (the largest torque) is 6.7e-13 N m, and a unit
    quaternion's components carry the same absolute error whatever their size."""
    sc = load_scenario(SCENARIOS / f"{scenario}.yaml")
    inp = prepare(sc, controller)
    inp.grid.ref_q[:] = sim_oracle.reference_quaternions_dop853(inp.t, np.array(sc.reference.q_RN0), sc.reference.amplitude_deg_s,
                                                          sc.reference.periods_s)
    run = run_single(inp, 0, stride=1)
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
    assert not inp.disturbance.use_table
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
    kinds, dparams, dscale, dphase = encode_disturbance(model, 2)
    draws, win = random_draws(model, t, 2)
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
    J_inv = np.linalg.inv(J)
    for n in range(20):
        x = np.concatenate((q[n], w[n]))
        PK.propagate(x, torque[n], 0.01, 3, J, J_inv)
        assert np.max(np.abs(x - ref[n])) <= 1e-15
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    t = np.arange(6001) * 0.01
    w_k, wd_k = sc.reference.rates(t)
    assert _close(w_k, sc.reference.omega_RN_R(t)) <= 1e-13
    assert _close(wd_k, sc.reference.omegadot_RN_R(t)) <= 1e-13


def test_start_checks_apply() -> None:
    from gnc_common.validation import ConfigError, InputError

    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    with pytest.raises(InputError, match="180 deg singularity"):
        prepare(sc, "sappc", q_BN0=np.array([1.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ConfigError, match="must start inside its funnel"):
        prepare(sc, "trappc", q_BN0=np.array([0.6, 0.0, 0.0, 0.8]))


def test_the_cache_directory_is_a_user_directory_named_by_the_kernel_sources(monkeypatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A user directory (works from a read-only install), named by a digest of every kernel module:
    an edit of any kernel gives a fresh cache (numba alone would keep a stale caller of that kernel)."""
    from gnc_common import compiled

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("SAPPC_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    chosen = compiled._choose_cache_dir()
    assert chosen == str(tmp_path / "sappc" / "numba" / f"sappc-{compiled.kernel_sources_digest()}")
    assert Path(chosen).is_dir() and compiled.os.environ["NUMBA_CACHE_DIR"] == chosen
    assert compiled._choose_cache_dir() == chosen  # a child process inheriting it keeps it
    monkeypatch.setenv("SAPPC_CACHE_DIR", str(tmp_path / "mine"))
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert compiled._choose_cache_dir().startswith(str(tmp_path / "mine" / "numba" / "sappc-"))
    # the digest covers every kernel module: changing one changes it
    real = Path.read_bytes

    def edited(self: Path) -> bytes:
        return real(self) + (b"# edit" if self.name == "kernels.py" and "spacecraft_sim" in str(self) else b"")

    before = compiled.kernel_sources_digest()
    monkeypatch.setattr(Path, "read_bytes", edited)
    assert compiled.kernel_sources_digest() != before
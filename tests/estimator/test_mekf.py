"""The MEKF kernel (:func:`sappc_estimator.core.mekf.mekf_step`) against its specification.

(a) **Parity with the oracle.**  The kernel equals the numpy transcription of
``docs/estimator.md`` (``tests/estimator/oracle.py``) step after step on fixed measurement
sequences from the project's sensor models (a tumbling body; a tracker outage; outliers and a
burst that re-initialises; a prior 10 deg off).  Statuses and counters exactly; the numbers to
the bounds of :data:`PARITY_ABS`, :data:`PARITY_REL_P` (module constants; their justification
there).

(b) **Behaviour.**  Initialisation from the first tracker sample; propagation only through an
outage, with the attitude variance growing as the continuous model predicts, then re-acquisition;
the gate (an outlier rejected without a trace, a burst that re-initialises); the multiplicative
reset; bias convergence and attitude errors within 3 sigma; the covariance symmetric positive
definite over a 3 h soak; NEES consistency on a small Monte Carlo.

Units: angles [rad], rates [rad/s], times [s].  Quaternions scalar last, ``q_BN``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from estimator import oracle
from estimator.oracle import MekfOracle, attitude_error, dq, quat_conjugate, quat_multiply, rotvec
from sappc_estimator.core import mekf
from sappc_estimator.core.config import MekfConfig
from spacecraft_sim.core.sensors import S_BIAS0, Gyro, Sensors, StarTracker, measure

# ----------------------------------------------------------------------------- the hardware

#: Control period [s] (100 Hz gyro and filter) and the tracker's rate [Hz].
DT_S = 0.01
TRACKER_HZ = 10.0
STRIDE = int(round(1.0 / (TRACKER_HZ * DT_S)))
#: 1-sigma star-tracker noise per body axis [rad] (boresight z ~7.5x worse than across it).
TRACKER_NOISE_RAD = (9.7e-6, 9.7e-6, 7.3e-5)
#: Gyro angle random walk [rad/sqrt(s)], bias random walk [rad/s/sqrt(s)], turn-on bias [rad/s].
ARW_RAD_SQRT_S = 1.45e-6
BRW_RAD_S_SQRT_S = 8.1e-10
BIAS0_RAD_S = (2.4e-6, -1.5e-6, 1e-6)

#: Kernel-oracle bounds.  Both evaluate the same page in float64; they differ by the route (the
#: closed-form Φ with its series against ``scipy.linalg.expm``, which agree to ~1e-16 relative of
#: ``|F h| ~ 1e-2``; ``inv``/``solve`` against the kernel's own 3x3 algebra; the order of the sums)
#: so each step adds a few ulps, and the filter's updates pull both onto the same measurements,
#: which keeps the differences from accumulating (they are measured ~1e-15 after thousands of steps).
#: * quaternion components (unit vectors, O(1)): absolute, ``PARITY_ABS``;
#: * attitude-like and bias quantities compare in the filter's own units, relative to their
#:   sigma (see :func:`_compare`), because their values are 1e-6..1e-5 rad or rad/s and an
#:   absolute 1e-12 on them would be a bound that cannot fail;
#: * ``P`` relative to its diagonal scale ``sqrt(P_ii P_jj)`` (entries span 1e-19..1e-9).
PARITY_ABS = 1e-12
PARITY_REL_P = 1e-12


def mekf_config(**kw: object) -> MekfConfig:
    """The filter of the data sheet above (``docs/estimator.md``'s defaults), overridden by ``kw``."""
    base: dict[str, object] = dict(tracker_noise_rad=TRACKER_NOISE_RAD, gyro_angle_random_walk_rad_sqrt_s=ARW_RAD_SQRT_S,
                                   gyro_bias_random_walk_rad_s_sqrt_s=BRW_RAD_S_SQRT_S)
    base.update(kw)
    return MekfConfig(**base)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- truth and measurements


def qmul_rows(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton product of (N, 4) arrays (scalar last)."""
    pv, p0 = p[:, :3], p[:, 3:]
    qv, q0 = q[:, :3], q[:, 3:]
    return np.concatenate((p0 * qv + q0 * pv + np.cross(pv, qv), p0 * q0 - np.sum(pv * qv, axis=1, keepdims=True)), axis=1)


def dq_rows(r: np.ndarray) -> np.ndarray:
    """Row-wise ``dq(r)`` of (N, 3) rotation vectors [rad]."""
    angle = np.linalg.norm(r, axis=1, keepdims=True)
    safe = np.where(angle > 0.0, angle, 1.0)
    return np.concatenate((np.where(angle > 0.0, np.sin(angle / 2.0) / safe, 0.5) * r, np.cos(angle / 2.0)), axis=1)


def cumulative_product(q0: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """``q_k = q0 ⊗ d_1 ⊗ ... ⊗ d_k`` for the (N, 4) increments, (N + 1, 4), by a vectorised
    prefix scan (log2 N passes of row products), renormalised."""
    prod = increments.copy()
    shift = 1
    while shift < len(prod):
        prod[shift:] = qmul_rows(prod[:-shift], prod[shift:])
        shift *= 2
    out = np.vstack((q0, qmul_rows(np.broadcast_to(q0, prod.shape), prod)))
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def tumbling_rates(t_s: np.ndarray, scale_rad_s: float = 0.01) -> np.ndarray:
    """A slow tumble, (T, 3) [rad/s]: each axis ~``scale`` varying over minutes."""
    return scale_rad_s * np.stack((np.sin(2 * np.pi * t_s / 170.0 + 0.4), np.cos(2 * np.pi * t_s / 110.0),
                                   0.7 * np.sin(2 * np.pi * t_s / 230.0 + 1.1)), axis=-1)


@dataclass
class Run:
    """A truth and its measurements at the control samples ``t_s = k DT_S``, k < n."""

    t_s: np.ndarray  # (n,)
    q_true: np.ndarray  # (n, 4)
    omega_true_rad_s: np.ndarray  # (n, 3)
    bias_true_rad_s: np.ndarray  # (n, 3): the bias in the gyro sample k
    y: np.ndarray  # (n, 7): the tracker's quaternion (held between updates) and the gyro's rate


def simulate(duration_s: float, seed: int, *, outages_s: tuple[tuple[float, float], ...] = (), rate_scale_rad_s: float = 0.01,
             q0: np.ndarray | None = None, bias0_rad_s: tuple[float, float, float] = BIAS0_RAD_S, substeps: int = 10) -> Run:
    """A rigid body's attitude under :func:`tumbling_rates` (integrated with ``substeps`` exact
    rotations a sample at the midpoint rate) and the project's sensor models
    (:func:`spacecraft_sim.core.sensors.measure`: 10 Hz tracker held between updates and
    through ``outages_s``, gyro with ARW, bias walk and ``bias0_rad_s``), seed ``seed``."""
    n = int(round(duration_s / DT_S))
    t = np.arange(n) * DT_S
    h = DT_S / substeps
    t_mid = (np.arange((n - 1) * substeps) + 0.5) * h
    incr = dq_rows(tumbling_rates(t_mid, rate_scale_rad_s) * h)
    q_init = np.array([0.3254, 0.4068, -0.3254, 0.7891]) if q0 is None else np.asarray(q0, dtype=np.float64)
    q_fine = cumulative_product(q_init / np.linalg.norm(q_init), incr)
    q_true = np.ascontiguousarray(q_fine[::substeps])
    omega = np.ascontiguousarray(tumbling_rates(t, rate_scale_rad_s))
    sensors = Sensors(star_tracker=StarTracker(noise_rad=TRACKER_NOISE_RAD, rate_hz=TRACKER_HZ, outages_s=outages_s),
                      gyro=Gyro(ARW_RAD_SQRT_S, BRW_RAD_S_SQRT_S, bias0_rad_s), seed=seed)
    prm = sensors.params(DT_S)
    draws = sensors.draws(n)
    outages = sensors.outages()
    held = np.zeros(4)
    bias = prm[S_BIAS0:S_BIAS0 + 3].copy()
    y = np.zeros((n, 7))
    b_true = np.zeros((n, 3))
    for k in range(n):
        b_true[k] = bias
        measure(k, t[k], q_true[k], omega[k], draws[k], prm, outages, held, bias, y[k])
    return Run(t, q_true, omega, b_true, y)


def tracker_samples(run: Run) -> np.ndarray:
    """Indices of the steps whose tracker quaternion is new (the first, and every change)."""
    changed = np.any(run.y[1:, :4] != run.y[:-1, :4], axis=1)
    return np.concatenate(([0], 1 + np.flatnonzero(changed)))


def with_outliers(run: Run, starts: list[int], angle_rad: float, axis: np.ndarray) -> Run:
    """A copy of ``run`` whose tracker samples at the steps ``starts`` (each the first step of a
    tracker sample) are rotated by ``angle_rad`` about the body ``axis``, held until the next."""
    y = run.y.copy()
    new = set(tracker_samples(run).tolist())
    offset = dq(angle_rad * np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis))
    for k in starts:
        assert k in new, k
        j = k + 1
        while j < len(y) and j not in new:
            j += 1
        y[k:j, :4] = quat_multiply(y[k, :4], offset)
    return Run(run.t_s, run.q_true, run.omega_true_rad_s, run.bias_true_rad_s, y)


# ----------------------------------------------------------------------------- running the kernel


@dataclass
class KernelRun:
    """The kernel's outputs a step: ``out`` (n, N_EST_OUT), ``status`` (n,), ``P`` (n, 6, 6) and the
    counters (updates, rejections, consecutive rejections, re-initialisations) (n, 4)."""

    out: np.ndarray
    status: np.ndarray
    P: np.ndarray
    counters: np.ndarray

    @property
    def q_hat(self) -> np.ndarray:
        return self.out[:, mekf.EO_Q:mekf.EO_Q + 4]

    @property
    def b_hat(self) -> np.ndarray:
        return self.out[:, mekf.EO_B:mekf.EO_B + 3]

    @property
    def sigma(self) -> np.ndarray:
        return self.out[:, mekf.EO_SIGMA:mekf.EO_SIGMA + 6]

    @property
    def nis(self) -> np.ndarray:
        return self.out[:, mekf.EO_NIS]


_COUNTERS = (mekf.ES_N_UPD, mekf.ES_N_REJ, mekf.ES_N_CONSEC, mekf.ES_N_REINIT)


def run_kernel(prm: np.ndarray, t_s: np.ndarray, y: np.ndarray) -> KernelRun:
    """``mekf_step`` over the samples, from a fresh state (a Python loop, ~3 us a step)."""
    n = len(t_s)
    st = mekf.new_state()
    P = np.zeros((6, 6))
    work = np.zeros((mekf.N_EST_WORK, 6))
    out = np.zeros((n, mekf.N_EST_OUT))
    status = np.zeros(n, dtype=np.int64)
    Ps = np.zeros((n, 6, 6))
    counters = np.zeros((n, 4), dtype=np.int64)
    step = mekf.mekf_step
    for k in range(n):
        status[k] = step(prm, float(t_s[k]), y[k], st, P, work, out[k])
        Ps[k] = P
        counters[k] = st[list(_COUNTERS)]
    return KernelRun(out, status, Ps, counters)


def run_oracle(prm: np.ndarray, t_s: np.ndarray, y: np.ndarray) -> tuple[list[oracle.Output], np.ndarray, np.ndarray]:
    """The oracle over the samples: its outputs, ``P`` (n, 6, 6) and counters (n, 4)."""
    f = MekfOracle.from_params(prm)
    outs, Ps, counters = [], np.zeros((len(t_s), 6, 6)), np.zeros((len(t_s), 4), dtype=np.int64)
    for k in range(len(t_s)):
        outs.append(f.step(float(t_s[k]), y[k, :4], y[k, 4:]))
        Ps[k] = f.P
        counters[k] = f.counters
    return outs, Ps, counters


def rotvec_rows(q: np.ndarray) -> np.ndarray:
    """Row-wise ``rotvec`` (the shortest rotation) of (N, 4) unit quaternions."""
    s = np.where(q[:, 3:] >= 0.0, 1.0, -1.0)
    v = s * q[:, :3]
    n = np.linalg.norm(v, axis=1, keepdims=True)
    safe = np.where(n > 0.0, n, 1.0)
    return np.where(n > 0.0, 2.0 * np.arctan2(n, s * q[:, 3:]) * v / safe, 2.0 * v / (s * q[:, 3:]))


def attitude_errors(q_hat: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """The true attitude errors ``rotvec(q_hat* ⊗ q_true)`` (N, 3) [rad], body frame."""
    conj = q_hat * np.array([-1.0, -1.0, -1.0, 1.0])
    return rotvec_rows(qmul_rows(conj, q_true))


# ----------------------------------------------------------------------------- fixed sequences

#: The parity sequences: (name, duration [s], what is done to the measurements).  Seeds fixed.
OUTAGE_S = (10.0, 30.0)
OUTLIER_STEPS = (500, 800)  # single 1-deg outliers at 5 s and 8 s
BURST_START_STEP, BURST_SAMPLES = 1500, 25  # 2.5 s of 1-deg outliers from 15 s: > 20 in a row
ONE_DEG = np.deg2rad(1.0)


def outlier_run(duration_s: float, seed: int) -> Run:
    """A tumbling run with two isolated 1-deg outliers and a 25-sample burst of them (module constants)."""
    run = simulate(duration_s, seed)
    starts = list(OUTLIER_STEPS) + [BURST_START_STEP + STRIDE * i for i in range(BURST_SAMPLES)]
    return with_outliers(run, starts, ONE_DEG, np.array([1.0, 2.0, 3.0]))


def prior_10deg(run: Run) -> np.ndarray:
    """A prior 10 deg off the truth at t = 0 (about the body axis (1, -1, 2))."""
    axis = np.array([1.0, -1.0, 2.0]) / np.sqrt(6.0)
    return quat_multiply(run.q_true[0], dq(np.deg2rad(10.0) * axis))


def parity_case(name: str) -> tuple[np.ndarray, Run]:
    """(prm, run) of a parity sequence."""
    if name == "tumbling_200s":
        return mekf_config().params(), simulate(200.0, 11)
    if name == "outage_20s":
        return mekf_config().params(), simulate(40.0, 12, outages_s=(OUTAGE_S,))
    if name == "outliers_and_burst":
        return mekf_config().params(), outlier_run(40.0, 13)
    if name == "from_prior_10deg":
        run = simulate(20.0, 14)
        return mekf_config(initial_q_BN=tuple(prior_10deg(run)), initial_attitude_sigma_rad=np.deg2rad(10.0)).params(), run
    raise ValueError(name)


# ----------------------------------------------------------------------------- (a) parity


@pytest.mark.parametrize("name", ["tumbling_200s", "outage_20s", "outliers_and_burst", "from_prior_10deg"])
def test_kernel_equals_oracle(name: str) -> None:
    """Kernel = oracle step after step: statuses and counters exactly; ``q_hat`` (sign-aligned) to
    ``PARITY_ABS`` absolute; ``b_hat`` and ``omega_hat`` so that the attitude they integrate to over
    the sequence (``|Δb| T``) stays within ``PARITY_ABS`` rad; ``P`` to ``PARITY_REL_P`` of
    ``sqrt(P_ii P_jj)``, sigma to ``PARITY_REL_P`` relative; the NIS to the bound an attitude
    difference of ``PARITY_ABS`` rad implies, ``2 sqrt(NIS) PARITY_ABS / min sigma_st`` plus
    ``PARITY_REL_P`` relative (the NIS of a ~1e-5 rad residual is a ratio of tiny numbers: an ulp
    of a unit quaternion is ~1e-11 of it)."""
    prm, run = parity_case(name)
    kr = run_kernel(prm, run.t_s, run.y)
    outs, P_or, counters_or = run_oracle(prm, run.t_s, run.y)
    status_or = np.array([oracle.STATUS.index(o.status) for o in outs])
    np.testing.assert_array_equal(kr.status, status_or)
    np.testing.assert_array_equal(kr.counters, counters_or)
    live = np.flatnonzero(status_or != mekf.STATUS_NONE)
    assert len(live) == len(run.t_s)  # from_tracker initialises at the first step (its sample is new)
    q_or = np.array([o.q_hat for o in outs])
    sign = np.where(np.sum(q_or * kr.q_hat, axis=1, keepdims=True) < 0.0, -1.0, 1.0)
    dq_max = np.max(np.abs(kr.q_hat - sign * q_or))
    duration = run.t_s[-1] - run.t_s[0]
    db_max = np.max(np.abs(kr.b_hat - np.array([o.b_hat for o in outs])))
    dw_max = np.max(np.abs(kr.out[:, mekf.EO_OMEGA:mekf.EO_OMEGA + 3] - np.array([o.omega_hat for o in outs])))
    d = np.sqrt(np.einsum("nii->ni", P_or))
    dP_rel = np.max(np.abs(kr.P - P_or) / (d[:, :, None] * d[:, None, :]))
    sig_or = np.array([o.sigma for o in outs])
    dsig_rel = np.max(np.abs(kr.sigma - sig_or) / sig_or)
    nis_or = np.array([o.nis for o in outs])
    np.testing.assert_array_equal(np.isnan(kr.nis), np.isnan(nis_or))
    ok = ~np.isnan(nis_or)
    nis_bound = 2.0 * np.sqrt(nis_or[ok]) * PARITY_ABS / min(TRACKER_NOISE_RAD) + PARITY_REL_P * nis_or[ok]
    nis_ratio = np.max(np.abs(kr.nis[ok] - nis_or[ok]) / nis_bound, initial=0.0)
    print(f"\n{name}: |dq| {dq_max:.2e}, |db| {db_max:.2e} rad/s, |domega| {dw_max:.2e} rad/s, dP/scale {dP_rel:.2e}, "
          f"dsigma/sigma {dsig_rel:.2e}, max |dNIS| {np.max(np.abs(kr.nis[ok] - nis_or[ok]), initial=0.0):.2e} "
          f"({nis_ratio:.1e} of its bound); counters {kr.counters[-1].tolist()}")
    assert dq_max <= PARITY_ABS
    assert db_max * duration <= PARITY_ABS
    assert dw_max * duration <= PARITY_ABS
    assert dP_rel <= PARITY_REL_P
    assert dsig_rel <= PARITY_REL_P
    assert nis_ratio <= 1.0

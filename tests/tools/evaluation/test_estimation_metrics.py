"""The estimation metrics (:mod:`sappc.evaluation.estimation`) against independent truths: scipy's
rotations, an explicit inverse, and the chi-square distribution's known quantiles."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from conftest import random_unit_quaternions
from sappc.evaluation.estimation import attitude_errors, nees, nees_band, rotation_vectors


def test_rotation_vectors_are_scipys_for_the_shortest_rotation(rng: np.random.Generator) -> None:
    q = random_unit_quaternions(rng, 200)
    ref = Rotation.from_quat(q).as_rotvec()  # scipy: scalar last, shortest rotation
    np.testing.assert_allclose(rotation_vectors(q), ref, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rotation_vectors(-q), ref, rtol=0, atol=1e-14)  # the same rotation
    np.testing.assert_array_equal(rotation_vectors(np.array([0.0, 0.0, 0.0, 1.0])), np.zeros(3))
    tiny = np.array([1e-20, 0.0, 0.0, 1.0])
    assert rotation_vectors(tiny)[0] == 2e-20


def test_attitude_errors_are_the_truth_relative_to_the_estimate_in_the_body_frame(rng: np.random.Generator) -> None:
    q_est = random_unit_quaternions(rng, 50)
    a = 0.01 * rng.standard_normal((50, 3))
    q_true = (Rotation.from_quat(q_est) * Rotation.from_rotvec(a)).as_quat()  # q_true = q_est ⊗ dq(a)
    np.testing.assert_allclose(attitude_errors(q_est, q_true), a, rtol=0, atol=1e-15)


def test_nees_is_the_quadratic_form_and_nan_without_an_estimate(rng: np.random.Generator) -> None:
    A = rng.standard_normal((4, 6, 6))
    P = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(6)
    e = rng.standard_normal((4, 6))
    expected = np.array([e[i] @ np.linalg.inv(P[i]) @ e[i] for i in range(4)])
    np.testing.assert_allclose(nees(e, P), expected, rtol=1e-12)
    e[2, 0] = np.nan
    out = nees(e, P)
    assert np.isnan(out[2]) and np.all(np.isfinite(out[[0, 1, 3]]))


def test_the_nees_band_is_the_chi_square_quantiles_over_runs() -> None:
    lo, hi = nees_band(1)
    assert abs(lo - 1.2373442) < 1e-6 and abs(hi - 14.449375) < 1e-5  # chi2_6 2.5 % and 97.5 % (tables)
    lo, hi = nees_band(500)
    assert 5.6 < lo < 6.0 < hi < 6.4  # narrows around the dof as runs are added


def test_the_estimation_metrics_are_the_same_for_any_blocks_and_any_batch() -> None:
    """Fed in blocks of any size, or as one run of a batch, the estimation metrics have the same bits
    (their sums run sample after sample, as the compiled metrics')."""
    from sappc.evaluation.estimation import EstimateHistory
    from sappc.evaluation.metrics import MetricsAccumulator

    rng = np.random.default_rng(9)
    T, N = 700, 3
    t = np.arange(T) * 0.01
    q_true = random_unit_quaternions(rng, T * N).reshape(T, N, 4)
    q_est = q_true + 1e-6 * rng.standard_normal((T, N, 4))
    q_est /= np.linalg.norm(q_est, axis=-1, keepdims=True)
    A = rng.standard_normal((T, N, 6, 6))
    P = 1e-12 * (A @ np.swapaxes(A, -1, -2) + np.eye(6))
    b = 1e-6 * rng.standard_normal((T, N, 3))
    est = EstimateHistory(q_BN=q_est, omega_BN_B=np.zeros((T, N, 3)), gyro_bias=b, covariance=P, nis=np.zeros((T, N)),
                          status=np.full((T, N), 3, dtype=np.int8), gyro_bias_true=b + 1e-7 * rng.standard_normal((T, N, 3)))

    def acc(n: int) -> MetricsAccumulator:
        return MetricsAccumulator(t, n, steady_from_s=2.0, settle_threshold=1e-3, t2_s=3.0, fault_windows=[])

    whole = acc(N)
    whole.update_estimate(0, t, q_true, est)
    blocks = acc(N)
    for k0, k1 in ((0, 1), (1, 333), (333, 334), (334, 700)):
        part = EstimateHistory(*(None if v is None else v[k0:k1] for v in (est.q_BN, est.omega_BN_B, est.gyro_bias, est.covariance,
                                                                           est.nis, est.status, est.gyro_bias_true)))
        blocks.update_estimate(k0, t[k0:k1], q_true[k0:k1], part)
    alone = acc(1)
    alone.update_estimate(0, t, q_true[:, 1:2], EstimateHistory(*(None if v is None else v[:, 1:2] for v in (
        est.q_BN, est.omega_BN_B, est.gyro_bias, est.covariance, est.nis, est.status, est.gyro_bias_true))))
    assert whole._estimation_metrics(1) == blocks._estimation_metrics(1) == alone._estimation_metrics(0)
    assert whole._estimation_metrics(1)["mean_nees"] is not None


def test_the_estimation_kernel_interpreted_compiled_and_against_numpys_linear_algebra(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The estimation metrics' kernel (:func:`sappc.evaluation.metrics._estimate_kernel`): its source
    run by the interpreter (``sappc report`` on a short bag without numba) gives the compiled
    kernel's bits, with samples without an estimate, a non-finite and a singular covariance, and
    without the true bias; against numpy (``attitude_errors``, and :func:`nees` by LAPACK's
    ``gesv``) the attitude metrics are within 1e-14 relative (the same formula; ``arctan2`` may be
    a SIMD implementation in numpy, within a few ulps) and each NEES within ``10 n cond(P) eps``
    (two backward-stable eliminations of a 6 x 6 system, in different operation orders)."""
    from sappc.evaluation import metrics
    from sappc.evaluation.estimation import EstimateHistory
    from sappc.evaluation.metrics import MetricsAccumulator

    rng = np.random.default_rng(21)
    T, N = 400, 3
    t = np.arange(T) * 0.05  # NEES from 5 s: samples 100 on
    q_true = random_unit_quaternions(rng, T * N).reshape(T, N, 4)
    q_est = q_true + 1e-5 * rng.standard_normal((T, N, 4))
    q_est /= np.linalg.norm(q_est, axis=-1, keepdims=True)
    q_est[:30, 0] = np.nan  # run 0 has no estimate for its first 30 samples
    A = rng.standard_normal((T, N, 6, 6))
    P = 1e-10 * (A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(6))
    P[150, 1, 2, 3] = np.nan  # one non-finite covariance: no NEES there
    P[200, 2] = 0.0  # one singular covariance: no NEES there (non-finite)
    b = 1e-6 * rng.standard_normal((T, N, 3))
    b_true = b + 1e-6 * rng.standard_normal((T, N, 3))

    def run(kernel, truth: bool) -> MetricsAccumulator:  # type: ignore[no-untyped-def]
        monkeypatch.setattr(metrics, "_estimate_function", lambda samples: kernel)
        acc = MetricsAccumulator(t, N, steady_from_s=4.0, settle_threshold=1e-3, t2_s=3.0, fault_windows=[])
        est = EstimateHistory(q_BN=q_est, omega_BN_B=np.zeros((T, N, 3)), gyro_bias=b, covariance=P, nis=np.zeros((T, N)),
                              status=np.full((T, N), 3, dtype=np.int8), gyro_bias_true=b_true if truth else None)
        for k0, k1 in ((0, 170), (170, 171), (171, T)):
            acc.update_estimate(k0, t[k0:k1], q_true[k0:k1], EstimateHistory(
                *(None if v is None else v[k0:k1] for v in (est.q_BN, est.omega_BN_B, est.gyro_bias, est.covariance, est.nis, est.status,
                                                           est.gyro_bias_true))))
        return acc

    names = ("est_att_max", "est_att_sq", "est_att_n", "est_bias_last", "est_nees_sum", "est_nees_n", "nees_sum_t", "nees_runs_t")
    interpreted = metrics._interpreted(metrics._estimate_kernel, (metrics._nees_of, metrics.rotation_vector))
    for truth in (True, False):
        a, c = run(interpreted, truth), run(metrics._estimate_kernel, truth)
        for name in names:
            x, y = getattr(a, name), getattr(c, name)
            assert (x is None and y is None) or np.asarray(x).tobytes() == np.asarray(y).tobytes(), (name, truth)
    # against numpy
    acc = run(metrics._estimate_kernel, True)
    att = attitude_errors(q_est, q_true)
    steady = (t >= 4.0 - 1e-9)[:, None] & np.all(np.isfinite(att), axis=-1)
    np.testing.assert_allclose(acc.est_att_max, np.where(steady[..., None], np.abs(att), 0.0).max(axis=0), rtol=1e-14, atol=0)
    np.testing.assert_allclose(acc.est_att_sq, np.where(steady[..., None], att * att, 0.0).sum(axis=0), rtol=1e-14, atol=0)
    assert acc.est_att_n.tolist() == steady.sum(axis=0).tolist() and acc.est_att_n[0] == T - 80  # 4 s on, run 0's estimate from 1.5 s
    ok = np.all(np.isfinite(P), axis=(-2, -1)) & (np.abs(np.linalg.det(np.where(np.isfinite(P), P, 0.0))) > 0.0)
    ok &= np.all(np.isfinite(att), axis=-1) & (t >= 5.0 - 1e-9)[:, None]
    want = np.full((T, N), np.nan)
    want[ok] = nees(np.concatenate((att, b_true - b), axis=-1)[ok], P[ok])
    cond = np.full((T, N), np.nan)
    cond[ok] = np.linalg.cond(P[ok])
    bound = 10 * 6 * cond * np.finfo(float).eps
    got = np.full((T, N), np.nan)
    for n in range(N):  # each run's NEES alone, from its accumulator's sum over one sample at a time
        for k in np.flatnonzero(ok[:, n]):
            one = MetricsAccumulator(t[k:k + 1], 1, steady_from_s=4.0, settle_threshold=1e-3, t2_s=3.0, fault_windows=[])
            one.update_estimate(0, t[k:k + 1], q_true[k:k + 1, n:n + 1], EstimateHistory(
                q_BN=q_est[k:k + 1, n:n + 1], omega_BN_B=np.zeros((1, 1, 3)), gyro_bias=b[k:k + 1, n:n + 1], covariance=P[k:k + 1, n:n + 1],
                nis=np.zeros((1, 1)), status=np.full((1, 1), 3, dtype=np.int8), gyro_bias_true=b_true[k:k + 1, n:n + 1]))
            got[k, n] = one.est_nees_sum[0] if one.est_nees_n[0] == 1 else np.nan
    assert np.all(np.abs(got[ok] - want[ok]) <= bound[ok] * np.abs(want[ok]))
    assert acc.est_nees_n.tolist() == ok.sum(axis=0).tolist() and not ok[150, 1] and not ok[200, 2]

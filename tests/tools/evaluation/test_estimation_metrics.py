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

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

"""Quaternion convention and attitude maths against independent truths (scipy, matrices, finite differences)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from conftest import random_unit_quaternions
from gnc_common import compiled
from gnc_common.attitude import (
    cross,
    error_quaternion,
    euler_to_quaternion,
    from_scalar_first,
    quat_conjugate,
    quat_kinematics,
    quat_multiply,
    quat_to_dcm_BN,
    to_scalar_first,
)

unit_quat = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 1e-3
).map(lambda v: np.asarray(v) / np.linalg.norm(v))


def dcm_BR_times(q_BR: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The compiled ``C_e v`` (:func:`gnc_common.compiled.dcm_BR_times`) row by row, (N, 3)."""
    out = np.empty(np.broadcast_shapes(q_BR.shape[:-1], v.shape[:-1]) + (3,))
    q, w = np.broadcast_to(q_BR, out.shape[:-1] + (4,)), np.broadcast_to(v, out.shape)
    for i in range(out.shape[0]):
        compiled.dcm_BR_times(np.ascontiguousarray(q[i]), np.ascontiguousarray(w[i]), out[i])
    return out


def gamma_inverse_times(q_BR: np.ndarray, x: np.ndarray, q0_floor: float) -> np.ndarray:
    """The compiled ``Gamma^-1 x`` (:func:`gnc_common.compiled.gamma_inverse_times`) row by row."""
    out = np.empty(x.shape)
    for i in range(x.shape[0]):
        compiled.gamma_inverse_times(np.ascontiguousarray(q_BR[i]), np.ascontiguousarray(x[i]), q0_floor, out[i])
    return out


def gamma_times(q_BR: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``Gamma(q_e) omega = 1/2 (q0 I + q_v^x) omega`` (eq. Jacobian), written out for the test."""
    return 0.5 * (q_BR[:, 3:] * omega + np.cross(q_BR[:, :3], omega))


vec3 = st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3).map(np.asarray)


def test_scalar_last_order_matches_ros_and_the_paper() -> None:
    # The paper's q_d(0) = [0, 0, 0, 1] is the identity: scalar last.
    q = np.array([0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(quat_multiply(q[None], q[None])[0], q)
    np.testing.assert_array_equal(to_scalar_first(q), [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(from_scalar_first([1.0, 2.0, 3.0, 4.0]), [2.0, 3.0, 4.0, 1.0])


def test_product_matches_scipy_composition(rng) -> None:
    p, q = random_unit_quaternions(rng, 50), random_unit_quaternions(rng, 50)
    expected = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
    got = quat_multiply(p, q)
    got = np.where(np.sum(got * expected, axis=1, keepdims=True) < 0, -got, got)  # q ~ -q
    np.testing.assert_allclose(got, expected, atol=1e-14)


def test_dcm_matches_scipy_and_maps_inertial_to_body(rng) -> None:
    q = random_unit_quaternions(rng, 20)
    C_BN = quat_to_dcm_BN(q)
    # scipy's matrix is the active rotation R (v_N = R v_B); C_BN = R^T.
    np.testing.assert_allclose(C_BN, np.transpose(Rotation.from_quat(q).as_matrix(), (0, 2, 1)), atol=1e-14)


def test_dcm_BR_is_C_BN_C_RN_transpose(rng) -> None:
    q_BN, q_RN = random_unit_quaternions(rng, 20), random_unit_quaternions(rng, 20)
    v = rng.standard_normal((20, 3))
    q_BR = error_quaternion(q_RN, q_BN)
    expected = np.einsum("nij,nkj,nk->ni", quat_to_dcm_BN(q_BN), quat_to_dcm_BN(q_RN), v)
    np.testing.assert_allclose(dcm_BR_times(q_BR, v), expected, atol=1e-13)


def test_error_quaternion_is_shortest_rotation(rng) -> None:
    q_BN, q_RN = random_unit_quaternions(rng, 200), random_unit_quaternions(rng, 200)
    q_BR = error_quaternion(q_RN, q_BN)
    assert np.all(q_BR[:, 3] >= 0.0)
    # and it is the same attitude as q_RN^* q_BN up to sign
    raw = quat_multiply(quat_conjugate(q_RN), q_BN)
    np.testing.assert_allclose(np.abs(np.sum(raw * q_BR, axis=1)), 1.0, atol=1e-14)
    np.testing.assert_allclose(error_quaternion(q_BN, q_BN), np.tile([0, 0, 0, 1.0], (200, 1)), atol=1e-15)


def test_kinematics_matches_exact_constant_rate_rotation() -> None:
    # For constant omega_B, q(t) = q0 (x) exp(omega t / 2): compare the derivative by central difference.
    q0 = np.array([[0.1, -0.3, 0.2, 0.9]])
    q0 /= np.linalg.norm(q0)
    w = np.array([[0.3, -0.2, 0.5]])

    def q_at(t: float) -> np.ndarray:
        ang = np.linalg.norm(w) * t
        axis = w / np.linalg.norm(w)
        return quat_multiply(q0, np.concatenate((axis * np.sin(ang / 2), [[np.cos(ang / 2)]]), axis=1))

    h = 1e-5
    fd = (q_at(h) - q_at(-h)) / (2 * h)
    np.testing.assert_allclose(quat_kinematics(q0, w), fd, atol=1e-10)  # central difference error ~ h^2 |q'''| ~ 1e-11


def test_gamma_inverse_is_the_inverse(rng) -> None:
    q = random_unit_quaternions(rng, 100)
    q = np.where(q[:, 3:] < 0, -q, q)
    q = q[q[:, 3] > 0.05]  # away from the floor
    x = rng.standard_normal((q.shape[0], 3))
    np.testing.assert_allclose(gamma_times(q, gamma_inverse_times(q, x, 1e-3)), x, atol=1e-12)
    # and Gamma as written in eq. (Jacobian): 1/2 (q0 I + q_v^x)
    G = 0.5 * (q[:, 3, None, None] * np.eye(3) + np.cross(q[:, None, :3], -np.eye(3)[None]))
    np.testing.assert_allclose(gamma_times(q, x), np.einsum("nij,nj->ni", G, x), atol=1e-15)


def test_gamma_inverse_stays_bounded_at_180_degrees() -> None:
    q = np.array([[1.0, 0.0, 0.0, 0.0], [0.6, 0.8, 0.0, 1e-300]])
    x = np.ones((2, 3))
    y = gamma_inverse_times(q, x, q0_floor=1e-3)
    assert np.all(np.isfinite(y))
    assert np.all(np.linalg.norm(y, axis=1) <= 2 * (1 + 1 / 1e-3) * np.sqrt(3))


def test_euler_angles_compose_as_scipy_does() -> None:
    """The written-out composition against scipy's ``Rotation.from_euler`` (what it replaces in the
    campaigns' draws), intrinsic and extrinsic, Tait-Bryan and proper sequences, one angle triple
    and a stack.  Bound 4e-16: both take sin and cos of the same half angles and sum the same
    products in the same order, so they agree to the last bit where both use the same libm (they
    do here); 4e-16 (two units in the last place of a component of at most 1) is what docs/parity.md
    allows a campaign's initial quaternion across hosts, whose trigonometric routines may differ."""
    from scipy.spatial.transform import Rotation

    angles = np.radians(np.random.default_rng(5).uniform(-179.0, 179.0, (2000, 3)))
    for seq in ("ZYX", "XYZ", "ZXZ", "zyx", "xzy", "yxy"):
        ref = Rotation.from_euler(seq, angles).as_quat()
        ref = np.where(ref[:, 3:] < 0.0, -ref, ref)
        assert np.max(np.abs(euler_to_quaternion(angles, seq) - ref)) <= 4e-16, seq
        one = Rotation.from_euler(seq, angles[7]).as_quat()
        assert np.max(np.abs(euler_to_quaternion(angles[7], seq) - (one if one[3] >= 0 else -one))) <= 4e-16, seq
    for bad in ("ZY", "ZZX", "ZyX", "ABC", "XYZX"):
        with pytest.raises(ValueError, match="sequence must be three axis letters"):
            euler_to_quaternion([0.1, 0.2, 0.3], bad)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        euler_to_quaternion([0.1, 0.2], "ZYX")


def test_euler_zyx_intrinsic_is_yaw_pitch_roll() -> None:
    yaw = np.radians(30.0)
    q = euler_to_quaternion([yaw, 0.0, 0.0], "ZYX")
    np.testing.assert_allclose(q, [0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)], atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(unit_quat, unit_quat, unit_quat)
def test_product_is_associative_and_norm_preserving(p, q, r) -> None:
    a = quat_multiply(quat_multiply(p[None], q[None]), r[None])
    b = quat_multiply(p[None], quat_multiply(q[None], r[None]))
    np.testing.assert_allclose(a, b, atol=1e-14)
    assert abs(np.linalg.norm(a) - 1.0) < 1e-14


@settings(max_examples=200, deadline=None)
@given(unit_quat, vec3)
def test_dcm_BR_preserves_length_and_conjugate_inverts(q, v) -> None:
    q = np.where(q[3] < 0, -q, q)[None]
    w = dcm_BR_times(q, v[None])
    assert abs(np.linalg.norm(w) - np.linalg.norm(v)) <= 1e-13 * max(1.0, np.linalg.norm(v))
    np.testing.assert_allclose(dcm_BR_times(quat_conjugate(q), w), v[None], atol=1e-12 * max(1.0, np.linalg.norm(v)))


@settings(max_examples=200, deadline=None)
@given(vec3, vec3)
def test_cross_matches_numpy(a, b) -> None:
    np.testing.assert_allclose(cross(a[None], b[None])[0], np.cross(a, b), atol=1e-12)


def test_batch_axis_any_size() -> None:
    q = np.tile([0.0, 0.0, 0.0, 1.0], (7, 1))
    assert quat_multiply(q, q).shape == (7, 4)
    with pytest.raises(ValueError):
        quat_multiply(np.zeros((3, 4)), np.zeros((2, 4)))

"""Attitude mathematics: the one quaternion convention of this project.

Convention
----------
* **Order: scalar last**, ``q = (x, y, z, w)`` with vector part ``q_v = q[..., :3]``
  and scalar part ``q_0 = q[..., 3]``.  This is the order of ROS
  ``geometry_msgs/Quaternion`` and of the numbers in the paper's simulation
  section (``q_s(0) = [0.3254, 0.4068, -0.3254, 0.7891]`` has scalar ``0.7891``).
  The paper's equations write ``q = [q0, q_v]``; only the storage order differs.
  :func:`from_scalar_first` and :func:`to_scalar_first` convert at the edges.
* **Hamilton product**, ``p ⊗ q = (p0 q_v + q0 p_v + p_v × q_v,  p0 q0 - p_v·q_v)``.
* ``q_BN`` is the attitude of frame B relative to frame N: a vector's
  components transform as ``v_N = q_BN ⊗ v_B ⊗ q_BN^*``.
* Kinematics: ``dq_BN/dt = 1/2 q_BN ⊗ (omega_BN_B, 0)`` with ``omega_BN_B`` the
  body rate relative to N in body components.
* Error quaternion (docs/paper_notes.md): ``q_BR = q_RN^* ⊗ q_BN`` (body relative to
  the desired/reference frame R), and the paper's ``C_e`` (eq. errorsystem) is
  ``C_BR``, mapping R-frame components to B-frame components.

Every function accepts a batch: a leading axis of N runs (or any leading
shape); the last axis holds the 3 or 4 components.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "cross",
    "dot",
    "error_quaternion",
    "euler_to_quaternion",
    "from_scalar_first",
    "matvec",
    "quat_conjugate",
    "quat_kinematics",
    "quat_multiply",
    "quat_normalize",
    "quat_to_dcm_BN",
    "rotation_vector_to_quaternion",
    "to_scalar_first",
]

Array = NDArray[np.float64]

# Memory layout: batch arrays are kept in Fortran order, so that each component
# is contiguous over the N runs.  numpy's inner loops then run over N instead
# of over the 3 components (a broadcast product on (3000, 3) drops from 25 us to
# 6 us); for one run the layout makes no difference.  New arrays are allocated
# with order="F" and element-wise operations preserve the order.
#
# Index permutations for the cross product: rows of the transposed (3, ...) view
# are taken, which are contiguous blocks for Fortran-ordered input (4x faster
# than np.cross on one vector, 2x faster than gathering columns for 3000 runs).
_I120 = np.array([1, 2, 0])
_I201 = np.array([2, 0, 1])

# Sums over components are written out element-wise (never matmul, einsum or
# vecdot): BLAS and the SIMD reduction kernels sum in an order that depends on
# the memory layout and on the number of rows, while every result of a run must
# be the same bit for bit whether the run is alone or inside a batch of any
# size (tests/test_controllers.py checks it).  Element-wise products and sums
# are exact IEEE operations, identical for every layout.


def dot(a: Array, b: Array) -> Array:
    """Row-wise dot product of (..., n) arrays, shape (...): ``((a0 b0 + a1 b1) + a2 b2) ...``."""
    aT: Array = a.T
    bT: Array = b.T
    acc: Array = aT[0] * bT[0]
    for i in range(1, aT.shape[0]):
        acc = acc + aT[i] * bT[i]
    row_sums: Array = acc.T
    return row_sums


def matvec(M: Array, v: Array) -> Array:
    """``M v`` per row for a shared (3, 3) or per-run (N, 3, 3) matrix and (..., 3) vectors."""
    vT: Array = v.T
    out: Array
    if M.ndim == 2:
        col = (3,) + (1,) * (vT.ndim - 1)
        out = M[:, 0].reshape(col) * vT[0] + M[:, 1].reshape(col) * vT[1] + M[:, 2].reshape(col) * vT[2]
    else:
        MT: Array = M.T  # MT[j, i, n] = M[n, i, j]
        out = MT[0] * vT[0] + MT[1] * vT[1] + MT[2] * vT[2]
    out_T: Array = out.T
    return out_T


def cross(a: Array, b: Array) -> Array:
    """Row-wise cross product ``a × b`` of (..., 3) arrays."""
    aT: Array = a.T
    bT: Array = b.T
    c: Array = (aT.take(_I120, axis=0) * bT.take(_I201, axis=0) - aT.take(_I201, axis=0) * bT.take(_I120, axis=0)).T
    return c


def from_scalar_first(q_wxyz: ArrayLike) -> Array:
    """Reorder ``(w, x, y, z)`` quaternions to this project's ``(x, y, z, w)``."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    return np.concatenate((q[..., 1:], q[..., :1]), axis=-1)


def to_scalar_first(q_xyzw: ArrayLike) -> Array:
    """Reorder this project's ``(x, y, z, w)`` quaternions to ``(w, x, y, z)``."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    return np.concatenate((q[..., 3:], q[..., :3]), axis=-1)


def quat_multiply(p: Array, q: Array) -> Array:
    """Hamilton product ``p ⊗ q`` of scalar-last quaternions, shape (..., 4)."""
    pv, p0 = p[..., :3], p[..., 3:]
    qv, q0 = q[..., :3], q[..., 3:]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape), order="F")
    out[..., :3] = p0 * qv + q0 * pv + cross(pv, qv)
    out[..., 3] = p0[..., 0] * q0[..., 0] - dot(pv, qv)
    return out


def quat_conjugate(q: Array) -> Array:
    """Conjugate (inverse of a unit quaternion): ``(-q_v, q_0)``."""
    conj: Array = q * np.array([-1.0, -1.0, -1.0, 1.0])
    return conj


def quat_normalize(q: Array) -> Array:
    """Scale quaternions to unit norm (the caller guarantees a non-zero norm)."""
    return q / np.sqrt(dot(q, q))[..., None]


def rotation_vector_to_quaternion(rotvec: Array) -> Array:
    """Unit quaternions ``(axis sin(angle/2), cos(angle/2))`` of rotation vectors ``rotvec`` [rad],
    shape (..., 3) -> (..., 4); the zero vector gives the identity."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = np.sqrt(dot(rotvec, rotvec))[..., None]
    safe = np.where(angle > 0.0, angle, 1.0)
    return np.concatenate((rotvec * (np.sin(angle / 2.0) / safe), np.cos(angle / 2.0)), axis=-1)


def error_quaternion(q_RN: Array, q_BN: Array) -> Array:
    """Attitude error ``q_BR = q_RN^* ⊗ q_BN`` with the scalar part kept ``>= 0``.

    ``q`` and ``-q`` describe the same attitude; keeping ``q_0 >= 0`` selects
    the shortest rotation (angle <= 180 deg).  When the true error passes
    through 180 deg the returned vector part flips sign: the error is then
    measured the short way round from the other side.  ``q_0 = 0`` exactly
    (180 deg) is the singular point of the paper's Jacobian (docs/paper_notes.md, error 5);
    the controllers guard it (see ``sappc_controller.core.sappc``).
    """
    q_BR = quat_multiply(quat_conjugate(q_RN), q_BN)
    return np.where(q_BR[..., 3:] < 0.0, -q_BR, q_BR)


def quat_to_dcm_BN(q_BN: Array) -> Array:
    """Direction cosine matrix ``C_BN`` (N components -> B components), shape (..., 3, 3)."""
    qv, q0 = q_BN[..., :3], q_BN[..., 3]
    x, y, z = qv[..., 0], qv[..., 1], qv[..., 2]
    c = np.empty(q_BN.shape[:-1] + (3, 3))
    c[..., 0, 0] = q0**2 + x**2 - y**2 - z**2
    c[..., 0, 1] = 2 * (x * y + q0 * z)
    c[..., 0, 2] = 2 * (x * z - q0 * y)
    c[..., 1, 0] = 2 * (x * y - q0 * z)
    c[..., 1, 1] = q0**2 - x**2 + y**2 - z**2
    c[..., 1, 2] = 2 * (y * z + q0 * x)
    c[..., 2, 0] = 2 * (x * z + q0 * y)
    c[..., 2, 1] = 2 * (y * z - q0 * x)
    c[..., 2, 2] = q0**2 - x**2 - y**2 + z**2
    return c


def quat_kinematics(q_BN: Array, omega_BN_B: Array) -> Array:
    """``dq_BN/dt = 1/2 q_BN ⊗ (omega_BN_B, 0)``, shape (..., 4)."""
    qv, q0 = q_BN[..., :3], q_BN[..., 3:]
    out = np.empty(np.broadcast_shapes(q_BN.shape[:-1], omega_BN_B.shape[:-1]) + (4,), order="F")
    out[..., :3] = 0.5 * (q0 * omega_BN_B + cross(qv, omega_BN_B))
    out[..., 3] = -0.5 * dot(qv, omega_BN_B)
    return out


def euler_to_quaternion(angles_rad: ArrayLike, sequence: str) -> Array:
    """Quaternion ``q_BN`` (scalar last, ``q_0 >= 0``) from Euler angles about body axes.

    Parameters
    ----------
    angles_rad : array_like, shape (..., 3)
        Rotation angles in radians, applied in the order of ``sequence``.
    sequence : str
        Three axis letters, consecutive ones different; upper case (e.g. ``"ZYX"``) for intrinsic
        rotations about the moving body axes, lower case for extrinsic rotations about fixed axes
        (scipy's convention).

    Notes
    -----
    The composition of scipy's ``Rotation.from_euler`` (whose quaternions are also scalar last
    and represent the active rotation taking N to B, i.e. ``q_BN`` in this module's sense),
    written out so that a campaign does not import ``scipy.spatial`` (0.3-0.9 s): each elementary
    rotation is ``(sin(a/2) e_axis, cos(a/2))`` with the platform's ``libm`` (``math``), and they
    are composed by the Hamilton product summed as scipy sums it, intrinsic sequences on the right
    and extrinsic ones on the left.  ``tests/ground/test_attitude.py`` compares it with scipy.
    """
    seq = str(sequence)
    if len(seq) != 3 or not (seq.isupper() or seq.islower()) or set(seq.lower()) - set("xyz") or seq[0] == seq[1] or seq[1] == seq[2]:
        raise ValueError(f"sequence must be three axis letters of 'xyz' (all upper case: intrinsic, all lower case: extrinsic), "
                         f"consecutive ones different, got {sequence!r}")
    angles = np.asarray(angles_rad, dtype=np.float64)
    if angles.shape[-1:] != (3,):
        raise ValueError(f"angles_rad must have shape (..., 3), got {angles.shape}")
    half = angles.reshape(-1, 3) / 2.0
    s = np.array([math.sin(a) for a in half.ravel()]).reshape(half.shape)  # libm, as scipy's compiled from_euler
    c = np.array([math.cos(a) for a in half.ravel()]).reshape(half.shape)
    elementary = np.zeros((3,) + half.shape[:1] + (4,))
    for i, axis in enumerate(seq.lower()):
        elementary[i, :, 3] = c[:, i]
        elementary[i, :, "xyz".index(axis)] = s[:, i]
    q = elementary[0]
    for e in elementary[1:]:
        q = _compose(q, e) if seq.isupper() else _compose(e, q)
    q = q.reshape(angles.shape[:-1] + (4,))
    out: Array = np.where(q[..., 3:] < 0.0, -q, q)
    return out


def _compose(p: Array, q: Array) -> Array:
    """Hamilton product ``p ⊗ q`` of quaternion stacks (N, 4), summed as scipy's ``compose_quat``."""
    c0 = p[:, 1] * q[:, 2] - p[:, 2] * q[:, 1]
    c1 = p[:, 2] * q[:, 0] - p[:, 0] * q[:, 2]
    c2 = p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]
    return np.stack([p[:, 3] * q[:, 0] + q[:, 3] * p[:, 0] + c0, p[:, 3] * q[:, 1] + q[:, 3] * p[:, 1] + c1,
                     p[:, 3] * q[:, 2] + q[:, 3] * p[:, 2] + c2,
                     p[:, 3] * q[:, 3] - p[:, 0] * q[:, 0] - p[:, 1] * q[:, 1] - p[:, 2] * q[:, 2]], axis=-1)

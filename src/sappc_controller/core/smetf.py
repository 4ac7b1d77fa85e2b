"""Shear-mapping-based error transformation function (SMETF, eqs. Rs, solve, chosenfunction, P0PS, PS).

With the paper's base transformation (eq. chosenfunction, ``a = delta``, ``b = 1``)

    R(z0) = tan( pi (z0 - 1) / (2 delta) ),     z0 in (1 - delta, 1 + delta),

the SMETF value ``eps = R_s(z_s)`` is defined implicitly (eq. Rs, eq. solve) by

    z0 + tan(theta) R(z0) = z_s,    eps = R(z0).

Solver
------
Write ``a = 2 delta / pi``, ``k = tan(theta)`` and ``w = z_s - 1``.  Since
``z0 - 1 = a arctan(eps)``, eq. (solve) is, in ``eps``,

    h(eps) = a arctan(eps) + k eps = w.

``h`` is odd, strictly increasing with ``k <= h' <= a + k``, and concave on
``eps >= 0``, so the root is unique for every finite ``z_s`` and every
``delta > 0``: the transformation is global (no singularity, the point of the
paper).  The solver works on ``|w|`` and restores the sign.  Cold, it starts
from ``lower = max(|w| / (a + k), (|w| - a pi / 2) / k)``, a lower bound of the
root (from ``arctan x <= x`` and ``arctan x < pi / 2``), from which Newton's
iterates increase monotonically to the root (a concave increasing function's
tangent lies above it).  Warm (the controller passes a first-order prediction
from the previous sample), it starts from ``max(guess, lower)``: from above the
root one Newton step lands at or below it, and every iterate is raised to
``lower``, so the same monotone argument applies after the first step.  It
stops when ``|h(eps) - |w||`` is within 4 ulps of the terms' magnitude; cold,
over ``|w|`` in [1e-16, 1e12] and ``delta`` in [1e-8, 1e10], that takes at most
12 iterations, warm 1 to 3 (``tests/test_smetf.py`` checks the first and that
any guess gives the same root).  ``_MAX_NEWTON_ITERATIONS`` bounds the loop.

Derivatives
-----------
* ``P_s = d eps / d z_s = P_0 / (1 + k P_0)`` (eq. P0PS) with
  ``P_0 = (1 + eps^2) / a`` (eq. P0i); evaluated as ``1 / (k + a / (1 + eps^2))``,
  which cannot overflow.  Same as eq. (PS).
* ``d eps / d delta`` (docs/paper_notes.md, error 3): implicit differentiation of
  ``h(eps, delta) = w`` gives ``(2/pi) arctan(eps) + h_eps d eps/d delta = 0``, so
  ``d eps / d delta = -(2/pi) arctan(eps) P_s = -((z0 - 1)/delta) P_s``.  This
  equals ``R_delta / (1 + k R_z)`` of docs/paper_notes.md; the paper's ``d eps_0 / d delta``
  misses the denominator.  The
  sign claim of eq. (SupControl) still holds: ``eps d eps/d delta <= 0``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["smetf", "smetf_derivatives"]

Array = NDArray[np.float64]

#: Iteration cap of the Newton solver; 12 iterations suffice over the tested
#: range (see module docstring), the cap only bounds pathological inputs.
_MAX_NEWTON_ITERATIONS = 60
#: Stopping tolerance in units of the float64 epsilon times the magnitude of
#: the terms of h(eps) - |w|: below this the residual is rounding noise.
_RESIDUAL_ULPS = 4.0
_EPS64 = float(np.finfo(np.float64).eps)
_TWO_OVER_PI = 2.0 / np.pi


def smetf(z_s: Array, delta: Array, tan_theta: float, eps_guess: Array | None = None) -> tuple[Array, Array]:
    """Solve eq. (solve) for the transformed error.

    Parameters
    ----------
    z_s : ndarray
        Auxiliary variable ``e / rho`` (any finite value).
    delta : ndarray
        Constraint half-width in ``z`` (``> 0``), broadcastable with ``z_s``.
    tan_theta : float
        ``tan(theta)`` of the shear angle, ``> 0``.
    eps_guess : ndarray, optional
        A warm start (a prediction from the previous sample).  Any finite value
        is safe: a guess below the lower bound (or of the wrong sign) is raised
        to it; from a guess above the root one Newton step lands at or below
        the root of the concave ``h`` (its tangent lies above it), and every
        iterate is raised to the lower bound, so the monotone convergence
        argument holds.  Only the number of iterations depends on the guess;
        the root is the same to 4 ulps.

    Returns
    -------
    eps : ndarray
        ``eps_s = eps_0 = R(z0)``.
    z0_offset : ndarray
        ``z0 - 1 = a arctan(eps)``: the pre-image ``z0`` of eq. (Rs) relative to
        the band centre, so that ``1 + z0_offset + eps tan(theta) = z_s``.
        Returned as an offset because ``z0 - 1`` is what the derivatives need
        and it is exact where ``1 + (z0 - 1)`` would round.
    """
    a = _TWO_OVER_PI * delta
    w = z_s - 1.0
    abs_w = np.abs(w)
    k = tan_theta
    lower = np.maximum(abs_w / (a + k), (abs_w - a * (np.pi / 2.0)) / k)
    eps = lower if eps_guess is None else np.maximum(eps_guess * np.sign(w), lower)
    for _ in range(_MAX_NEWTON_ITERATIONS):
        a_atan = a * np.arctan(eps)
        k_eps = k * eps
        resid = a_atan + k_eps - abs_w
        active = np.abs(resid) > (_RESIDUAL_ULPS * _EPS64) * (a_atan + k_eps + abs_w)
        if not active.any():
            break
        # Newton step, raised to the lower bound: from above the root the step lands at or
        # below it (concavity), from below the iterates increase monotonically to it.
        eps = np.maximum(eps - np.where(active, resid / (a / (1.0 + eps * eps) + k), 0.0), lower)
    # a_atan belongs to the final eps (the loop exits right after computing it)
    return np.copysign(eps, w), np.copysign(a_atan, w)


def smetf_derivatives(eps: Array, z0_offset: Array, delta: Array, tan_theta: float) -> tuple[Array, Array]:
    """Partial derivatives of ``eps_s(z_s, delta)`` at the solution ``(eps, z0 - 1)`` of :func:`smetf`.

    Returns
    -------
    P_s : ndarray
        ``d eps_s / d z_s`` (eq. PS).
    d_eps_d_delta : ndarray
        ``d eps_s / d delta = -(2/pi) arctan(eps) P_s = -((z0 - 1) / delta) P_s``,
        exact (docs/paper_notes.md, error 3).
    """
    P_s = 1.0 / (tan_theta + (_TWO_OVER_PI * delta) / (1.0 + eps * eps))
    return P_s, -(z0_offset / delta) * P_s

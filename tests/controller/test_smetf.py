"""SMETF (eqs. Rs, solve, PS; docs/paper_notes.md, error 3): global solvability, shear identity,
derivatives, of the compiled solver (``kernels.smetf_solve``, ``kernels.smetf_derivatives``)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sappc_controller.core import kernels as K

TAN10 = float(np.tan(np.radians(10.0)))
#: Shear identity tolerance: 1e-12 relative to the magnitude of the terms (issue requirement).
SHEAR_RTOL = 1e-12


def _solve(z_s, delta, k, guess=None):  # type: ignore[no-untyped-def]
    """The compiled solver element by element: ``eps``, ``z0 - 1`` and the Newton steps taken."""
    z_s, delta = np.broadcast_arrays(np.asarray(z_s, dtype=float), np.asarray(delta, dtype=float))
    g = np.zeros(z_s.shape) if guess is None else np.broadcast_to(np.asarray(guess, dtype=float), z_s.shape)
    eps, offset, steps = np.empty(z_s.shape), np.empty(z_s.shape), np.empty(z_s.shape, dtype=int)
    for i in np.ndindex(z_s.shape):
        eps[i], offset[i], steps[i] = K.smetf_solve(float(z_s[i]), float(delta[i]), float(k), guess is not None, float(g[i]))
    return eps, offset, steps


def smetf(z_s, delta, k, guess=None):  # type: ignore[no-untyped-def]
    """``eps`` and ``z0 - 1`` of the compiled solver, elementwise."""
    return _solve(z_s, delta, k, guess)[:2]


def smetf_derivatives(eps, z0_offset, delta, k):  # type: ignore[no-untyped-def]
    """``P_s`` and ``d eps / d delta`` of the compiled ``smetf_derivatives``, elementwise."""
    out = [K.smetf_derivatives(float(e), float(o), float(d), float(k)) for e, o, d in zip(*np.broadcast_arrays(eps, z0_offset, delta))]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


def _shear_residual(z_s, delta, k):  # type: ignore[no-untyped-def]
    eps, offset = smetf(z_s, delta, k)
    z0 = 1.0 + offset
    scale = np.maximum.reduce([np.ones_like(z_s), np.abs(z_s), np.abs(z0), np.abs(eps * k)])
    return eps, z0, np.abs(z0 + eps * k - z_s) / scale


def test_shear_identity_and_base_map_over_the_whole_range() -> None:
    mag = np.concatenate(([0.0], np.logspace(-16, 12, 300)))
    z_s = np.concatenate((1.0 - mag, 1.0 + mag, -mag, mag))
    delta = np.logspace(-8, 10, 120)
    Z, D = np.meshgrid(z_s, delta)
    eps, z0, rel = _shear_residual(Z, D, TAN10)
    assert np.all(np.isfinite(eps)) and np.all(np.isfinite(z0))
    assert rel.max() <= SHEAR_RTOL
    # eps = R(z0) = tan(pi (z0 - 1) / (2 delta)) (eq. chosenfunction).  Recomputing eps from the
    # rounded z0 amplifies z0's rounding (4 ulp of max(1, |z0|)) by dR/dz0 = pi (1 + eps^2) / (2 delta):
    # the comparison allows exactly that, plus 1e-12 relative.
    inside = np.abs(eps) < 1e3
    e, z, d = eps[inside], z0[inside], D[inside]
    allowed = 1e-12 * np.abs(e) + 4 * np.finfo(float).eps * np.maximum(1.0, np.abs(z)) * np.pi * (1 + e**2) / (2 * d)
    assert np.all(np.abs(np.tan(np.pi * (z - 1.0) / (2.0 * d)) - e) <= allowed)


def test_finite_at_huge_inputs() -> None:
    z_s = np.array([1e12, -1e12, 1e12 + 1.0])
    for delta in (1e-12, 1.0, 1e12):
        eps, z0, rel = _shear_residual(z_s, np.full(3, delta), TAN10)
        assert np.all(np.isfinite(eps)) and np.all(np.isfinite(z0)) and rel.max() <= SHEAR_RTOL
        P_s, d = smetf_derivatives(eps, z0 - 1.0, np.full(3, delta), TAN10)
        assert np.all(np.isfinite(P_s)) and np.all(np.isfinite(d))


def test_newton_iterations_stay_small() -> None:
    z = np.concatenate((1 - np.logspace(-16, 12, 200), 1 + np.logspace(-16, 12, 200)))
    Z, D = np.meshgrid(z, np.logspace(-8, 10, 100))
    _, _, steps = _solve(Z, D, TAN10)
    # at most 12 Newton steps over this grid (cold start); the last of 13 arctan evaluations confirms convergence
    assert steps.max() <= 12


def test_warm_start_takes_one_to_three_steps_along_a_run() -> None:
    """The controller's warm start (a first-order prediction from the previous sample) along a
    smooth z_s, delta: 1 to 3 Newton steps (module docstring of kernels)."""
    t = np.linspace(0.0, 5.0, 501)
    z_s, delta = 1.0 + 0.8 * np.sin(t) + 0.1 * t, 0.5 + 0.2 * np.cos(0.5 * t)
    eps, offset, _ = _solve(z_s[:1], delta[:1], TAN10)
    prev = (eps[0], *smetf_derivatives(eps, offset, delta[:1], TAN10))
    worst = 0
    for n in range(1, t.size):
        P_s, d = prev[1][0], prev[2][0]
        guess = prev[0] + P_s * (z_s[n] - z_s[n - 1]) + d * (delta[n] - delta[n - 1])
        e, o, steps = _solve(z_s[n : n + 1], delta[n : n + 1], TAN10, guess)
        worst = max(worst, int(steps[0]))
        prev = (e[0], *smetf_derivatives(e, o, delta[n : n + 1], TAN10))
    assert worst <= 3


def test_P_s_and_d_eps_d_delta_match_finite_differences() -> None:
    rng = np.random.default_rng(3)
    z_s = np.concatenate((rng.uniform(-5, 7, 200), 1 + rng.uniform(-1e-3, 1e-3, 50)))
    delta = np.concatenate((rng.uniform(0.01, 5, 200), rng.uniform(1.0, 1e3, 50)))
    eps, offset = smetf(z_s, delta, TAN10)
    P_s, d_eps_d_delta = smetf_derivatives(eps, offset, delta, TAN10)
    h_z = 1e-6 * np.maximum(1.0, np.abs(z_s))
    fd_z = (smetf(z_s + h_z, delta, TAN10)[0] - smetf(z_s - h_z, delta, TAN10)[0]) / (2 * h_z)
    h_d = 1e-6 * delta
    fd_d = (smetf(z_s, delta + h_d, TAN10)[0] - smetf(z_s, delta - h_d, TAN10)[0]) / (2 * h_d)
    # central differences: truncation ~h^2, rounding ~1e-16/h ~ 1e-10 relative
    np.testing.assert_allclose(P_s, fd_z, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(d_eps_d_delta, fd_d, rtol=1e-6, atol=1e-10)
    # eq. (PS) as printed in the paper
    paper_P_s = np.pi * (eps**2 + 1) / (np.pi * (eps**2 + 1) * TAN10 + 2 * delta)
    np.testing.assert_allclose(P_s, paper_P_s, rtol=1e-13)


def test_paper_d_eps_d_delta_misses_the_denominator() -> None:
    # docs/paper_notes.md, error 3: the paper's d eps_0 / d delta equals the exact value times (1 + R_z tan(theta)).
    z_s, delta = np.array([1.3, 0.4, 5.0]), np.array([0.5, 0.8, 2.0])
    eps, offset = smetf(z_s, delta, TAN10)
    z0 = 1.0 + offset
    P_s, exact = smetf_derivatives(eps, offset, delta, TAN10)
    paper = (np.pi / 2) * (eps**2 + 1) * (z0 - 1) * (-1 / delta**2)
    P0 = np.pi / (2 * delta) * (eps**2 + 1)
    np.testing.assert_allclose(paper / (1 + P0 * TAN10), exact, rtol=1e-12)
    assert np.all(np.abs(paper) > np.abs(exact) * 1.01)


def test_sign_property_of_eq_supcontrol() -> None:
    z_s = np.linspace(-10, 12, 1001)
    eps, offset = smetf(z_s, np.full_like(z_s, 0.7), TAN10)
    _, d = smetf_derivatives(eps, offset, np.full_like(z_s, 0.7), TAN10)
    assert np.all(eps * d <= 0.0)  # with delta_dot >= 0: eps^T xi <= 0
    assert np.all(np.diff(eps) > 0)  # R_s is strictly increasing


def test_theta_to_zero_recovers_the_base_map_inside_the_band() -> None:
    z_s = np.array([0.9, 1.0, 1.2])
    eps, _ = smetf(z_s, np.full(3, 0.5), 1e-12)
    np.testing.assert_allclose(eps, np.tan(np.pi * (z_s - 1) / (2 * 0.5)), rtol=1e-9, atol=1e-15)


@settings(max_examples=500, deadline=None)
@given(
    z_s=st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False),
    delta=st.floats(1e-9, 1e9, allow_nan=False),
    theta_deg=st.floats(1.0, 80.0),
)
def test_property_global_solution(z_s, delta, theta_deg) -> None:
    k = float(np.tan(np.radians(theta_deg)))
    eps, z0, rel = _shear_residual(np.array([z_s]), np.array([delta]), k)
    assert np.isfinite(eps[0]) and rel[0] <= SHEAR_RTOL
    assert 1 - delta <= z0[0] <= 1 + delta  # the pre-image lies in the base map's domain
    P_s, _ = smetf_derivatives(eps, z0 - 1.0, np.array([delta]), k)
    assert 0.0 < P_s[0] <= 1.0 / k * (1 + 1e-15)  # slope bounded by 1/tan(theta): no singularity


def test_any_warm_start_gives_the_same_root() -> None:
    rng = np.random.default_rng(11)
    z_s = np.concatenate((rng.uniform(-50, 50, 500), 1 + rng.uniform(-1e-4, 1e-4, 100)))
    delta = rng.uniform(1e-3, 1e3, z_s.size)
    cold, _ = smetf(z_s, delta, TAN10)
    for guess in (np.zeros_like(z_s), -cold, 10 * cold, cold + rng.normal(0, 1, z_s.size), np.full_like(z_s, 1e12)):
        warm, offset = smetf(z_s, delta, TAN10, guess)
        np.testing.assert_allclose(warm, cold, rtol=1e-14, atol=1e-300)
        assert np.all(np.abs(1.0 + offset + warm * TAN10 - z_s) <= SHEAR_RTOL * np.maximum(1, np.abs(z_s)))

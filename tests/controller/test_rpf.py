"""RPF (eq. RPF, docs/paper_notes.md, errors 1 and 2) and the time-varying constraint (eq. delta_i):
the set-up (coefficients by Lambert W, feasibility) in Python, the evaluation compiled
(``kernels.rpf_evaluate``, fed by ``packing.rpf_coef``), as the law uses them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from controller.oracle import constraint_bound
from sappc_controller.core import kernels as K
from sappc_controller.core import packing as KP
from sappc_controller.core.rpf import (
    InfeasibleRPFError,
    ReferencePerformanceFunction,
    RPFParameters,
    feasible_l_range,
)
from sappc_controller.core.sappc import BacksteppingGains, SappcConfig
from gnc_common.validation import ConfigError

TABLE1 = dict(rho_e0=0.4, rho_einf=1e-6, t2_s=20.0, g_inf=3e-5)
E0_EXP1 = [0.3254, 0.4068, -0.3254]


def _evaluate(r: ReferencePerformanceFunction, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``rho``, ``rho_dot`` (N, 3) of the compiled ``kernels.rpf_evaluate`` with the run constants of
    ``packing.rpf_coef`` and the parameters packed from a SAPPC config holding ``r.params``."""
    cfg = SappcConfig(((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), r.params, B0=0.01, gains=BacksteppingGains(1.0, 1.0, 0.0, 1.0))
    prm, coef = KP.pack_params(cfg)[0], KP.rpf_coef(r)
    rho, rho_dot = np.empty(r.sign.shape), np.empty(r.sign.shape)
    for n in range(coef.shape[0]):
        for i in range(3):
            rho[n, i], rho_dot[n, i] = K.rpf_evaluate(prm, coef[n], float(t), i)
    return rho, rho_dot


def _pieces(r: ReferencePerformanceFunction, p: RPFParameters):  # type: ignore[no-untyped-def]
    """The exponential and parabolic pieces and their slopes, evaluated independently of the kernel."""
    A = r.rho_e0 - p.rho_einf

    def expo(t):  # type: ignore[no-untyped-def]
        return A * np.exp(-r.l * t) + p.rho_einf, -r.l * A * np.exp(-r.l * t)

    def para(t):  # type: ignore[no-untyped-def]
        return r.a1 * (t - p.t2_s) ** 2 + p.g_inf, 2 * r.a1 * (t - p.t2_s)

    return expo, para


def test_table1_is_infeasible_with_a_message_naming_l_and_the_range() -> None:
    with pytest.raises(InfeasibleRPFError) as info:
        RPFParameters(l=0.5, **TABLE1)
    msg = str(info.value)
    assert "rpf.l = 0.5" in msg and "0.0999927 <= l <= 0.491939" in msg
    assert isinstance(info.value, ValueError)


def test_upper_bound_is_the_closed_form_of_spec_notes() -> None:
    lower, upper = feasible_l_range(0.4, 1e-6, 3e-5, 20.0)
    A, G = 0.4 - 1e-6, 3e-5 - 1e-6
    assert upper == pytest.approx(np.log(np.e * A / (2 * G)) / 20.0, rel=1e-15)
    assert upper == pytest.approx(0.49194, abs=1e-5)
    # just inside and just outside the bound
    RPFParameters(l=float(upper) * (1 - 1e-9), **TABLE1)
    with pytest.raises(InfeasibleRPFError):
        RPFParameters(l=float(upper) * (1 + 1e-6), **TABLE1)
    with pytest.raises(InfeasibleRPFError):
        RPFParameters(l=float(lower) * (1 - 1e-6), **TABLE1)


@pytest.mark.parametrize("l", [0.49, 0.4919, 0.3, 0.2, 0.1])
def test_value_and_slope_are_continuous_at_t1_and_t2(l) -> None:
    p = RPFParameters(l=l, **TABLE1)
    r = ReferencePerformanceFunction(p, E0_EXP1)
    expo, para = _pieces(r, p)
    t1 = r.t1[0, 0]
    assert 0.0 <= t1 < p.t2_s
    v_e, s_e = expo(t1)
    v_p, s_p = para(t1)
    # value and slope continuity at t1: relative 1e-12 of the value / slope scale
    assert abs(v_e[0, 0] - v_p[0, 0]) <= 1e-12 * v_e[0, 0]
    assert abs(s_e[0, 0] - s_p[0, 0]) <= 1e-11 * abs(s_e[0, 0])
    # at t2 the parabola lands on g_inf with zero slope
    v2, s2 = para(p.t2_s)
    assert v2[0, 0] == pytest.approx(p.g_inf, rel=1e-15) and s2[0, 0] == 0.0
    # the compiled evaluation agrees with the pieces on each side
    for t in (0.5 * t1, t1, 0.5 * (t1 + p.t2_s), p.t2_s, p.t2_s + 5):
        rho, rho_dot = _evaluate(r, t)
        ref = expo(t) if t < t1 else para(t) if t < p.t2_s else (np.full((1, 3), p.g_inf), np.zeros((1, 3)))
        np.testing.assert_allclose(np.abs(rho), ref[0], rtol=1e-14)
        np.testing.assert_allclose(np.abs(rho_dot), np.abs(ref[1]), rtol=1e-13, atol=1e-300)


def test_derivative_matches_finite_differences() -> None:
    r = ReferencePerformanceFunction(RPFParameters(l=0.49, **TABLE1), E0_EXP1)
    h = 1e-6
    for t in np.linspace(0.1, 25.0, 57):
        fd = (_evaluate(r, t + h)[0] - _evaluate(r, t - h)[0]) / (2 * h)
        # central difference error h^2 |rho'''| / 6 <= 1e-13 here; 1e-9 absolute covers rounding of rho / h
        np.testing.assert_allclose(_evaluate(r, t)[1], fd, atol=1e-9)


def test_root_rule_is_the_earliest_switch_time() -> None:
    p = RPFParameters(l=0.49, **TABLE1)
    r = ReferencePerformanceFunction(p, [[0.4, 0.4, 0.4]])
    A, G = 0.4 - 1e-6, 3e-5 - 1e-6
    s = np.linspace(1e-6, p.t2_s, 2_000_001)
    f = A * np.exp(-p.l * (p.t2_s - s)) * (1 - p.l * s / 2) - G
    roots = s[:-1][np.sign(f[:-1]) != np.sign(f[1:])]
    assert roots.size == 2  # two roots, one each side of s = 1/l
    assert p.t2_s - r.t1[0, 0] == pytest.approx(roots.max(), abs=1e-5)  # grid spacing 1e-5


def test_sign_follows_the_initial_error() -> None:
    r = ReferencePerformanceFunction(RPFParameters(l=0.49, **TABLE1), [0.3, -0.2, 0.0])
    np.testing.assert_array_equal(r.sign, [[1.0, -1.0, 1.0]])
    rho, rho_dot = _evaluate(r, 1.0)
    assert rho[0, 0] > 0 > rho_dot[0, 0] and rho[0, 1] < 0 < rho_dot[0, 1]


def test_initial_error_at_or_below_terminal_value_gives_a_flat_rpf() -> None:
    p = RPFParameters(rho_e0=None, rho_einf=1e-6, l=0.2, t2_s=20.0, g_inf=3e-5)
    r = ReferencePerformanceFunction(p, [[3e-5, -1e-5, 0.0]])
    assert r.flat.all()
    for t in (0.0, 5.0, 19.9, 20.0, 30.0):
        rho, rho_dot = _evaluate(r, t)
        np.testing.assert_array_equal(rho, [[3e-5, -3e-5, 3e-5]])
        np.testing.assert_array_equal(rho_dot, np.zeros((1, 3)))


def test_small_initial_error_with_auto_rho_e0_is_infeasible_unless_clamped() -> None:
    p = RPFParameters(rho_e0=None, rho_einf=1e-6, l=0.2, t2_s=20.0, g_inf=3e-5)
    with pytest.raises(InfeasibleRPFError, match=r"rpf.l = 0.2 .*\(run 0, component 1\)"):
        ReferencePerformanceFunction(p, [[0.3, 5e-4, -0.2]])
    r = ReferencePerformanceFunction(p, [[0.3, 5e-4, -0.2]], on_infeasible="clamp")
    np.testing.assert_array_equal(r.clamped, [[False, True, False]])
    _, upper = feasible_l_range(5e-4, 1e-6, 3e-5, 20.0)
    assert r.l[0, 1] == upper and r.l[0, 0] == 0.2
    rho0, _ = _evaluate(r, 0.0)
    rho2, _ = _evaluate(r, 20.0)
    np.testing.assert_allclose(np.abs(rho0), [[0.3, 5e-4, 0.2]], rtol=1e-12)
    np.testing.assert_allclose(np.abs(rho2), 3e-5, rtol=1e-15)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(rho_e0=0.4, rho_einf=3e-5, l=0.2, t2_s=20.0, g_inf=3e-5), "rho_einf"),
        (dict(rho_e0=-0.4, rho_einf=1e-6, l=0.2, t2_s=20.0, g_inf=3e-5), "rho_e0"),
        (dict(rho_e0=0.4, rho_einf=1e-6, l=float("nan"), t2_s=20.0, g_inf=3e-5), "rpf.l"),
        (dict(rho_e0=0.4, rho_einf=1e-6, l=0.2, t2_s=0.0, g_inf=3e-5), "t2_s"),
    ],
)
def test_bad_parameters_name_the_key(kwargs, key) -> None:
    with pytest.raises(ConfigError, match=key):
        RPFParameters(**kwargs)


def test_constraint_is_a_tube_of_half_width_B0() -> None:
    r = ReferencePerformanceFunction(RPFParameters(l=0.49, **TABLE1), E0_EXP1)
    B0 = 0.016
    for t in (0.0, 3.0, 18.0, 25.0):
        rho, rho_dot = _evaluate(r, t)
        delta, delta_dot = constraint_bound(B0, rho, rho_dot)  # the oracle's eq. (delta_i), on the compiled RPF
        np.testing.assert_allclose(delta * np.abs(rho), B0, rtol=1e-15)
        assert np.all(delta_dot >= 0.0)
        h = 1e-6
        fd = (constraint_bound(B0, *_evaluate(r, t + h))[0] - constraint_bound(B0, *_evaluate(r, t - h))[0]) / (2 * h) if t > 0 else delta_dot
        np.testing.assert_allclose(delta_dot, fd, rtol=1e-6)


@settings(max_examples=300, deadline=None)
@given(
    rho_e0=st.floats(1e-4, 1.0),
    frac=st.floats(0.0, 1.0),
    t2=st.floats(1.0, 100.0),
)
def test_every_feasible_l_has_a_continuous_rpf(rho_e0, frac, t2) -> None:
    g_inf, rho_einf = 3e-5, 1e-6
    lower, upper = feasible_l_range(rho_e0, rho_einf, g_inf, t2)
    l = float(lower + frac * (upper - lower))
    assume(l > 0)
    r = ReferencePerformanceFunction(RPFParameters(rho_e0=rho_e0, rho_einf=rho_einf, l=l, t2_s=t2, g_inf=g_inf), [[rho_e0, -rho_e0, rho_e0]])
    t1 = float(r.t1[0, 0])
    assert 0.0 <= t1 < t2
    A = rho_e0 - rho_einf
    v_exp = A * np.exp(-l * t1) + rho_einf
    v_par = r.a1[0, 0] * (t1 - t2) ** 2 + g_inf
    # near the double root (l = l_upper) the root is only defined to sqrt(eps): 1e-6 relative
    assert abs(v_exp - v_par) <= 1e-6 * v_exp
    s_exp = -l * A * np.exp(-l * t1)
    s_par = 2 * r.a1[0, 0] * (t1 - t2)
    assert abs(s_exp - s_par) <= 1e-9 * abs(s_exp) + 1e-15
    rho, _ = _evaluate(r, np.nextafter(t1, 0) if t1 > 0 else 0.0)
    assert np.all(np.isfinite(rho))


def test_the_compiled_law_uses_the_tube_of_half_width_B0() -> None:
    """In the law (``kernels.sappc_transform``): ``delta = B0 / |rho|`` (eq. delta_i), the band is
    ``rho -+ B0``, and ``z = q_ev / rho``."""
    r = ReferencePerformanceFunction(RPFParameters(l=0.49, **TABLE1), E0_EXP1)
    cfg = SappcConfig(((4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0)), r.params, B0=0.016, gains=BacksteppingGains(0.3, 1.0, 0.0, 1.0))
    prm, coef = KP.pack_params(cfg)[0], KP.rpf_coef(r)[0]
    work, out = np.zeros((K.N_WORK, 4)), np.zeros((K.N_OUT, 4))
    for t in (0.0, 3.0, 18.0, 25.0):
        work[K.W_QBR, :3] = [0.3, 0.2, -0.1]
        state = K.new_state(1)[0]
        K.sappc_transform(prm, coef, state, t, work, out)
        rho = _evaluate(r, t)[0][0]
        np.testing.assert_array_equal(out[K.O_RHO, :3], rho)
        np.testing.assert_array_equal(out[K.O_BL, :3], rho - 0.016)
        np.testing.assert_array_equal(out[K.O_BU, :3], rho + 0.016)
        np.testing.assert_array_equal(out[K.O_Z, :3], np.array([0.3, 0.2, -0.1]) / rho)
        np.testing.assert_array_equal(state[K.S_PREV + 12 : K.S_PREV + 15], 0.016 / np.abs(rho))  # delta, kept for the warm start

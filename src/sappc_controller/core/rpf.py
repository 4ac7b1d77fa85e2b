"""Reference performance function (RPF, eq. RPF): parameters, feasibility and coefficients.

This module sets a run up (once, in Python, with scipy's Lambert W); the RPF is evaluated at every
sample by the compiled law (:func:`.kernels.rpf_evaluate`, fed by :func:`.packing.rpf_coef`), with
the time-varying constraint ``delta = B0 / |rho|`` of eq. (delta_i) (a tube of half-width ``B0``
around the RPF: ``1 - delta < q_ev / rho < 1 + delta`` is ``|q_ev - rho| < B0``).

The RPF of one error component is

    rho(t) = sign * { (rho_e0 - rho_einf) exp(-l t) + rho_einf     0  <= t < t1
                    { a1 (t - t2)^2 + g_inf                         t1 <= t < t2
                    { g_inf                                         t2 <= t

with value and slope continuous at ``t1`` and ``t2``.

Coefficients (docs/paper_notes.md, error 1)
---------------------------------
The paper's eq. (RPFsolve) has ``k`` for ``l`` and a wrong ``a1``.  Matching
slopes at ``t1`` gives ``a1 = l (rho_e0 - rho_einf) exp(-l t1) / (2 (t2 - t1))``;
with ``a2 = -2 a1 t2`` and ``a3 = g_inf + a1 t2^2`` the parabola is
``a1 (t - t2)^2 + g_inf``, which has zero slope at ``t2``.  Matching values at
``t1`` gives, with ``A = rho_e0 - rho_einf``, ``G = g_inf - rho_einf`` and
``s = t2 - t1``,

    f(s) = A exp(-l (t2 - s)) (1 - l s / 2) = G.                      (*)

Closed-form root
----------------
Substituting ``x = 1 - l s / 2`` turns (*) into ``x exp(-2x) = c`` with
``c = G exp(l t2 - 2) / A``, so ``x = -W(-2c) / 2`` with ``W`` the Lambert W
function.  Real roots exist iff ``-2c >= -1/e``.  The principal branch ``W_0``
gives ``s in [1/l, 2/l)``, the branch ``W_-1`` gives ``s <= 1/l``.

Root choice (documented rule): **the earliest switch time** ``t1 >= 0``, i.e.
the largest root ``s`` in ``(0, t2]``.  That is the ``W_0`` root whenever it
lies in ``(0, t2]`` (the parabola then takes over as early as possible, which
gives the gentlest landing on ``g_inf``), and the ``W_-1`` root otherwise.

Feasible range of ``l`` (docs/paper_notes.md, error 2)
--------------------------------------------
``f`` rises on ``s < 1/l`` and falls after, so a root in ``(0, t2]`` exists iff
``min(f(0), f(t2)) <= G <= f(min(1/l, t2))``.  In closed form
``l_lower <= l <= l_upper`` with

    l_upper = ln(e A / (2 G)) / t2          if A >= 2 G   (the bound of docs/paper_notes.md)
            = 2 (1 - G / A) / t2            otherwise,
    l_lower = min(ln(A / G), 2 (1 - G / A)) / t2.

When ``ln(A / G)`` is the smaller, the lower end is **excluded**: there the
root is ``s = 0`` (the exponential reaches ``g_inf`` exactly at ``t2`` and the
parabola has zero length, ``a1`` infinite); :data:`_LOWER_BOUND_MARGIN` keeps
``l`` away from it.  When ``2 (1 - G / A)`` is the smaller, the root is
``s = t2`` (``t1 = 0``: the RPF is the parabola alone), which is valid.

The paper's Table 1 (rho_e0 = 0.4, l = 0.5, t2 = 20, g_inf = 3e-5,
rho_einf = 1e-6) gives ``l_upper = 0.4919``: infeasible.

Small initial errors
--------------------
When ``rho_e0 <= g_inf`` (the error already starts at or below the terminal
value, common in Monte Carlo runs with Euler angles near zero) no ``l`` solves
(*).  Defined behaviour: that component's RPF is **flat**, ``rho(t) = sign *
g_inf`` for all ``t >= 0`` (``t1 = 0``, ``a1 = 0``); the error is steered to the
terminal value at once.  This is not a fallback for infeasible input: it is
the only RPF whose value never exceeds its start and never falls below its
terminal value.  Infeasible ``l`` with ``rho_e0 > g_inf`` raises
:class:`InfeasibleRPFError` unless the caller explicitly asks for
``on_infeasible="clamp"`` (used by Monte Carlo campaigns, which count the
clamped components), in which case ``l`` is moved to the nearest feasible bound.

Sign
----
``sign = +1`` if the initial error ``e(0) >= 0`` and ``-1`` otherwise (the
paper's sign rule after eq. RPF); ``e(0) = 0`` takes ``+1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import ConfigError, check_positive

__all__ = ["InfeasiblePolicy", "InfeasibleRPFError", "RPFParameters", "ReferencePerformanceFunction", "feasible_l_range"]

Array = NDArray[np.float64]

#: Relative slack when comparing ``l`` with the closed-form feasibility bounds
#: and when clamping the Lambert W argument at its branch point -1/e: a few
#: ulps of the quantities involved, so that ``l = l_upper`` computed by this
#: module is itself accepted (it is a double root).
_FEASIBILITY_RTOL = 1e-12
#: Relative margin above an excluded lower bound ``ln(A/G)/t2`` (see module
#: docstring): keeps ``s = t2 - t1 >= ~1e-6 t2``, where the W_-1 root still has
#: 10 correct digits.
_LOWER_BOUND_MARGIN = 1e-6
#: Relative rounding allowance when comparing the W_0 root with t2 (the root
#: is computed to ~1e-13 relative; 1e-9 is generous and still far from any
#: meaningful difference in switch time).
_ROOT_RTOL = 1e-9


class InfeasibleRPFError(ConfigError):
    """The RPF equation (RPFsolve) has no real solution for the given parameters."""


@dataclass(frozen=True)
class RPFParameters:
    """Design parameters of the RPF (eq. RPF, Table 1).

    Attributes
    ----------
    rho_e0 : float or None
        Initial magnitude of the exponential part.  ``None`` means "the
        magnitude of each component's initial error" (the paper's Monte Carlo
        rule, Table 2).
    rho_einf : float
        Asymptote of the exponential part, ``0 <= rho_einf < g_inf``.
    l : float
        Exponential rate [1/s].
    t2_s : float
        Settling time of the RPF ``t2`` [s].
    g_inf : float
        Terminal value of the RPF.
    """

    rho_e0: float | None
    rho_einf: float
    l: float
    t2_s: float
    g_inf: float

    def __post_init__(self) -> None:
        if self.rho_e0 is not None:
            check_positive("rpf.rho_e0", self.rho_e0)
        check_positive("rpf.rho_einf", self.rho_einf, allow_zero=True)
        check_positive("rpf.l", self.l)
        check_positive("rpf.t2_s", self.t2_s)
        check_positive("rpf.g_inf", self.g_inf)
        if not self.rho_einf < self.g_inf:
            raise ConfigError(
                f"rpf.rho_einf ({self.rho_einf!r}) must be less than rpf.g_inf ({self.g_inf!r}); "
                "otherwise eq. (RPFsolve) has no solution"
            )
        if self.rho_e0 is not None and self.rho_e0 > self.g_inf:
            lower, upper = feasible_l_range(self.rho_e0, self.rho_einf, self.g_inf, self.t2_s)
            if not lower * (1.0 - _FEASIBILITY_RTOL) <= self.l <= upper * (1.0 + _FEASIBILITY_RTOL):
                raise InfeasibleRPFError(_infeasible_message(self.l, self.rho_e0, self.rho_einf, self.g_inf, self.t2_s, float(lower), float(upper)))


def _infeasible_message(l: float, rho_e0: float, rho_einf: float, g_inf: float, t2: float, lower: float, upper: float) -> str:
    return (
        f"rpf.l = {l!r} is infeasible for rho_e0 = {float(rho_e0):.6g}, rho_einf = {rho_einf!r}, g_inf = {g_inf!r}, "
        f"t2_s = {t2!r}: eq. (RPFsolve) has a real solution only for {float(lower):.6g} <= l <= {float(upper):.6g}"
    )


def feasible_l_range(rho_e0: ArrayLike, rho_einf: float, g_inf: float, t2: float) -> tuple[Array, Array]:
    """Closed-form interval ``[l_lower, l_upper]`` of ``l`` for which eq. (RPFsolve) has a root.

    Parameters
    ----------
    rho_e0 : array_like
        Initial magnitude(s); entries ``<= g_inf`` give ``nan`` bounds (no ``l`` works).
    rho_einf, g_inf, t2 : float
        As in :class:`RPFParameters`.

    Returns
    -------
    l_lower, l_upper : ndarray
        Shaped like ``rho_e0``.  See the module docstring for the derivation;
        an excluded lower end is returned raised by ``_LOWER_BOUND_MARGIN``
        (relative), so the returned interval is closed and every value in it works.
    """
    A = np.asarray(rho_e0, dtype=np.float64) - rho_einf
    G = g_inf - rho_einf
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = A / G
        upper = np.where(ratio >= 2.0, np.log(np.e * ratio / 2.0), 2.0 * (1.0 - 1.0 / ratio)) / t2
        lower = np.minimum(np.log(ratio), 2.0 * (1.0 - 1.0 / ratio)) / t2
        excluded = np.log(ratio) < 2.0 * (1.0 - 1.0 / ratio)
    lower = np.where(excluded, lower * (1.0 + _LOWER_BOUND_MARGIN), lower)
    bad = ~(ratio > 1.0)
    return np.where(bad, np.nan, lower), np.where(bad, np.nan, upper)


class InfeasiblePolicy(str, Enum):
    """What :class:`ReferencePerformanceFunction` does with a component whose ``l`` is infeasible."""

    RAISE = "raise"  #: raise :class:`InfeasibleRPFError` naming ``l`` and the feasible range
    CLAMP = "clamp"  #: move ``l`` to the nearest bound and flag the component (Monte Carlo campaigns)


class ReferencePerformanceFunction:
    """The RPF of eq. (RPF) for a batch of error components, shape (N, 3).

    Parameters
    ----------
    params : RPFParameters
        Design parameters.
    e0 : array_like, shape (N, 3) or (3,)
        Initial error of each component (``q_ev(0)``); gives the sign, and the
        initial magnitude when ``params.rho_e0`` is ``None``.
    on_infeasible : InfeasiblePolicy or {"raise", "clamp"}
        What to do when ``l`` is outside the feasible range of a component
        whose initial magnitude exceeds ``g_inf``.  ``"raise"`` (default)
        raises :class:`InfeasibleRPFError` naming ``l`` and the range;
        ``"clamp"`` moves ``l`` to the nearest bound for that component and
        records it in :attr:`clamped`.

    Attributes
    ----------
    sign, t1, a1, l, rho_e0 : ndarray, shape (N, 3)
        Per-component sign, switch time [s], parabola coefficient, exponential
        rate actually used [1/s] and initial magnitude.
    A : ndarray, shape (N, 3)
        ``rho_e0 - rho_einf``, the amplitude of the exponential part (0 where flat).
    flat : ndarray of bool, shape (N, 3)
        Components with ``rho_e0 <= g_inf`` (flat RPF, see module docstring).
    clamped : ndarray of bool, shape (N, 3)
        Components whose ``l`` was clamped (only with ``on_infeasible="clamp"``).
    """

    def __init__(
        self,
        params: RPFParameters,
        e0: ArrayLike,
        *,
        on_infeasible: InfeasiblePolicy | str = InfeasiblePolicy.RAISE,
    ) -> None:
        try:
            policy = InfeasiblePolicy(on_infeasible)
        except ValueError:
            raise ConfigError(f"on_infeasible must be 'raise' or 'clamp', got {on_infeasible!r}") from None
        e0_arr = np.atleast_2d(np.asarray(e0, dtype=np.float64))
        self.params = params
        self.sign: Array = np.where(e0_arr >= 0.0, 1.0, -1.0)
        rho_e0 = np.abs(e0_arr) if params.rho_e0 is None else np.full(e0_arr.shape, float(params.rho_e0))
        self.rho_e0: Array = rho_e0
        self.flat = rho_e0 <= params.g_inf
        t2, g_inf, rho_einf = params.t2_s, params.g_inf, params.rho_einf

        l_lower, l_upper = feasible_l_range(np.where(self.flat, 2.0 * g_inf, rho_e0), rho_einf, g_inf, t2)
        too_high = params.l > l_upper * (1.0 + _FEASIBILITY_RTOL)
        too_low = params.l < l_lower * (1.0 - _FEASIBILITY_RTOL)
        infeasible = ~self.flat & (too_high | too_low)
        if np.any(infeasible) and policy is InfeasiblePolicy.RAISE:
            k = tuple(int(i) for i in np.argwhere(infeasible)[0])
            raise InfeasibleRPFError(
                _infeasible_message(params.l, rho_e0[k], rho_einf, g_inf, t2, l_lower[k], l_upper[k]) + f" (run {k[0]}, component {k[1]})"
            )
        self.clamped = infeasible
        l = np.clip(np.full(rho_e0.shape, float(params.l)), l_lower, l_upper)
        l = np.where(infeasible, l, params.l)
        self.l: Array = l

        from scipy.special import lambertw  # here, not at import: scipy.special costs 0.2 s (see cli)

        A = np.where(self.flat, 1.0, rho_e0 - rho_einf)
        G = g_inf - rho_einf
        arg = -2.0 * G * np.exp(l * t2 - 2.0) / A  # -2c
        # At (or, by rounding, just below) the branch point -1/e both branches equal -1
        # (the double root at l = l_upper); scipy's lambertw returns NaN exactly there.
        at_branch = arg <= -np.exp(-1.0)
        with np.errstate(invalid="ignore"):
            w0 = np.where(at_branch, -1.0, lambertw(arg, 0).real)
            w_m1 = np.where(at_branch, -1.0, lambertw(arg, -1).real)
        s0 = (2.0 + w0) / l  # x = -W/2, s = 2 (1 - x) / l
        s_m1 = (2.0 + w_m1) / l
        # The W_0 root when it lies in (0, t2] (allowing rounding at s = t2, i.e. t1 = 0), else the W_-1 root.
        s = np.where(s0 <= t2 * (1.0 + _ROOT_RTOL), np.minimum(s0, t2), s_m1)
        s = np.where(self.flat, t2, s)
        self.t1: Array = t2 - s
        self.A: Array = np.where(self.flat, 0.0, A)
        self.a1: Array = np.where(self.flat, 0.0, l * self.A * np.exp(-l * self.t1) / (2.0 * s))  # docs/paper_notes.md, error 1

"""External disturbance torque models [N m, body axes].

Each model is a pure function of time (and, for the random model, of its
seed): ``torque_B(t, n_runs)`` takes a vector of sample times ``t`` (T,) and
returns (T, n, 3) with ``n = n_runs``, or ``n = 1`` when every run sees the
same torque (broadcastable).  Evaluating a block of samples at once keeps the
per-step cost of the closed loop independent of the models.  The plant holds the disturbance
constant over a control period (sampled at the period's start, zero-order
hold), exactly as it holds the control torque: that is what a disturbance
injected as a message per step can do, so the offline runner and the ROS 2
graph see the same torque.

Time windows (pulse, step) are compared with a tolerance of
``TIME_TOLERANCE_S`` so that a window sampled on a grid covers exactly
``duration / dt`` samples despite rounding in ``k * dt``.

The formulas are computed by the compiled kernels (:mod:`spacecraft_sim.core.kernels`,
:func:`~spacecraft_sim.core.kernels.disturbance_sample`, the one implementation used by the
injector node, the offline run and a campaign): a model is encoded once
(:func:`encode_disturbance`, cached on the frozen dataclass) and each
``torque_B`` call evaluates the block in compiled code.  The random kind's draws are made in
Python before (:func:`random_draws`, the same
``default_rng([seed, window])`` calls).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import ConfigError, as_finite_array, check_positive, from_kind_list
from spacecraft_sim.core import kernels
from spacecraft_sim.core.kernels import TIME_TOLERANCE_S

__all__ = [
    "pack_disturbance",
    "encode_disturbance",
    "random_draws",
    "ConstantTorque",
    "DisturbanceModel",
    "DisturbanceSum",
    "PaperPeriodic",
    "PulseTorque",
    "RandomTorque",
    "StepTorque",
    "TIME_TOLERANCE_S",
    "disturbances_from_list",
]

Array = NDArray[np.float64]


class DisturbanceModel(Protocol):
    """A disturbance torque model."""

    def torque_B(self, t: Array, n_runs: int) -> Array:
        """Torque [N m] at times ``t`` [s] (T,), shape (T, n_runs or 1, 3)."""

    def events(self) -> list[tuple[float, float]]:
        """Fault windows ``(start_s, end_s)`` this model injects (empty for background disturbances)."""


def _vec3(name: str, value: ArrayLike) -> Array:
    return as_finite_array(name, value, shape_tail=(3,))


class _Compiled:
    """``torque_B`` of a model (or a sum of models) through the compiled kernels."""

    @cached_property
    def _kernel_sum(self) -> DisturbanceSum:
        """The models the kernels evaluate: this model alone, or the sum itself."""
        return self if isinstance(self, DisturbanceSum) else DisturbanceSum((self,))  # type: ignore[arg-type]  # a kind satisfies DisturbanceModel

    @cached_property
    def _plan(self) -> tuple[bool, bool, dict[int, tuple[Array, Array, Array, Array, Array]]]:
        """Whether each run has its own torque, whether there is a random model, and the encodings
        made so far: n -> (kinds, dparams, dscale, dphase, no_draws) (:func:`encode_disturbance`)."""
        models = self._kernel_sum.models
        return any(_per_run(m) for m in models), any(isinstance(m, RandomTorque) for m in models), {}

    def torque_B(self, t: Array, n_runs: int) -> Array:
        """Torque [N m] at times ``t`` [s] (T,), shape (T, n_runs, 3), or (T, 1, 3) when every
        run sees the same torque."""
        per_run, has_random, encodings = self._plan
        n = n_runs if per_run else 1
        enc = encodings.get(n)
        if enc is None:  # once per model and batch size
            enc = (*encode_disturbance(self._kernel_sum, n), np.zeros((0, n, 1, 3)))
            encodings[n] = enc
        kinds, dparams, dscale, dphase, no_draws = enc
        tt = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        if has_random:
            draws, win = random_draws(self._kernel_sum, tt, n)
        else:
            draws, win = no_draws, np.zeros((0, tt.size), dtype=np.int64)
        total: Array = kernels.disturbance_tables(tt, kinds, dparams, dscale, dphase, draws, win)
        return total


def _per_run(model: DisturbanceModel) -> bool:
    """Whether ``model`` gives each run of a batch its own torque."""
    if isinstance(model, RandomTorque):
        return True
    if isinstance(model, PaperPeriodic):
        return int(np.size(model.scale)) > 1 or int(np.size(model.phase_rad)) > 1
    return False


@dataclass(frozen=True)
class PaperPeriodic(_Compiled):
    """The paper's disturbance (Sec. V.A), ``omega_p = 0.01`` rad/s:

        d = 1e-3 [ 4 sin(3 w t) + 3 cos(10 w t) - 20,
                  -1.5 sin(2 w t) + 3 cos(5 w t) + 20,
                   3 sin(10 w t) - 8 cos(4 w t) + 20 ]   N m

    ``scale`` multiplies the whole torque and ``phase_rad`` shifts every
    harmonic's argument (``w t + phase``); both may be per-run arrays (N,)
    for Monte Carlo dispersions.
    """

    omega_p_rad_s: float = 0.01
    scale: float | tuple[float, ...] = 1.0
    phase_rad: float | tuple[float, ...] = 0.0

    def __post_init__(self) -> None:
        check_positive("omega_p_rad_s", self.omega_p_rad_s)
        as_finite_array("scale", self.scale)
        as_finite_array("phase_rad", self.phase_rad)

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class ConstantTorque(_Compiled):
    """A constant torque for all time."""

    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        _vec3("torque_Nm", self.torque_Nm)

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class StepTorque(_Compiled):
    """A torque switched on at ``start_s`` and kept (a fault that does not clear)."""

    start_s: float
    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        check_positive("start_s", self.start_s, allow_zero=True)
        _vec3("torque_Nm", self.torque_Nm)

    def events(self) -> list[tuple[float, float]]:
        return [(self.start_s, float("inf"))]


@dataclass(frozen=True)
class PulseTorque(_Compiled):
    """A torque on during ``[start_s, start_s + duration_s)``: the paper's sudden fault is
    ``(1, 1, 1)`` N m for 0.5 s at 50 s (Sec. V.C)."""

    start_s: float
    duration_s: float
    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        check_positive("start_s", self.start_s, allow_zero=True)
        check_positive("duration_s", self.duration_s)
        _vec3("torque_Nm", self.torque_Nm)

    def events(self) -> list[tuple[float, float]]:
        return [(self.start_s, self.start_s + self.duration_s)]


@dataclass(frozen=True)
class RandomTorque(_Compiled):
    """Zero-mean Gaussian torque, piecewise constant over windows of ``hold_s``.

    The value in window ``k = floor(t / hold_s)`` is drawn from
    ``numpy.random.default_rng([seed, k])``: a pure function of the seed and the
    window, so any caller (offline runner, injector node, a replay) gets the
    same sequence whatever order it asks in.  Each run of a batch gets an
    independent stream from ``seed + run index`` unless ``seeds`` lists them.
    """

    sigma_Nm: tuple[float, float, float]
    hold_s: float
    seed: int = 0
    seeds: tuple[int, ...] = field(default=())

    def __post_init__(self) -> None:
        sigma = _vec3("sigma_Nm", self.sigma_Nm)
        if np.any(sigma < 0.0):
            raise ConfigError(f"sigma_Nm must be >= 0, got {self.sigma_Nm!r}")
        check_positive("hold_s", self.hold_s)
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class DisturbanceSum(_Compiled):
    """The sum of several models."""

    models: tuple[DisturbanceModel, ...] = ()

    def events(self) -> list[tuple[float, float]]:
        return sorted(e for m in self.models for e in m.events())


#: The ``kind`` names of the models in schedule files (scenario ``disturbances:`` lists).
DISTURBANCE_KINDS: dict[str, type] = {
    "paper_periodic": PaperPeriodic,
    "constant": ConstantTorque,
    "step": StepTorque,
    "pulse": PulseTorque,
    "random": RandomTorque,
}


def disturbances_from_list(entries: object, prefix: str = "disturbances") -> DisturbanceSum:
    """Build the sum of the models listed as ``[{kind: ..., <fields>}, ...]`` (a scenario's
    ``disturbances:`` section), raising :class:`ConfigError` naming the entry and key."""
    return DisturbanceSum(from_kind_list(entries, DISTURBANCE_KINDS, prefix))


# ============================================================================= the compiled kernels' arrays


def encode_disturbance(model: DisturbanceSum, n_runs: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``kinds``, ``dparams``, ``dscale`` (n_runs, M), ``dphase`` (n_runs, M) of a disturbance sum.

    A periodic model's ``scale`` and ``phase_rad`` may be per-run tuples (length ``n_runs``).
    """
    models = model.models
    M = len(models)
    kinds = np.zeros(M, dtype=np.int64)
    dparams = np.zeros((M, kernels.N_DPARAMS))
    dscale = np.ones((n_runs, M))
    dphase = np.zeros((n_runs, M))
    r = 0
    for m, mod in enumerate(models):
        if isinstance(mod, PaperPeriodic):
            kinds[m] = kernels.D_PERIODIC
            dparams[m, 0] = mod.omega_p_rad_s
            dscale[:, m] = np.broadcast_to(np.asarray(mod.scale, dtype=np.float64), (n_runs,))
            dphase[:, m] = np.broadcast_to(np.asarray(mod.phase_rad, dtype=np.float64), (n_runs,))
        elif isinstance(mod, ConstantTorque):
            kinds[m] = kernels.D_CONSTANT
            dparams[m, :3] = mod.torque_Nm
        elif isinstance(mod, StepTorque):
            kinds[m] = kernels.D_STEP
            dparams[m, :3], dparams[m, 3] = mod.torque_Nm, mod.start_s
        elif isinstance(mod, PulseTorque):
            kinds[m] = kernels.D_PULSE
            dparams[m, :3], dparams[m, 3], dparams[m, 4] = mod.torque_Nm, mod.start_s, mod.duration_s
        elif isinstance(mod, RandomTorque):
            kinds[m] = kernels.D_RANDOM
            dparams[m, :3], dparams[m, 3], dparams[m, 4] = mod.sigma_Nm, mod.hold_s, r
            r += 1
        else:
            raise TypeError(f"no compiled kernel for disturbance model {type(mod).__name__}")
    return kinds, dparams, dscale, dphase


def random_draws(model: DisturbanceSum, t: np.ndarray, n_runs: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``rand_draws`` (R, n_runs, W, 3) and ``rand_win`` (R, T) of the random models of ``model``
    on the grid ``t``: the draws ``default_rng([seed, window]).standard_normal(3)`` that
    :meth:`.disturbance.RandomTorque.torque_B` makes, one per run and window (:mod:`.kernels`' docstring)."""
    randoms = [m for m in model.models if isinstance(m, RandomTorque)]
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if not randoms:
        return np.zeros((0, n_runs, 1, 3)), np.zeros((0, t.size), dtype=np.int64)
    wins, invs = [], []
    for m in randoms:
        windows = np.floor(t / m.hold_s + TIME_TOLERANCE_S / m.hold_s).astype(np.int64)
        uniq, inv = np.unique(windows, return_inverse=True)
        wins.append(uniq)
        invs.append(inv.reshape(-1))
    W = max(u.size for u in wins)
    draws = np.zeros((len(randoms), n_runs, W, 3))
    for r, m in enumerate(randoms):
        seeds = m.seeds if m.seeds else tuple(m.seed + i for i in range(n_runs))
        if len(seeds) != n_runs:
            raise ConfigError(f"seeds lists {len(seeds)} runs, the batch has {n_runs}")
        for n, s in enumerate(seeds):
            for j, k in enumerate(wins[r]):
                draws[r, n, j] = np.random.default_rng([int(s), int(k)]).standard_normal(3)
    return draws, np.stack(invs).astype(np.int64)


def pack_disturbance(model: DisturbanceSum, t: ArrayLike, n_runs: int) -> kernels.DisturbanceArrays:
    """The disturbance of a batch for the whole-run loop (:class:`~.kernels.DisturbanceArrays`):
    the encoding, the random models' draws on the grid ``t`` (T,), and, when every run has the same
    torques (no random model, one scale and phase), their table, computed once."""
    tt = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    kinds, dparams, dscale, dphase = encode_disturbance(model, n_runs)
    draws, windows = random_draws(model, tt, n_runs)
    use_table = draws.shape[0] == 0 and bool(np.all(dscale == dscale[:1]) and np.all(dphase == dphase[:1]))
    table = (kernels.disturbance_table(tt, kinds, dparams, dscale[0], dphase[0], draws[:, 0], windows) if use_table else np.zeros((0, 3)))
    f64 = np.ascontiguousarray
    return kernels.DisturbanceArrays(use_table, f64(table, dtype=np.float64), f64(kinds, dtype=np.int64), f64(dparams, dtype=np.float64),
                                     f64(dscale, dtype=np.float64), f64(dphase, dtype=np.float64), f64(draws, dtype=np.float64),
                                     f64(windows, dtype=np.int64))

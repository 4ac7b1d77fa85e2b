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
(:func:`~spacecraft_sim.core.kernels.encode_disturbance`, cached on the frozen dataclass) and each
``torque_B`` call evaluates the block in compiled code.  The random kind's draws are made in
Python before (:func:`~spacecraft_sim.core.kernels.random_draws`, the same
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
        made so far: n -> (kinds, dparams, dscale, dphase, no_draws) (:func:`kernels.encode_disturbance`)."""
        models = self._kernel_sum.models
        return any(_per_run(m) for m in models), any(isinstance(m, RandomTorque) for m in models), {}

    def torque_B(self, t: Array, n_runs: int) -> Array:
        """Torque [N m] at times ``t`` [s] (T,), shape (T, n_runs, 3), or (T, 1, 3) when every
        run sees the same torque."""
        per_run, has_random, encodings = self._plan
        n = n_runs if per_run else 1
        enc = encodings.get(n)
        if enc is None:  # once per model and batch size
            enc = (*kernels.encode_disturbance(self._kernel_sum, n), np.zeros((0, n, 1, 3)))
            encodings[n] = enc
        kinds, dparams, dscale, dphase, no_draws = enc
        tt = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        if has_random:
            draws, win = kernels.random_draws(self._kernel_sum, tt, n)
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

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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import ConfigError, as_finite_array, check_positive, from_kind_list

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

#: Tolerance of time-window comparisons [s]: far below any control period
#: (>= 1e-4 s), far above the rounding of k * dt over hours (1e-12 s).
TIME_TOLERANCE_S = 1e-9


class DisturbanceModel(Protocol):
    """A disturbance torque model."""

    def torque_B(self, t: Array, n_runs: int) -> Array:
        """Torque [N m] at times ``t`` [s] (T,), shape (T, n_runs or 1, 3)."""

    def events(self) -> list[tuple[float, float]]:
        """Fault windows ``(start_s, end_s)`` this model injects (empty for background disturbances)."""


def _vec3(name: str, value: ArrayLike) -> Array:
    return as_finite_array(name, value, shape_tail=(3,))


@dataclass(frozen=True)
class PaperPeriodic:
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

    def torque_B(self, t: Array, n_runs: int) -> Array:
        phase = np.asarray(self.phase_rad, dtype=np.float64).reshape(1, -1)
        wt = (self.omega_p_rad_s * np.asarray(t, dtype=np.float64).reshape(-1, 1) + phase)[..., None]  # (T, n, 1)
        d = 1e-3 * np.concatenate(
            (
                4.0 * np.sin(3.0 * wt) + 3.0 * np.cos(10.0 * wt) - 20.0,
                -1.5 * np.sin(2.0 * wt) + 3.0 * np.cos(5.0 * wt) + 20.0,
                3.0 * np.sin(10.0 * wt) - 8.0 * np.cos(4.0 * wt) + 20.0,
            ),
            axis=-1,
        )
        return np.asarray(self.scale, dtype=np.float64).reshape(1, -1, 1) * d

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class ConstantTorque:
    """A constant torque for all time."""

    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        _vec3("torque_Nm", self.torque_Nm)

    def torque_B(self, t: Array, n_runs: int) -> Array:
        return np.broadcast_to(np.asarray(self.torque_Nm, dtype=np.float64), (np.size(t), 1, 3))

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class StepTorque:
    """A torque switched on at ``start_s`` and kept (a fault that does not clear)."""

    start_s: float
    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        check_positive("start_s", self.start_s, allow_zero=True)
        _vec3("torque_Nm", self.torque_Nm)

    def torque_B(self, t: Array, n_runs: int) -> Array:
        on = np.asarray(t, dtype=np.float64).reshape(-1, 1, 1) >= self.start_s - TIME_TOLERANCE_S
        return np.asarray(self.torque_Nm, dtype=np.float64) * on

    def events(self) -> list[tuple[float, float]]:
        return [(self.start_s, float("inf"))]


@dataclass(frozen=True)
class PulseTorque:
    """A torque on during ``[start_s, start_s + duration_s)``: the paper's sudden fault is
    ``(1, 1, 1)`` N m for 0.5 s at 50 s (Sec. V.C)."""

    start_s: float
    duration_s: float
    torque_Nm: tuple[float, float, float]

    def __post_init__(self) -> None:
        check_positive("start_s", self.start_s, allow_zero=True)
        check_positive("duration_s", self.duration_s)
        _vec3("torque_Nm", self.torque_Nm)

    def torque_B(self, t: Array, n_runs: int) -> Array:
        tt = np.asarray(t, dtype=np.float64).reshape(-1, 1, 1)
        on = ((self.start_s - TIME_TOLERANCE_S) <= tt) & (tt < (self.start_s + self.duration_s - TIME_TOLERANCE_S))
        return np.asarray(self.torque_Nm, dtype=np.float64) * on

    def events(self) -> list[tuple[float, float]]:
        return [(self.start_s, self.start_s + self.duration_s)]


@dataclass(frozen=True)
class RandomTorque:
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

    def torque_B(self, t: Array, n_runs: int) -> Array:
        windows = np.floor(np.asarray(t, dtype=np.float64).reshape(-1) / self.hold_s + TIME_TOLERANCE_S / self.hold_s).astype(np.int64)
        seeds = self.seeds if self.seeds else tuple(self.seed + i for i in range(n_runs))
        if len(seeds) != n_runs:
            raise ConfigError(f"seeds lists {len(seeds)} runs, the batch has {n_runs}")
        draws = np.array([[np.random.default_rng([int(s), int(k)]).standard_normal(3) for s in seeds] for k in windows])
        return draws * np.asarray(self.sigma_Nm, dtype=np.float64)

    def events(self) -> list[tuple[float, float]]:
        return []


@dataclass(frozen=True)
class DisturbanceSum:
    """The sum of several models."""

    models: tuple[DisturbanceModel, ...] = ()

    def torque_B(self, t: Array, n_runs: int) -> Array:
        total = np.zeros((np.size(t), 1, 3))
        for m in self.models:
            total = total + m.torque_B(t, n_runs)
        return total

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

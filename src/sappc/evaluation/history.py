"""Time histories of a run or a batch: the record that offline runs, campaigns and bags share."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sappc_controller.core.base import ControlOutput

__all__ = ["History", "HistoryRecorder", "Observer", "both"]

Array = NDArray[np.float64]

#: Observer called after each control computation: (k, t, state (N, 7), output, disturbance (N, 3)).
Observer = Callable[[int, float, Array, ControlOutput, Array], None]


@dataclass
class History:
    """Full time histories of a run or a batch: arrays (T, N, ...) with ``t`` (T,)."""

    t: Array
    q_BN: Array
    omega_BN_B: Array
    q_BR: Array
    torque_B: Array
    torque_cmd_B: Array
    saturated: NDArray[np.bool_]
    disturbance_B: Array
    rho: Array
    band_lower: Array
    band_upper: Array
    eps: Array
    z: Array
    V: Array

    @property
    def q_ev(self) -> Array:
        """Vector part of the error quaternion, (T, N, 3)."""
        return self.q_BR[..., :3]


def both(*observers: Observer) -> Observer:
    """An observer that calls each of ``observers`` in turn."""

    def call(k: int, t: float, x: Array, out: ControlOutput, d: Array) -> None:
        for obs in observers:
            obs(k, t, x, out, d)

    return call


class HistoryRecorder:
    """Observer that stores every sample (for single runs and small batches)."""

    _FIELDS = ("q_BR", "torque_B", "torque_cmd_B", "saturated", "rho", "band_lower", "band_upper", "eps", "z", "V")

    def __init__(self, t: Array, n_runs: int) -> None:
        T = t.size
        self.t = t
        self.state = np.empty((T, n_runs, 7))
        self.disturbance = np.empty((T, n_runs, 3))
        self.arrays: dict[str, Array] = {}
        self._T = T

    def __call__(self, k: int, t: float, x: Array, out: ControlOutput, d: Array) -> None:
        if not self.arrays:
            for name in self._FIELDS:
                v = getattr(out, name)
                self.arrays[name] = np.empty((self._T,) + v.shape, dtype=v.dtype)
        self.state[k] = x
        self.disturbance[k] = d  # (1 or N, 3), broadcast
        for name, arr in self.arrays.items():
            arr[k] = getattr(out, name)

    def history(self) -> History:
        return History(
            t=self.t,
            q_BN=self.state[..., :4],
            omega_BN_B=self.state[..., 4:],
            disturbance_B=self.disturbance,
            **self.arrays,  # type: ignore[arg-type]  # the fields of ControlOutput by name (saturated is bool)
        )

"""A three-axis magnetometer (issue 36): what the flight software knows of the Earth's field.

Every ``control_period / rate`` samples (the rate must divide the control rate, as the star
tracker's) it measures the true field in B with a constant bias and white noise, and holds the
measurement in between (Markley & Crassidis, eq. 4.1, the standard magnetometer model
``B_meas = B_B + b + v``, without scale-factor and misalignment errors):

    B_meas,j = B_B,j + b_j + sigma_j n_j,        n ~ N(0, 1) per axis and update      [T]

The draws are made before the run (:func:`magnetometer_draws`), one row per update, from the
magnetometer's own stream ``default_rng([seed, MAGNETOMETER_STREAM, *key])``, ``key`` the run's
(``(0,)`` for ``sappc simulate`` and the graph; a campaign's run ``k`` of seed ``s``: ``(k, s)``,
whatever chunk it runs in): a run with a magnetometer keeps every other model's draws as they are.

Pure: no ROS, no clock; the kernel allocates nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.validation import ConfigError
from spacecraft_sim.core.sensors import sample_stride

__all__ = ["MAGNETOMETER_STREAM", "Magnetometer", "magnetometer_draws", "magnetometer_generator", "measure_field"]

Array = NDArray[np.float64]

#: The magnetometer's stream in ``default_rng([seed, MAGNETOMETER_STREAM, run])``: a number no other
#: model of the project uses (the letters "MAG" as ASCII codes, 77 65 71).
MAGNETOMETER_STREAM = 776571

@dataclass(frozen=True)
class Magnetometer:
    """A magnetometer's data sheet (module docstring).

    Attributes
    ----------
    noise_T : float or 3 floats
        ``sigma`` [T], 1 sigma per axis (one number for the three).
    bias_T : 3 floats
        ``b`` [T], the residual bias after calibration.
    rate_hz : float
        Updates per second; must divide the control rate.
    seed : int
        The draws' seed.
    """

    noise_T: float | tuple[float, float, float] = 0.0
    bias_T: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rate_hz: float = 10.0
    seed: int = 0

    def __post_init__(self) -> None:
        n = np.asarray(self.noise_T, dtype=np.float64)
        if n.shape not in ((), (3,)) or not np.all(np.isfinite(n)) or not np.all(n >= 0):
            raise ConfigError(f"noise_T must be one number >= 0 or three, got {self.noise_T!r}")
        b = np.asarray(self.bias_T, dtype=np.float64)
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise ConfigError(f"bias_T must be 3 finite numbers, got {self.bias_T!r}")
        if isinstance(self.rate_hz, bool) or not isinstance(self.rate_hz, (int, float)) or not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"rate_hz must be a finite number > 0, got {self.rate_hz!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0, got {self.seed!r}")

    def stride(self, control_period_s: float) -> int:
        """Control samples per update; raises naming ``rate_hz`` when the rates do not divide."""
        return sample_stride(self.rate_hz, control_period_s)

    def params(self, control_period_s: float) -> Array:
        """The kernel's parameters (7,): the stride (samples per update), ``sigma`` (3), ``b`` (3)."""
        n = np.broadcast_to(np.asarray(self.noise_T, dtype=np.float64), (3,))
        return np.array([float(self.stride(control_period_s)), *n, *np.asarray(self.bias_T, dtype=np.float64)], dtype=np.float64)


def magnetometer_draws(mag: Magnetometer, n_samples: int, control_period_s: float, run: int | Sequence[int] = 0) -> Array:
    """The standard normal draws (U, 3) of the run keyed ``run`` (an index, or a tuple of integers:
    module docstring), one row per update (``U = ceil(T / stride)``)."""
    stride = mag.stride(control_period_s)
    rows = (n_samples + stride - 1) // stride
    out: Array = magnetometer_generator(mag, run).standard_normal((rows, 3))
    return out


def magnetometer_generator(mag: Magnetometer, run: int | Sequence[int] = 0) -> np.random.Generator:
    """The generator of the run keyed ``run``'s draws (:func:`magnetometer_draws` its first rows;
    drawn block by block, the same rows: a ``Generator`` fills in order)."""
    key = [int(run)] if isinstance(run, (int, np.integer)) else [int(k) for k in run]
    return np.random.default_rng([mag.seed, MAGNETOMETER_STREAM, *key])


@jit
def measure_field(prm, draws, k, row0, B_B, held):
    """The measurement of sample ``k`` into ``held`` (3,): a new one when ``k`` is an update sample
    (``k % stride == 0``: ``B_B + b + sigma n``, module docstring), else the held one unchanged;
    ``draws`` hold the update rows from ``row0`` (0: the run's; a block of samples: its own)."""
    stride = int(prm[0])
    if k % stride != 0:
        return
    row = k // stride - row0
    for j in range(3):
        held[j] = B_B[j] + prm[4 + j] + prm[1 + j] * draws[row, j]

"""Attitude sensors of a flight-like plant (issue 16): a star tracker and a rate gyro.

The controller sees their measurements; the metrics use the true state.

**Star tracker.**  At each update the measured attitude is the true one rotated in the body frame
by the rotation vector ``(sigma_x n_x, sigma_y n_y, sigma_z n_z)`` (``n`` standard normals;
per-axis sigmas: a tracker is typically several times less accurate about its boresight than
across it).  It updates every ``control_period / rate`` samples (the rate must divide the
control rate: a tracker at 10 Hz beside a 100 Hz loop updates every 10th sample) and holds its
last value in between, as flight software holds the last star-tracker quaternion.  During an
outage (sun or earth in the field of view, lost-in-space) it does not update: the last
value is held.  Its first update is at ``t = 0``; an outage may not cover it.

**Rate gyro** (the usual continuous model, sampled once per control period ``dt``): the measured
rate is the true one plus the bias plus white noise of standard deviation ``N / sqrt(dt)``, with
``N`` the angle random walk [rad/sqrt(s)]; the bias starts at ``b0`` and walks, ``b_{k+1} = b_k
+ K sqrt(dt) n``, with ``K`` the bias (rate) random walk [rad/s/sqrt(s)].

The kernel :func:`measure` takes 9 standard normals a sample (3 for the tracker, 3 for the gyro's
white noise, 3 for its bias walk; their source is the caller's, one stream per run) and per-sample
parameters (:meth:`Sensors.params`), so the white-noise model of earlier campaigns
(``dispersions.sensor_noise``: a tracker at every sample, isotropic, and a gyro without bias) is
the special case it computes bit for bit.

Pure: no ROS, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit, quat_multiply, quat_normalize
from gnc_common.validation import ConfigError, from_mapping

__all__ = ["G_SIGMA", "N_SENSOR_DRAWS", "N_SENSOR_PARAMS", "S_BIAS0", "ST_SIGMA", "Gyro", "SensorArrays", "Sensors", "measure_run", "pack_sensors", "StarTracker", "measure", "rotate_by_vector", "sample_stride", "sensors_from_mapping",
           "white_noise_params"]

Array = NDArray[np.float64]

#: Standard normals a sample: tracker (3), gyro white noise (3), gyro bias walk (3).
N_SENSOR_DRAWS = 9
#: Columns of :meth:`Sensors.params`: tracker sigmas (3), tracker stride [samples] (1), gyro noise
#: sigma per sample (3), bias step sigma per sample (3), initial bias (3).
N_SENSOR_PARAMS = 13
_ST_SIGMA, _ST_STRIDE, _G_SIGMA, _G_WALK, _G_BIAS0 = 0, 3, 4, 7, 10
#: Columns of :meth:`Sensors.params`: the gyro's initial bias (the loop starts its bias there) and
#: the tracker's sigmas (campaigns scale them per run).
S_BIAS0 = _G_BIAS0
ST_SIGMA = _ST_SIGMA
#: Columns of :meth:`Sensors.params`: the gyro's white-noise sigma per sample (what its
#: ``sensor_msgs/Imu`` says of its angular velocity's covariance).
G_SIGMA = _G_SIGMA
#: Rounding allowed when the tracker's period is checked to be a whole number of control periods.
_STRIDE_TOL = 1e-9


def sample_stride(rate_hz: float, control_period_s: float) -> int:
    """Control samples per update of a sensor sampling at ``rate_hz``; raises naming ``rate_hz`` when
    the rates do not divide (every sensor model's rule: the tracker's, the magnetometer's)."""
    ratio = 1.0 / (rate_hz * control_period_s)
    k = round(ratio)
    if k < 1 or abs(ratio - k) > _STRIDE_TOL * max(1.0, ratio):
        raise ConfigError(f"rate_hz = {rate_hz!r} must divide the control rate {1.0 / control_period_s:g} Hz "
                          f"(an update every whole number of control periods)")
    return int(k)


def _three(name: str, value: float | tuple[float, ...]) -> tuple[float, float, float]:
    v = np.asarray(value, dtype=np.float64)
    v = np.full(3, float(v)) if v.ndim == 0 else v
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be one finite number or 3 (x, y, z), got {value!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class StarTracker:
    """A star tracker (module docstring).

    Attributes
    ----------
    noise_rad : float or 3 floats
        1-sigma attitude error about each body axis [rad] (one number: the same about all three).
    rate_hz : float
        Update rate [Hz]; the control rate must be a whole multiple of it.
    outages_s : list of (start_s, end_s)
        Windows without updates (the last value is held); ``start_s > 0``.
    """

    noise_rad: float | tuple[float, float, float] = 0.0
    rate_hz: float = 10.0
    outages_s: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        sig = _three("noise_rad", self.noise_rad)
        if min(sig) < 0:
            raise ConfigError(f"noise_rad must be >= 0, got {self.noise_rad!r}")
        if isinstance(self.rate_hz, bool) or not isinstance(self.rate_hz, (int, float)):
            raise ConfigError(f"rate_hz must be a number, got {self.rate_hz!r}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"rate_hz must be finite and > 0, got {self.rate_hz!r}")
        for w in self.outages_s:
            if len(w) != 2 or not all(math.isfinite(float(v)) for v in w) or not 0.0 < float(w[0]) < float(w[1]):
                raise ConfigError(f"outages_s must be windows [start_s, end_s] with 0 < start_s < end_s, got {list(w)!r}")

    def stride(self, control_period_s: float) -> int:
        """Control samples per update; raises naming ``rate_hz`` when the rates do not divide."""
        return sample_stride(self.rate_hz, control_period_s)


@dataclass(frozen=True)
class Gyro:
    """A rate-integrating gyro sampled once per control period (module docstring).

    Attributes
    ----------
    angle_random_walk_rad_sqrt_s : float or 3 floats
        ``N`` [rad/sqrt(s)] (a data sheet's deg/sqrt(h) times pi/180/60).
    bias_random_walk_rad_s_sqrt_s : float or 3 floats
        ``K`` [rad/s/sqrt(s)], the bias's random walk (rate random walk).
    initial_bias_rad_s : float or 3 floats
        ``b0`` [rad/s].
    """

    angle_random_walk_rad_sqrt_s: float | tuple[float, float, float] = 0.0
    bias_random_walk_rad_s_sqrt_s: float | tuple[float, float, float] = 0.0
    initial_bias_rad_s: float | tuple[float, float, float] = 0.0

    def __post_init__(self) -> None:
        for name in ("angle_random_walk_rad_sqrt_s", "bias_random_walk_rad_s_sqrt_s"):
            if min(_three(name, getattr(self, name))) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        _three("initial_bias_rad_s", self.initial_bias_rad_s)


@dataclass(frozen=True)
class Sensors:
    """The plant's sensors (a scenario's ``sensors`` section): a star tracker, a gyro (either may be
    absent: that quantity is measured exactly), and the seed of a single run's draws (a campaign
    draws each run's from its own stream)."""

    star_tracker: StarTracker | None = None
    gyro: Gyro | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0, got {self.seed!r}")

    def params(self, control_period_s: float) -> Array:
        """The kernel's per-sample parameters (:data:`N_SENSOR_PARAMS`,)."""
        p = np.zeros(N_SENSOR_PARAMS)  # stride 0: no tracker, the attitude measured exactly
        if self.star_tracker is not None:
            p[_ST_SIGMA:_ST_SIGMA + 3] = _three("noise_rad", self.star_tracker.noise_rad)
            p[_ST_STRIDE] = self.star_tracker.stride(control_period_s)
        if self.gyro is not None:
            root_dt = math.sqrt(control_period_s)
            p[_G_SIGMA:_G_SIGMA + 3] = np.asarray(_three("arw", self.gyro.angle_random_walk_rad_sqrt_s)) / root_dt
            p[_G_WALK:_G_WALK + 3] = np.asarray(_three("brw", self.gyro.bias_random_walk_rad_s_sqrt_s)) * root_dt
            p[_G_BIAS0:_G_BIAS0 + 3] = _three("initial_bias_rad_s", self.gyro.initial_bias_rad_s)
        return p

    def outages(self) -> Array:
        """The tracker's outage windows (K, 2) [s]."""
        w = () if self.star_tracker is None else self.star_tracker.outages_s
        return np.array(w, dtype=np.float64).reshape(-1, 2)

    def draws(self, n_samples: int) -> Array:
        """A single run's standard normals (n_samples, :data:`N_SENSOR_DRAWS`), from ``seed``."""
        out: Array = np.random.default_rng(self.seed).standard_normal((n_samples, N_SENSOR_DRAWS))
        return out


def sensors_from_mapping(data: Any, prefix: str, control_period_s: float) -> Sensors:
    """The sensors of a parsed mapping (a scenario's ``sensors``, the plant node's ``sensors``
    parameter), strictly, the tracker's rate checked against the control period; every error
    names ``<prefix>.<key>``."""
    if isinstance(data, dict) and isinstance(data.get("star_tracker"), dict) and isinstance(data["star_tracker"].get("outages_s"), list):
        tracker = data["star_tracker"]
        data = {**data, "star_tracker": {**tracker, "outages_s": [tuple(w) if isinstance(w, list) else w for w in tracker["outages_s"]]}}
    try:
        sensors: Sensors = from_mapping(Sensors, data, prefix)
    except ConfigError as exc:  # the models' own checks name the bare key: name it in full
        msg = str(exc)
        for part in (f"{prefix}.star_tracker", f"{prefix}.gyro", prefix):
            if msg.startswith(f"{part}: "):
                msg = f"{part}.{msg[len(part) + 2:]}"
                break
        raise ConfigError(msg) from None
    if sensors.star_tracker is not None:
        try:
            sensors.star_tracker.stride(control_period_s)
        except ConfigError as exc:
            raise ConfigError(f"{prefix}.star_tracker.{exc}") from None
    return sensors


def white_noise_params(attitude_sigma_rad: float, rate_sigma_rad_s: float) -> Array:
    """The parameters of the white-noise model (a tracker at every sample with the same sigma about
    every axis, a gyro of per-sample sigma ``rate_sigma_rad_s`` without bias)."""
    p = np.zeros(N_SENSOR_PARAMS)
    p[_ST_SIGMA:_ST_SIGMA + 3] = attitude_sigma_rad
    p[_ST_STRIDE] = 1.0
    p[_G_SIGMA:_G_SIGMA + 3] = rate_sigma_rad_s
    return p


@jit(inline="always")
def rotate_by_vector(q_BN, rx, ry, rz, q_out):
    """``q_BN`` rotated in the body frame by the rotation vector ``(rx, ry, rz)`` [rad],
    normalised, into ``q_out`` (4,) (a star tracker's error; the white-noise fault's too)."""
    angle = np.sqrt((rx * rx + ry * ry) + rz * rz)
    s = np.sin(angle / 2.0) / angle if angle > 0.0 else 0.0
    dq = np.empty(4)
    dq[0], dq[1], dq[2], dq[3] = rx * s, ry * s, rz * s, np.cos(angle / 2.0)
    quat_multiply(q_BN, dq, q_out)
    quat_normalize(q_out, q_out)


@jit
def measure(k, t, t_epoch, q_BN, omega_BN_B, n, prm, outages, held_q, bias, y):
    """The measurement of sample ``k`` at time ``t`` [s] (module docstring) into ``y`` (8,):
    ``y[:4]`` the tracker's quaternion (updated into ``held_q[:4]`` on its samples outside the
    ``outages`` (K, 2), held otherwise), ``y[4:7]`` the gyro's rate with the bias ``bias`` (3,),
    which then walks one period, ``y[7]`` the tracker sample's epoch: ``t_epoch`` (this sample's
    stamp in the consumer's seconds) when it updates, kept in ``held_q[4]`` while it holds (a star
    tracker stamps each quaternion with its own time).  Stride 0 in ``prm``: no tracker, the attitude is exact (a new
    sample every time).  ``n``: the sample's standard normals (6 or more; the bias walk
    reads ``n[6:9]`` only when it is non-zero), ``prm`` (:data:`N_SENSOR_PARAMS`,)."""
    stride = int(prm[_ST_STRIDE])
    if stride == 0:  # no star tracker: the true attitude
        for i in range(4):
            held_q[i] = q_BN[i]
        held_q[4] = t_epoch
    update = stride > 0 and k % stride == 0
    for w in range(outages.shape[0]):
        if outages[w, 0] <= t < outages[w, 1]:
            update = False
    if update:
        rotate_by_vector(q_BN, prm[_ST_SIGMA] * n[0], prm[_ST_SIGMA + 1] * n[1], prm[_ST_SIGMA + 2] * n[2], held_q)
        held_q[4] = t_epoch
    for i in range(4):
        y[i] = held_q[i]
    for i in range(3):
        y[4 + i] = (omega_BN_B[i] + bias[i]) + prm[_G_SIGMA + i] * n[3 + i]
    y[7] = held_q[4]
    for i in range(3):
        step = prm[_G_WALK + i]
        if step != 0.0:
            bias[i] = bias[i] + step * n[6 + i]


# ============================================================================= a batch's arrays (the offline loop)


class SensorArrays(NamedTuple):
    """The sensors of a batch, as the whole-run loop takes them: ``draws`` (N, T or 0,
    :data:`N_SENSOR_DRAWS` or 6) each run's standard normals (no rows: the state is measured
    exactly), ``params`` (N, :data:`N_SENSOR_PARAMS`) each run's :meth:`Sensors.params`,
    ``outages`` (N, K, 2) [s] each run's tracker outages.  Packed by :func:`pack_sensors`."""

    draws: NDArray[np.float64]
    params: NDArray[np.float64]
    outages: NDArray[np.float64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"draws": 0, "params": 0, "outages": 0}


def pack_sensors(sensors: Sensors | None, n_runs: int, n_samples: int, control_period_s: float,
                 params: NDArray[np.float64] | None = None, outages: NDArray[np.float64] | None = None) -> SensorArrays:
    """A batch's sensors: the scenario's (every run with the draws of its ``seed``; ``None``: exact
    measurements), or ``params`` ((13,) or one row per run: a campaign's dispersed sensors) whose
    draws a campaign gives per sub-batch (no rows here); ``outages`` (n_runs, K, 2) [s]: each
    run's tracker outages, else the scenario's for every run."""
    if params is None:
        prm = np.zeros(N_SENSOR_PARAMS) if sensors is None else sensors.params(control_period_s)
        draws = (np.zeros((n_runs, 0, 6)) if sensors is None
                 else np.array(np.broadcast_to(sensors.draws(n_samples), (n_runs, n_samples, N_SENSOR_DRAWS)), dtype=np.float64))
    else:
        prm, draws = params, np.zeros((n_runs, 0, 6))
    if outages is None:
        own = np.zeros((0, 2)) if sensors is None else sensors.outages()
        outages = np.broadcast_to(own[None], (n_runs,) + own.shape)
    if outages.shape[0] != n_runs or outages.shape[2:] != (2,):
        raise ValueError(f"outages must be ({n_runs}, K, 2), got {outages.shape}")
    return SensorArrays(np.ascontiguousarray(draws, dtype=np.float64),
                        np.array(np.broadcast_to(prm, (n_runs, N_SENSOR_PARAMS)), dtype=np.float64, order="C"),
                        np.array(outages, dtype=np.float64, order="C"))


@jit(inline="always")
def measure_run(s, n, k, kb, t, t_epoch, x, held_q, bias, y):
    """Run ``n``'s measurement of sample ``k`` (:func:`measure` with :class:`SensorArrays` ``s``, whose
    batch has draws, row ``kb`` of them: the loop's draws are those of its block of samples; without
    draws the loop's input is the true state, which the loop copies itself: this call's seven arrays
    would cost seven reference counts per sample)."""
    measure(k, t, t_epoch, x[:4], x[4:7], s.draws[n, kb], s.params[n], s.outages[n], held_q, bias, y)

"""Flight modes and their guarded transitions (issue 49): the kernel every path will share.

Four modes, after Astrobee's GNC and Basilisk's flight-software modes:

==========  =========================================================================================
DETUMBLE    B-dot on the magnetorquers from the magnetometer alone (no gyro, no tracker needed):
            the tumble after separation is damped before anything points.
HOLD        rate damping / inertial hold with MRP feedback on the estimate: the star tracker locks,
            the estimator converges.
TRACK       the scenario's controller (SAPPC) on its reference.
SAFE        what HOLD does, on the gyro alone: the attitude estimate is not trusted.
==========  =========================================================================================

Each sample, :func:`mode_step` takes the sample's inputs (:data:`N_INPUTS` floats, ``IN_*``), counts
for how many consecutive samples each guard's condition has held, and takes at most one
transition; it returns why (``R_*``, :data:`REASON_NAMES`), :data:`R_NONE` for none.  The guards,
each with a threshold and a persistence (:class:`ModeConfig`):

=====================  ===================================================================  ================
from -> to             condition (every sample of the persistence)                          reason
=====================  ===================================================================  ================
any -> requested       a ground request (``IN_REQUEST``: a mode's number) for another mode:  ``request``
                       at once, the operator's authority; every count restarts
DETUMBLE -> HOLD       body-rate magnitude ``< detumbled_rate_rad_s`` for                    ``detumbled``
                       ``detumbled_for_s``
HOLD, TRACK -> SAFE    the run's loss-of-control rule fires (``IN_LOST``), at once           ``control_lost``
TRACK -> SAFE          the estimate's attitude error against the reference (``IN_ERROR``)   ``control_lost``
                       ``> lost_error_rad`` for ``lost_for_s`` (when ``lost_error_rad`` is
                       set: flight software's own view of a lost attitude)
HOLD, TRACK -> SAFE    a wheel's speed beyond ``max_wheel_speed_fraction`` of its limit, at  ``wheel_speed``
                       once
HOLD, TRACK -> SAFE    the estimator's health ERROR or STALE for ``safe_on_error_for_s``     ``estimator_error``
HOLD -> TRACK          health OK and the estimate's attitude 1-sigma                        ``acquired``
                       ``<= converged_sigma_rad`` (and, when ``acquired_error_rad`` is set,
                       the attitude error against the reference ``<=`` it) for
                       ``healthy_for_s``
SAFE -> HOLD           health OK, converged, control not lost, the wheels within their       ``recovered``
                       limit, for ``recover_for_s`` (then HOLD's own guard to TRACK)
=====================  ===================================================================  ================

A transition restarts every count: each guard counts from its mode's entry (HOLD after SAFE waits
its own ``healthy_for_s`` before TRACK).  DETUMBLE has no SAFE guard: while the spacecraft
tumbles the tracker cannot lock and the estimator is expected to report ERROR, and DETUMBLE
uses neither the estimate nor the wheels.  The SAFE guards come first in HOLD and TRACK: a sample
that meets a SAFE condition never starts TRACK.  Ground commands: ``IN_REQUEST`` (``-1``: none) and
``IN_INHIBIT``, a sum of ``INHIBIT_*`` flags that each stop one automatic transition (a request
still goes through).  An unknown input (NaN: no measurement yet, no health message yet) meets no
condition: it neither starts a mode nor sends one to SAFE.

The kernel runs compiled (numba) in loops and interpreted (``mode_step.py_func``) in a node: the
same operations on the same doubles, so the same modes.  Flight software: never imports the
simulator; plain arrays, nothing allocated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import error_quaternion, jit
from gnc_common.validation import ConfigError, check_positive

__all__ = [
    "DEFAULT_CONVERGED_SIGMA_RAD",
    "DEFAULT_DETUMBLED_FOR_S",
    "DEFAULT_DETUMBLED_RATE_RAD_S",
    "DEFAULT_HEALTHY_FOR_S",
    "DEFAULT_MAX_WHEEL_SPEED_FRACTION",
    "DEFAULT_RECOVER_FOR_S",
    "DEFAULT_SAFE_ON_ERROR_FOR_S",
    "DETUMBLE",
    "HEALTH_ERROR",
    "HEALTH_OK",
    "HEALTH_STALE",
    "HEALTH_WARN",
    "HOLD",
    "INHIBIT_ACQUIRED",
    "INHIBIT_DETUMBLED",
    "INHIBIT_RECOVERED",
    "INHIBIT_SAFE",
    "IN_ERROR",
    "IN_HEALTH",
    "IN_INHIBIT",
    "IN_LOST",
    "IN_RATE",
    "IN_REQUEST",
    "IN_SIGMA",
    "IN_WHEEL",
    "MODE_NAMES",
    "N_INPUTS",
    "N_PARAMS",
    "N_STATE",
    "ModeConfig",
    "REASON_NAMES",
    "R_ACQUIRED",
    "R_CONTROL_LOST",
    "R_DETUMBLED",
    "R_ESTIMATOR_ERROR",
    "R_NONE",
    "R_RECOVERED",
    "R_REQUEST",
    "R_WHEEL_SPEED",
    "SAFE",
    "S_MODE",
    "S_REASON",
    "TRACK",
    "mode_step",
    "new_mode_state",
    "samples_for",
]

Array = NDArray[np.float64]

#: The modes, in the order a flight normally meets them; :data:`MODE_NAMES` their names.
DETUMBLE, HOLD, TRACK, SAFE = 0, 1, 2, 3
MODE_NAMES = ("DETUMBLE", "HOLD", "TRACK", "SAFE")
#: The estimator's health levels, diagnostic_msgs/DiagnosticStatus's (``monitor_level`` on ``diagnostics``).
HEALTH_OK, HEALTH_WARN, HEALTH_ERROR, HEALTH_STALE = 0, 1, 2, 3

#: Inputs of a sample (:data:`N_INPUTS` floats): the body-rate magnitude [rad/s]; the estimator's
#: health level (``HEALTH_*``); its attitude 1-sigma, the largest axis's [rad]; 1.0 when the run's
#: loss-of-control rule fires, else 0.0; the largest wheel speed as a fraction of its limit (NaN:
#: no wheels); the ground's requested mode (-1: none); the ground's inhibit flags (a sum of ``INHIBIT_*``);
#: the estimate's attitude error against the reference, its rotation angle [rad] (NaN: unknown).
IN_RATE, IN_HEALTH, IN_SIGMA, IN_LOST, IN_WHEEL, IN_REQUEST, IN_INHIBIT, IN_ERROR = 0, 1, 2, 3, 4, 5, 6, 7
N_INPUTS = 8
#: Inhibit flags (``IN_INHIBIT``): each stops one automatic transition.
INHIBIT_DETUMBLED, INHIBIT_ACQUIRED, INHIBIT_SAFE, INHIBIT_RECOVERED = 1, 2, 4, 8
#: Parameters (:meth:`ModeConfig.packed`): the rate threshold and its samples, the convergence
#: threshold, the samples of health, of ERROR and of recovery, the wheel-speed fraction, the
#: acquisition's error threshold (infinite: no condition), the lost attitude's error threshold
#: (infinite: no condition) and its samples.
P_RATE, P_RATE_N, P_SIGMA, P_HEALTHY_N, P_ERROR_N, P_RECOVER_N, P_WHEEL, P_ACQUIRED, P_LOST, P_LOST_N = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
N_PARAMS = 10
#: State (:func:`new_mode_state`): the mode, the consecutive samples each condition has held since
#: the mode's entry (slow rate, healthy and acquired, ERROR, recovering), the reason of the last
#: transition, the consecutive samples of a lost attitude (:data:`COUNTS`: the counts).
S_MODE, S_RATE_N, S_HEALTHY_N, S_ERROR_N, S_RECOVER_N, S_REASON, S_LOST_N = 0, 1, 2, 3, 4, 5, 6
N_STATE = 7
#: The state's consecutive-sample counts (each restarts at a transition: :func:`restart_counts`).
COUNTS = (S_RATE_N, S_HEALTHY_N, S_ERROR_N, S_RECOVER_N, S_LOST_N)
#: Why a transition was taken (:func:`mode_step`'s return), :data:`REASON_NAMES` their names.
R_NONE, R_REQUEST, R_DETUMBLED, R_ACQUIRED, R_ESTIMATOR_ERROR, R_CONTROL_LOST, R_WHEEL_SPEED, R_RECOVERED = 0, 1, 2, 3, 4, 5, 6, 7
REASON_NAMES = ("none", "request", "detumbled", "acquired", "estimator_error", "control_lost", "wheel_speed", "recovered")

#: Default ``detumbled_rate_rad_s`` (0.5 deg/s): star trackers acquire below about 1 deg/s
#: (datasheets give 0.5 to 3 deg/s); half the lower figure leaves the tracker margin to lock in HOLD.
DEFAULT_DETUMBLED_RATE_RAD_S = math.radians(0.5)
#: Default ``detumbled_for_s``: the rate below the threshold for 30 s, not one quiet sample of a
#: tumble whose rate B-dot damps unevenly along the field's rotation.
DEFAULT_DETUMBLED_FOR_S = 30.0
#: Default ``converged_sigma_rad``: the estimate within twice the flight scenario's tracking
#: requirement (5e-5 on ``q_ev``, a half-angle: 1e-4 rad of angle), so TRACK starts on an estimate
#: good enough for what TRACK must meet.
DEFAULT_CONVERGED_SIGMA_RAD = 1e-4
#: Default ``healthy_for_s``: ten of the estimator's health messages (1 Hz) in a row OK and converged.
DEFAULT_HEALTHY_FOR_S = 10.0
#: Default ``safe_on_error_for_s``: 5 s of ERROR. The health monitor's ERROR is a verdict on a window
#: of innovations, but a consistent filter still raises it now and then: in the separation's
#: campaign (8 runs of 5700 s) two ERROR episodes of 2.0 s each (two verdicts) in one run, the
#: estimate's error at 2.5e-5 throughout; at once, each sent a tracking spacecraft to SAFE. A
#: real loss (a blinded tracker) persists: SAFE then comes 5 s after its ERROR.
DEFAULT_SAFE_ON_ERROR_FOR_S = 5.0
#: Default ``recover_for_s``: 30 s of health before leaving SAFE, three times HOLD's own wait, so a
#: health that flickers at the monitor's threshold does not cycle SAFE and HOLD.
DEFAULT_RECOVER_FOR_S = 30.0
#: Default ``max_wheel_speed_fraction``: SAFE beyond a wheel's speed limit itself (the issue's guard).
DEFAULT_MAX_WHEEL_SPEED_FRACTION = 1.0
#: Default ``lost_for_s``: 10 s of a lost attitude before SAFE (with ``lost_error_rad`` set). A
#: tracking controller recovers a fault's transient in seconds (the paper's sudden fault: under 5 s
#: outside its band); a spacecraft still far off after twice that is not coming back on its own.
DEFAULT_LOST_FOR_S = 10.0


def samples_for(seconds: float, dt_s: float) -> int:
    """The consecutive samples of period ``dt_s`` a condition must hold for to have held
    ``seconds``: ``ceil(seconds / dt_s)``, at least one (0 s: the sample itself); a quotient within
    1e-9 of an integer counts as that integer (0.3 s at 0.1 s is 3 samples, not 4)."""
    q = seconds / dt_s
    n = math.ceil(q - 1e-9 * max(1.0, q))
    return max(1, int(n))


def _check_number(name: str, value: object, *, positive: bool) -> float:
    """``value`` checked as every setting of the project is (:func:`~gnc_common.validation.check_positive`), one number."""
    x = check_positive(name, value, allow_zero=not positive)
    if not isinstance(x, float):
        raise ConfigError(f"{name} must be one number, got {value!r}")
    return x


@dataclass(frozen=True)
class ModeConfig:
    """The guards' thresholds and persistences (module docstring); each default is a named
    constant with its reason.

    Attributes
    ----------
    detumbled_rate_rad_s : float
        DETUMBLE -> HOLD below this body-rate magnitude [rad/s] (> 0).
    detumbled_for_s : float
        ... held this long [s] (>= 0).
    converged_sigma_rad : float
        HOLD -> TRACK (and SAFE -> HOLD) with the estimate's attitude 1-sigma at most this [rad] (> 0).
    healthy_for_s : float
        ... and health OK, this long [s] (>= 0).
    safe_on_error_for_s : float
        HOLD, TRACK -> SAFE after the health's ERROR or STALE this long [s] (>= 0; 0: at once).
    recover_for_s : float
        SAFE -> HOLD after every SAFE condition cleared and health OK and converged this long [s] (>= 0).
    max_wheel_speed_fraction : float
        HOLD, TRACK -> SAFE when a wheel's speed passes this fraction of its limit (> 0).
    acquired_error_rad : float or None
        HOLD -> TRACK also needs the attitude error against the reference (its rotation angle) at
        most this [rad] (> 0): a HOLD that points at the reference hands over near it, where the
        tracking controller's funnel is feasible (docs/design/modes.md); ``None`` (default): no
        such condition.
    lost_error_rad : float or None
        TRACK -> SAFE (reason ``control_lost``) when the estimate's attitude error against the
        reference (its rotation angle) stays above this [rad] (> 0) for ``lost_for_s``: the
        loss-of-control rule flight software can apply online (the run's own rule,
        :mod:`sappc.evaluation.requirements`, judges the true error after the run); ``None``
        (default): no such condition.  A sample without a valid estimate restarts the count.
    lost_for_s : float
        ... held this long [s] (>= 0).
    """

    detumbled_rate_rad_s: float = DEFAULT_DETUMBLED_RATE_RAD_S
    detumbled_for_s: float = DEFAULT_DETUMBLED_FOR_S
    converged_sigma_rad: float = DEFAULT_CONVERGED_SIGMA_RAD
    healthy_for_s: float = DEFAULT_HEALTHY_FOR_S
    safe_on_error_for_s: float = DEFAULT_SAFE_ON_ERROR_FOR_S
    recover_for_s: float = DEFAULT_RECOVER_FOR_S
    max_wheel_speed_fraction: float = DEFAULT_MAX_WHEEL_SPEED_FRACTION
    acquired_error_rad: float | None = None
    lost_error_rad: float | None = None
    lost_for_s: float = DEFAULT_LOST_FOR_S

    def __post_init__(self) -> None:
        for name in ("detumbled_rate_rad_s", "converged_sigma_rad", "max_wheel_speed_fraction"):
            object.__setattr__(self, name, _check_number(name, getattr(self, name), positive=True))
        if self.acquired_error_rad is not None:
            object.__setattr__(self, "acquired_error_rad", _check_number("acquired_error_rad", self.acquired_error_rad, positive=True))
        if self.lost_error_rad is not None:
            object.__setattr__(self, "lost_error_rad", _check_number("lost_error_rad", self.lost_error_rad, positive=True))
        for name in ("detumbled_for_s", "healthy_for_s", "safe_on_error_for_s", "recover_for_s", "lost_for_s"):
            object.__setattr__(self, name, _check_number(name, getattr(self, name), positive=False))

    def packed(self, dt_s: float) -> Array:
        """The parameters as :func:`mode_step` takes them (:data:`N_PARAMS`,), the persistences in
        samples of period ``dt_s`` (:func:`samples_for`)."""
        dt = _check_number("dt_s", dt_s, positive=True)
        out = np.zeros(N_PARAMS)
        out[P_RATE] = self.detumbled_rate_rad_s
        out[P_RATE_N] = samples_for(self.detumbled_for_s, dt)
        out[P_SIGMA] = self.converged_sigma_rad
        out[P_HEALTHY_N] = samples_for(self.healthy_for_s, dt)
        out[P_ERROR_N] = samples_for(self.safe_on_error_for_s, dt)
        out[P_RECOVER_N] = samples_for(self.recover_for_s, dt)
        out[P_WHEEL] = self.max_wheel_speed_fraction
        out[P_ACQUIRED] = math.inf if self.acquired_error_rad is None else self.acquired_error_rad
        out[P_LOST] = math.inf if self.lost_error_rad is None else self.lost_error_rad
        out[P_LOST_N] = samples_for(self.lost_for_s, dt)
        return out


def new_mode_state(mode: int = DETUMBLE) -> Array:
    """A flight's state (:data:`N_STATE`,) starting in ``mode`` (default DETUMBLE: after separation)."""
    if isinstance(mode, bool) or mode not in (DETUMBLE, HOLD, TRACK, SAFE):
        raise ConfigError(f"mode must be one of {dict(enumerate(MODE_NAMES))}, got {mode!r}")
    state = np.zeros(N_STATE)
    state[S_MODE] = mode
    return state


@jit
def mode_step(state, inputs, params):  # type: ignore[no-untyped-def]  # a numba kernel
    """One sample (module docstring): ``state`` (:data:`N_STATE`,) updated in place from ``inputs``
    (:data:`N_INPUTS`,) and ``params`` (:meth:`ModeConfig.packed`); returns the reason of the
    transition taken (``R_*``), :data:`R_NONE` for none."""
    mode = int(state[S_MODE])
    flags = inputs[IN_INHIBIT]
    inhibit = int(flags) if flags >= 0.0 and flags < 16.0 else 0  # NaN or out of range: nothing inhibited (a node refuses such a command)
    health = inputs[IN_HEALTH]
    lost = inputs[IN_LOST] > 0.5
    wheel_beyond = inputs[IN_WHEEL] > params[P_WHEEL]  # NaN (no wheels): never beyond
    healthy = health == HEALTH_OK and inputs[IN_SIGMA] <= params[P_SIGMA]
    acquired = params[P_ACQUIRED] == math.inf or inputs[IN_ERROR] <= params[P_ACQUIRED]  # no condition, or near the reference
    # the counts of consecutive samples (a NaN input fails every comparison it is in: no count)
    state[S_RATE_N] = state[S_RATE_N] + 1.0 if inputs[IN_RATE] < params[P_RATE] else 0.0
    state[S_HEALTHY_N] = state[S_HEALTHY_N] + 1.0 if healthy and acquired else 0.0
    state[S_ERROR_N] = state[S_ERROR_N] + 1.0 if health >= HEALTH_ERROR else 0.0
    state[S_RECOVER_N] = state[S_RECOVER_N] + 1.0 if healthy and not lost and not wheel_beyond else 0.0
    state[S_LOST_N] = state[S_LOST_N] + 1.0 if inputs[IN_ERROR] > params[P_LOST] else 0.0  # (infinite: never; NaN: no count)
    request = inputs[IN_REQUEST]
    target = mode
    reason = R_NONE
    if request >= 0.0 and request <= 3.0 and request == math.floor(request) and int(request) != mode:
        target = int(request)
        reason = R_REQUEST
    elif mode == HOLD or mode == TRACK:
        if (inhibit & INHIBIT_SAFE) == 0:
            if lost or (mode == TRACK and state[S_LOST_N] >= params[P_LOST_N]):
                target = SAFE
                reason = R_CONTROL_LOST
            elif wheel_beyond:
                target = SAFE
                reason = R_WHEEL_SPEED
            elif state[S_ERROR_N] >= params[P_ERROR_N]:
                target = SAFE
                reason = R_ESTIMATOR_ERROR
        if reason == R_NONE and mode == HOLD and (inhibit & INHIBIT_ACQUIRED) == 0 and state[S_HEALTHY_N] >= params[P_HEALTHY_N]:
            target = TRACK
            reason = R_ACQUIRED
    elif mode == DETUMBLE:
        if (inhibit & INHIBIT_DETUMBLED) == 0 and state[S_RATE_N] >= params[P_RATE_N]:
            target = HOLD
            reason = R_DETUMBLED
    elif mode == SAFE:
        if (inhibit & INHIBIT_RECOVERED) == 0 and state[S_RECOVER_N] >= params[P_RECOVER_N]:
            target = HOLD
            reason = R_RECOVERED
    if reason != R_NONE:
        state[S_MODE] = target
        restart_counts(state)
        state[S_REASON] = reason
    return reason


@jit
def restart_counts(state):  # type: ignore[no-untyped-def]  # a numba kernel
    """Every consecutive-sample count of ``state`` (:data:`COUNTS`) back to zero: a transition's
    (each guard counts from its mode's entry), or a mode node's activation."""
    state[S_RATE_N] = 0.0
    state[S_HEALTHY_N] = 0.0
    state[S_ERROR_N] = 0.0
    state[S_RECOVER_N] = 0.0
    state[S_LOST_N] = 0.0


@jit
def attitude_error_angle(q_RN, q_BN, q_err):  # type: ignore[no-untyped-def]  # a numba kernel
    """The mode manager's ``IN_ERROR``: the rotation angle [rad] of the attitude ``q_BN`` against the
    reference ``q_RN`` (``q_err``, (4,), receives the error quaternion ``q_BR`` with ``q_0 >= 0``,
    :func:`~gnc_common.compiled.error_quaternion`), ``2 atan2(|q_err,v|, |q_err,0|)``.  The offline
    loop's and the mode node's one formula."""
    error_quaternion(q_RN, q_BN, q_err)
    return 2.0 * math.atan2(math.sqrt((q_err[0] * q_err[0] + q_err[1] * q_err[1]) + q_err[2] * q_err[2]), abs(q_err[3]))


@jit
def wheel_speed_fraction(speeds_rad_s, max_speeds_rad_s):  # type: ignore[no-untyped-def]  # a numba kernel
    """The mode manager's ``IN_WHEEL``: the largest ``|speed_i| / max_speed_i`` of the wheels (0.0 for
    none: the loop gives NaN without wheels itself).  The offline loop's and the mode node's one formula."""
    frac = 0.0
    for i in range(speeds_rad_s.shape[0]):
        frac = max(frac, abs(speeds_rad_s[i]) / max_speeds_rad_s[i])
    return frac


@jit
def sigma_of_covariance(P):  # type: ignore[no-untyped-def]  # a numba kernel
    """The mode manager's ``IN_SIGMA``: the largest attitude 1-sigma [rad] of the estimator's
    covariance ``P`` (6, 6), ``sqrt(max(P_00, P_11, P_22))``.  The offline loop's and the mode node's one formula."""
    return math.sqrt(max(P[0, 0], max(P[1, 1], P[2, 2])))


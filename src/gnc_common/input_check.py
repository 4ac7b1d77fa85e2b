"""The controller's acceptance test of its inputs: finite, unit quaternions, plausible magnitudes.

In the ground floor because the flight software shares it: the controller, and the mode manager
(:mod:`sappc_modes.node` reads the estimate's error against the reference only on a sample the
controller finds valid).  One implementation for every path: the offline loop checks each sample's five inputs with
:func:`sample_verdicts` (:func:`sappc.offline.compiled_loop._run_one`, inside its compiled loop),
the controller node each message with :func:`input_verdict` (:mod:`sappc_controller.node`, after
the message's frame id and finiteness are decoded), which runs the same verdict kernels' source
interpreted (the same operations: the same verdicts).  An input that fails is
*rejected*: it never reaches the law, it is counted by reason (:data:`REJECT_REASONS`), and its
sample has no valid inputs, so the controller answers it without the law (held or watchdog zero,
:mod:`sappc_msgs_py.contract`), the same way on both paths.

Verdicts (:data:`INPUT_OK`, :data:`INPUT_INVALID`, :data:`INPUT_IMPLAUSIBLE`):

- invalid: a non-finite value, or a quaternion whose norm differs from 1 by more than
  ``max_attitude_norm_error`` (a zero quaternion included);
- implausible: a finite vector whose magnitude exceeds its bound: the measured body rate
  ``max_body_rate_rad_s``, the reference rate ``max_reference_rate_rad_s``, the reference
  acceleration ``max_reference_acceleration_rad_s2``.  Without this bound a rate of 1e12 rad/s
  is a finite number the law turns into a saturated torque and commands.

The bounds are :class:`InputBounds` (the node's parameters, a scenario's ``controller_node``
section); each default is a named constant below with its reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, InputError, check_positive

__all__ = [
    "DEFAULT_MAX_BODY_RATE_RAD_S",
    "DEFAULT_MAX_REFERENCE_ACCELERATION_RAD_S2",
    "DEFAULT_MAX_REFERENCE_RATE_RAD_S",
    "INPUT_IMPLAUSIBLE",
    "INPUT_INVALID",
    "INPUT_OK",
    "InputBounds",
    "ImplausibleInputError",
    "REJECT_REASONS",
    "check_input",
    "input_verdict",
    "sample_verdicts",
]

#: Verdicts of :func:`input_verdict`: accepted; rejected as invalid; rejected as implausible.
INPUT_OK, INPUT_INVALID, INPUT_IMPLAUSIBLE = 0, 1, 2
#: Why an input is rejected, as the node counts it (``rejected_by_reason`` keys, its summary and
#: ``sappc simulate``'s): a wrong frame id, a non-finite value or a zero or non-unit quaternion
#: (``invalid``); a magnitude beyond its :class:`InputBounds` bound (``implausible``); a stamp not
#: after the last computed sample (lockstep) or the topic's previous message (real time); a stamp
#: more than ``max_stamp_ahead_s`` ahead.  The offline loop can only meet the first two.
REJECT_REASONS = ("invalid", "implausible", "stamp_in_past", "stamp_too_far_ahead")

#: Input slots, in the order of :data:`sappc_msgs_py.contract.CONTROLLER_INPUTS` (and of
#: ``AttitudeController.step``): measured attitude, measured body rate, reference attitude,
#: reference rate, reference acceleration.
SLOT_ATTITUDE, SLOT_RATE, SLOT_REFERENCE_ATTITUDE, SLOT_REFERENCE_RATE, SLOT_REFERENCE_ACCELERATION = 0, 1, 2, 3, 4
#: What each slot is, in messages.
SLOT_NAMES = ("attitude", "body rate", "reference attitude", "reference rate", "reference acceleration")

#: Default ``max_body_rate_rad_s`` [rad/s] (573 deg/s): above the full-scale range of spacecraft
#: rate gyros (navigation-grade fibre-optic gyros measure up to 10 to 20 deg/s, MEMS gyros up to
#: about 400 deg/s = 7 rad/s), so a larger measured rate is a sensor or link fault, not a state; a
#: spacecraft tumbling that fast is outside any attitude controller's task.
DEFAULT_MAX_BODY_RATE_RAD_S = 10.0
#: Default ``max_reference_rate_rad_s`` [rad/s]: the body-rate bound, for the same reason: a
#: desired rate that no gyro could confirm is a guidance fault (the paper's is 0.01 rad/s).
DEFAULT_MAX_REFERENCE_RATE_RAD_S = 10.0
#: Default ``max_reference_acceleration_rad_s2`` [rad/s^2]: ten times what the most agile small
#: spacecraft can do (a 1 mN m wheel on a 1U CubeSat of 1e-3 kg m^2 gives 1 rad/s^2; the paper's
#: 0.5 N m on 4 kg m^2 gives 0.125 rad/s^2), so a larger desired acceleration is a guidance fault.
DEFAULT_MAX_REFERENCE_ACCELERATION_RAD_S2 = 10.0

#: Layout of :meth:`InputBounds.packed` (what the compiled checks take).
B_NORM, B_RATE, B_REFERENCE_RATE, B_REFERENCE_ACCELERATION = 0, 1, 2, 3
N_BOUNDS = 4


class ImplausibleInputError(InputError):
    """A finite input whose magnitude exceeds its plausibility bound (:class:`InputBounds`)."""

    reason = "implausible"


@dataclass(frozen=True)
class InputBounds:
    """Plausibility bounds on the controller's inputs (module docstring).

    Attributes
    ----------
    max_attitude_norm_error : float
        Largest accepted ``| |q| - 1 |`` of the measured and the reference attitude, in
        ``(0, QUATERNION_NORM_TOL]``: it may be tightened, not loosened, since the law itself
        requires unit quaternions to :data:`~gnc_common.validation.QUATERNION_NORM_TOL`.
    max_body_rate_rad_s : float
        Largest accepted magnitude of the measured body rate [rad/s]
        (:data:`DEFAULT_MAX_BODY_RATE_RAD_S`).
    max_reference_rate_rad_s : float
        Largest accepted magnitude of the reference rate [rad/s]
        (:data:`DEFAULT_MAX_REFERENCE_RATE_RAD_S`).
    max_reference_acceleration_rad_s2 : float
        Largest accepted magnitude of the reference acceleration [rad/s^2]
        (:data:`DEFAULT_MAX_REFERENCE_ACCELERATION_RAD_S2`).
    """

    max_attitude_norm_error: float = QUATERNION_NORM_TOL
    max_body_rate_rad_s: float = DEFAULT_MAX_BODY_RATE_RAD_S
    max_reference_rate_rad_s: float = DEFAULT_MAX_REFERENCE_RATE_RAD_S
    max_reference_acceleration_rad_s2: float = DEFAULT_MAX_REFERENCE_ACCELERATION_RAD_S2

    def __post_init__(self) -> None:
        for name in ("max_attitude_norm_error", "max_body_rate_rad_s", "max_reference_rate_rad_s", "max_reference_acceleration_rad_s2"):
            value = getattr(self, name)
            if isinstance(value, bool):
                raise ConfigError(f"{name} must be a number, got {value!r}")
            object.__setattr__(self, name, check_positive(name, value))
        if self.max_attitude_norm_error > QUATERNION_NORM_TOL:
            raise ConfigError(f"max_attitude_norm_error must be in (0, {QUATERNION_NORM_TOL:g}] (the law requires unit quaternions to "
                              f"{QUATERNION_NORM_TOL:g}), got {self.max_attitude_norm_error!r}")

    def packed(self) -> NDArray[np.float64]:
        """The bounds as the compiled checks take them, (:data:`N_BOUNDS`,)."""
        out = np.zeros(N_BOUNDS)
        out[B_NORM] = self.max_attitude_norm_error
        out[B_RATE] = self.max_body_rate_rad_s
        out[B_REFERENCE_RATE] = self.max_reference_rate_rad_s
        out[B_REFERENCE_ACCELERATION] = self.max_reference_acceleration_rad_s2
        return out

    def bound_of(self, slot: int) -> tuple[str, float, str]:
        """The bound of input ``slot`` (a vector slot): its parameter name, value and unit."""
        name = {SLOT_RATE: "max_body_rate_rad_s", SLOT_REFERENCE_RATE: "max_reference_rate_rad_s",
                SLOT_REFERENCE_ACCELERATION: "max_reference_acceleration_rad_s2"}[slot]
        return name, float(getattr(self, name)), "rad/s^2" if slot == SLOT_REFERENCE_ACCELERATION else "rad/s"


@jit(inline="always")  # type: ignore[no-untyped-call]
def quaternion_verdict(q0, q1, q2, q3, max_norm_error):  # type: ignore[no-untyped-def]  # a numba kernel (float64 scalars)
    """:data:`INPUT_OK` for a quaternion ``(q0, q1, q2, q3)`` whose norm is within
    ``max_norm_error`` of 1, else :data:`INPUT_INVALID` (a non-finite component fails the
    comparison).  The norm is summed as :func:`gnc_common.validation.check_unit_quaternion` sums
    it.  Scalars, not an array: no reference count per call in the loop that inlines it; ``math``'s
    functions, not numpy's: the same correctly rounded square root compiled, and interpreted
    (:func:`input_verdict`) no numpy scalar call (a third of a microsecond each)."""
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    return INPUT_OK if abs(norm - 1.0) <= max_norm_error else INPUT_INVALID


@jit(inline="always")  # type: ignore[no-untyped-call]
def vector_verdict(v0, v1, v2, max_norm):  # type: ignore[no-untyped-def]  # a numba kernel (float64 scalars)
    """:data:`INPUT_INVALID` for a 3-vector ``(v0, v1, v2)`` with a non-finite component,
    :data:`INPUT_IMPLAUSIBLE` when its magnitude (computed scaled by the largest component, so
    that a finite vector never overflows) exceeds ``max_norm``, else :data:`INPUT_OK`."""
    if not (math.isfinite(v0) and math.isfinite(v1) and math.isfinite(v2)):
        return INPUT_INVALID
    scale = max(abs(v0), abs(v1), abs(v2))  # the magnitude scaled: no overflow for a finite vector
    if scale == 0.0:
        return INPUT_OK
    a, b, c = v0 / scale, v1 / scale, v2 / scale
    norm = scale * math.sqrt((a * a + b * b) + c * c)
    return INPUT_IMPLAUSIBLE if norm > max_norm else INPUT_OK


def input_verdict(slot: int, value: NDArray[np.float64] | tuple[float, ...], bounds: NDArray[np.float64] | list[float]) -> int:
    """The verdict on one input of ``slot`` (``SLOT_*``): a quaternion (4,) or a vector (3,), an
    array or the tuple of floats a message's bytes unpack to; ``bounds`` (:data:`N_BOUNDS`,) from
    :meth:`InputBounds.packed` (the node's check of a message), or its ``tolist()``.

    The source of the compiled verdicts (:func:`quaternion_verdict`, :func:`vector_verdict`, which
    the offline loop runs inside its compiled loop), interpreted: a compiled call from Python spends
    about 20 us typing its arguments, which for one message is ten times the check itself; the
    interpreted source makes the same IEEE operations on the same doubles (products, sums, a
    correctly rounded square root, comparisons), so the verdict is the same."""
    v = value if type(value) is tuple else value.tolist() if type(value) is np.ndarray else [float(x) for x in value]
    if slot == SLOT_ATTITUDE or slot == SLOT_REFERENCE_ATTITUDE:
        return int(quaternion_verdict.py_func(v[0], v[1], v[2], v[3], float(bounds[B_NORM])))
    bound = bounds[B_RATE] if slot == SLOT_RATE else bounds[B_REFERENCE_RATE] if slot == SLOT_REFERENCE_RATE else bounds[B_REFERENCE_ACCELERATION]
    return int(vector_verdict.py_func(v[0], v[1], v[2], float(bound)))


@jit(inline="always")  # type: ignore[no-untyped-call]
def sample_verdicts(state_delivered, reference_delivered, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R, bounds, rejected):  # type: ignore[no-untyped-def]  # a numba kernel
    """Whether one sample's five inputs are all accepted (the offline loop), counting each rejected
    input into ``rejected`` (2,) int64: ``[invalid, implausible]``.

    ``state_delivered`` / ``reference_delivered`` false: those inputs arrived as "no data" (a
    dropout: the injector relays the contract's "no data" sample, NaN in every value; the estimator's
    sample without an estimate), so the sample is not valid, but nothing is counted: "no data" is no
    rejected input (the node counts it apart, :mod:`sappc_msgs_py.inputs`)."""
    n_invalid = 0
    n_implausible = 0
    if state_delivered:
        v0 = quaternion_verdict(q_BN[0], q_BN[1], q_BN[2], q_BN[3], bounds[B_NORM])
        v1 = vector_verdict(omega_BN_B[0], omega_BN_B[1], omega_BN_B[2], bounds[B_RATE])
        n_invalid += int(v0 == INPUT_INVALID) + int(v1 == INPUT_INVALID)
        n_implausible += int(v0 == INPUT_IMPLAUSIBLE) + int(v1 == INPUT_IMPLAUSIBLE)
    if reference_delivered:
        v2 = quaternion_verdict(q_RN[0], q_RN[1], q_RN[2], q_RN[3], bounds[B_NORM])
        v3 = vector_verdict(omega_RN_R[0], omega_RN_R[1], omega_RN_R[2], bounds[B_REFERENCE_RATE])
        v4 = vector_verdict(omegadot_RN_R[0], omegadot_RN_R[1], omegadot_RN_R[2], bounds[B_REFERENCE_ACCELERATION])
        n_invalid += (int(v2 == INPUT_INVALID) + int(v3 == INPUT_INVALID)) + int(v4 == INPUT_INVALID)
        n_implausible += (int(v2 == INPUT_IMPLAUSIBLE) + int(v3 == INPUT_IMPLAUSIBLE)) + int(v4 == INPUT_IMPLAUSIBLE)
    ok = state_delivered and reference_delivered and n_invalid == 0 and n_implausible == 0
    rejected[INPUT_INVALID - 1] += n_invalid
    rejected[INPUT_IMPLAUSIBLE - 1] += n_implausible
    return ok


def check_input(slot: int, name: str, value: NDArray[np.float64], bounds: InputBounds, packed: NDArray[np.float64] | None = None) -> None:
    """Accept input ``value`` of ``slot`` (named ``name`` in the message) or raise, by
    :func:`input_verdict` (the node's check of each message).

    ``packed``: ``bounds.packed()``, when the caller keeps it (no array per message).

    Raises
    ------
    InputError
        An invalid value (non-finite, or a quaternion off unit norm), naming it.
    ImplausibleInputError
        A magnitude beyond its bound, naming the value, the bound and its parameter.
    """
    verdict = int(input_verdict(slot, value, bounds.packed() if packed is None else packed))
    if verdict == INPUT_OK:
        return
    values = ", ".join(f"{v:.6g}" for v in value.tolist())
    if slot in (SLOT_ATTITUDE, SLOT_REFERENCE_ATTITUDE):
        norm = math.sqrt(sum(v * v for v in value.tolist())) if np.all(np.isfinite(value)) else math.nan
        raise InputError(f"{name} must be a unit quaternion (x, y, z, w) to within max_attitude_norm_error = "
                         f"{bounds.max_attitude_norm_error:g}, got [{values}] with norm {norm:.9g}")
    if verdict == INPUT_INVALID:
        raise InputError(f"{name} contains a non-finite value: [{values}]")
    param, bound, unit = bounds.bound_of(slot)
    magnitude = math.hypot(*value.tolist())
    raise ImplausibleInputError(f"{name}: the {SLOT_NAMES[slot]} [{values}] has magnitude {magnitude:.6g} {unit}, "
                                f"above {param} = {bound:g} {unit} (implausible)")

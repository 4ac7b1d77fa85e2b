"""The controller interface shared by SAPPC, TraPPC, BLFPPC and MRP feedback.

A controller never reads a clock: time ``t`` [s] and the sampling period ``dt`` [s] are arguments
of :meth:`AttitudeController.step`.  Inputs are checked there, in Python, once; the law itself is
the compiled kernel :func:`sappc_controller.core.kernels.controller_step` (one implementation for
the node, ``sappc rerun``, the offline loop and Monte Carlo), called for one run or a batch.

``kernels`` is imported when the first controller is built, not with this module: the kernels
depend on this module's start check, and modules that only need :class:`ControlOutput` (bag
analysis, metrics) do not pay numba's import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, InputError, as_finite_array, check_unit_quaternion

__all__ = ["AttitudeController", "ControlOutput", "SINGULAR_Q0_AT_START", "SingularStartError", "check_start"]

Array = NDArray[np.float64]
_F64 = np.dtype(np.float64)

#: A run may not *start* with an error scalar part below this: the paper's Jacobian is singular
#: at q_e0 = 0 (180 deg error, docs/paper_notes.md, error 5) and the RPF sign and the virtual
#: control are undefined there.  1e-6 is 179.9998 deg.
SINGULAR_Q0_AT_START = 1e-6


@dataclass(frozen=True)
class ControlOutput:
    """One control step's result for a batch (leading axis N), or one run (no batch axis).

    The arrays are views of the controller's output buffer: they hold this step's values until
    the controller's next :meth:`~AttitudeController.step` (or :meth:`~AttitudeController.reset`),
    which overwrites them.  Copy what you keep (:meth:`copy`).

    Attributes
    ----------
    torque_B : torque produced by the actuator model [N m], body frame.
    torque_cmd_B : torque commanded by the law before the actuator model [N m].
    saturated : per-axis flag, ``|torque_cmd_B| > max_torque_Nm``.
    q_BR : error quaternion used (scalar last, ``q0 >= 0``).
    rho : performance / reference function value per component.
    band_lower, band_upper : constraint band on ``q_ev`` per component.
    eps : transformed error per component.
    z : ``q_ev / rho`` per component (BLFPPC: ``q_ev``).
    V : (…, 3) Lyapunov values ``V1, V2, V3`` of the backstepping layers.
    """

    torque_B: Array
    torque_cmd_B: Array
    saturated: NDArray[np.bool_]
    q_BR: Array
    rho: Array
    band_lower: Array
    band_upper: Array
    eps: Array
    z: Array
    V: Array

    def first(self) -> ControlOutput:
        """The same output with the batch axis removed (run 0)."""
        return ControlOutput(**{f.name: getattr(self, f.name)[0] for f in fields(self)})

    def copy(self) -> ControlOutput:
        """The same output in arrays of its own (not overwritten by the next step)."""
        return ControlOutput(**{f.name: np.array(getattr(self, f.name)) for f in fields(self)})


class SingularStartError(InputError):
    """A run starts at the 180 deg singularity: ``q_e0 < SINGULAR_Q0_AT_START``.

    Attributes
    ----------
    q_e0 : float
        The run's initial error scalar part.
    run : int
        The run's index (along the batch axis, or a campaign's run number once the campaign names it).
    """

    def __init__(self, q_e0: float, run: int) -> None:
        self.q_e0, self.run = q_e0, run
        super().__init__(
            f"initial error quaternion scalar part q_e0 = {q_e0:.3g} (run {run}) is at the 180 deg singularity "
            f"of Gamma(q_e) (needs q_e0 >= {SINGULAR_Q0_AT_START}): the RPF sign and the virtual control are undefined"
        )

    def __reduce__(self) -> tuple[type[SingularStartError], tuple[float, int]]:  # crosses process boundaries (campaign workers)
        return SingularStartError, (self.q_e0, self.run)


def check_start(q_BR: ArrayLike) -> None:
    """Refuse a run that starts at the 180 deg singularity (``q_e0 < SINGULAR_Q0_AT_START``).

    Parameters
    ----------
    q_BR : array_like, (N, 4) or (4,)
        The runs' first error quaternions (scalar last, ``q0 >= 0``).

    Raises
    ------
    SingularStartError
        Naming the first such run of the batch (its index along the batch axis) and its ``q_e0``.
    """
    q0 = np.atleast_2d(np.asarray(q_BR, dtype=np.float64))[:, 3]
    bad = q0 < SINGULAR_Q0_AT_START
    if np.any(bad):
        k = int(np.argmax(bad))
        raise SingularStartError(float(q0[k]), k)


class StepInputs(NamedTuple):
    """The five inputs of one step for a batch, checked: (N, 4) and (N, 3) C-contiguous float64
    arrays of their own; each reference input has N rows or one row shared by the batch."""

    q_BN: Array
    omega_BN_B: Array
    q_RN: Array
    omega_RN_R: Array
    omegadot_RN_R: Array


def _as_vector(x: object, n: int) -> Array | None:
    """``x`` itself when the compiled step can take it as it is: an aligned, writable, C-contiguous
    float64 array of shape ``(n,)`` (anything else would be copied, or compiled anew by numba); else ``None``."""
    return x if type(x) is np.ndarray and x.shape == (n,) and x.dtype == _F64 and x.flags.carray else None


def _is_unit(q: list[float]) -> bool:
    """``| |q| - 1 | <= QUATERNION_NORM_TOL`` (norm summed as :func:`gnc_common.attitude.dot` does);
    false for a non-finite component too (NaN compares false, an infinite norm exceeds the tolerance)."""
    x, y, z, w = q
    return abs(math.sqrt(((x * x + y * y) + z * z) + w * w) - 1.0) <= QUATERNION_NORM_TOL


class AttitudeController:
    """One controller of a run or of a batch of runs: input checks, start, compiled law.

    Parameters
    ----------
    config : SappcConfig, TrappcConfig, BlfppcConfig or MrpFeedbackConfig
        The validated config; its type selects the law (:func:`.packing.kind_of`).
    on_infeasible : {"raise", "clamp"}
        SAPPC's policy for an infeasible RPF component (:class:`.rpf.ReferencePerformanceFunction`);
        the other laws have no RPF.

    Notes
    -----
    State: the packed parameters, per-run constants, filter and SMETF warm start are arrays
    (:mod:`.kernels`), created at the first step of a run (which fixes the time origin ``t0`` and
    the number of runs), forgotten by :meth:`reset`.
    """

    #: Gain fields :meth:`reconfigure` may change during a run (the filter's p, T3_s and
    #: V_floor are part of its state; the performance functions fix the run's envelope).
    #: MRP feedback's four gains may all change, as Basilisk's ``mrpFeedback`` reads them at each
    #: update (its ``int_sigma`` carries over).
    RUNTIME_GAINS = ("K_q", "K_omega", "K1", "K2", "K3", "D_m_Nm", "mu_rad_s", "q0_floor",
                     "K_Nm", "P_Nms", "Ki_per_kg_m2", "integralLimit_Nms")

    def __init__(self, config: Any, *, on_infeasible: str = "raise") -> None:
        from sappc_controller.core import kernels, packing  # see the module docstring

        self._K = kernels
        self._pack = packing
        self.config = config
        self.kind: int = packing.kind_of(config)
        self.on_infeasible = on_infeasible
        self.t0: float | None = None
        self.n_runs: int | None = None
        #: The RPF's ``flat`` and ``clamped`` components (N, 3) of the current run (all False for
        #: the laws without an RPF); ``None`` before the run starts.
        self.start_flags: dict[str, NDArray[np.bool_]] | None = None
        self._work = np.zeros((kernels.N_WORK, 4))
        self._prm = np.zeros((0, kernels.N_PARAMS))
        self._coef = np.zeros((0, kernels.N_COEF, 3))
        self._state = np.zeros((0, kernels.N_STATE))
        self._out = np.zeros((0, kernels.N_OUT, 4))
        self._sat = np.zeros((0, 3), dtype=bool)
        self._batch_output: ControlOutput | None = None
        self._single_output: ControlOutput | None = None
        self._torque_rows = self._out[:0, 0, :3]

    def reconfigure(self, config: Any) -> None:
        """Take new gains and actuator limits during a run, all or nothing, from the next step on.

        ``config`` is a validated config of this controller's kind; it may differ from the
        current one only in ``gains`` fields listed in :data:`RUNTIME_GAINS`, in ``actuator`` and in
        ``noise_filter`` (a cut-off takes effect at the next step; the filters' outputs carry over).

        Raises
        ------
        ConfigError
            Naming the first field that may not change during a run.
        """
        current = self.config
        if type(config) is not type(current):
            raise ConfigError(f"reconfigure needs a {type(current).__name__}, got {type(config).__name__}")
        for f in fields(current):
            if f.name in ("gains", "actuator", "noise_filter"):
                continue
            if getattr(config, f.name) != getattr(current, f.name):
                raise ConfigError(f"{f.name} cannot change during a run (it defines the performance envelope); restart the controller")
        for f in fields(current.gains):
            if f.name not in self.RUNTIME_GAINS and getattr(config.gains, f.name) != getattr(current.gains, f.name):
                raise ConfigError(f"gains.{f.name} cannot change during a run (it is part of the filter's state); restart the controller")
        prm = self._pack.pack_params(config, self.n_runs) if self.n_runs is not None else None  # may raise: nothing changed yet
        self.config = config
        if prm is not None:
            self._prm[...] = prm

    def reset(self) -> None:
        """Forget the run: the next step starts a new one (RPF, filter, time origin)."""
        self.t0 = None
        self.n_runs = None
        self.start_flags = None

    def step(
        self,
        t: float,
        dt: float,
        q_BN: ArrayLike,
        omega_BN_B: ArrayLike,
        q_RN: ArrayLike,
        omega_RN_R: ArrayLike,
        omegadot_RN_R: ArrayLike,
    ) -> ControlOutput:
        """Compute the torque for one sampling instant.

        Parameters
        ----------
        t : float
            Time [s]; the first call fixes the run's time origin.
        dt : float
            Sampling period [s] (> 0), used by the dynamic-surface filter.
        q_BN : array_like, (4,) or (N, 4)
            Measured attitude, unit quaternion, scalar last.
        omega_BN_B : array_like, (3,) or (N, 3)
            Measured body rate [rad/s].
        q_RN, omega_RN_R, omegadot_RN_R : array_like
            Desired attitude, rate [rad/s] and acceleration [rad/s^2] in the
            desired frame; shapes (4,)/(3,) are shared by the whole batch.

        Returns
        -------
        ControlOutput
            Without a batch axis when ``q_BN`` was a single quaternion.  Its arrays are views of
            the controller's output buffer, valid until the next step (copy what you keep).

        Raises
        ------
        InputError
            Naming the offending input (non-finite values, non-unit or zero
            quaternions, ``dt <= 0``, a batch size that changed, or a run that
            starts at the 180 deg singularity).
        FloatingPointError
            If the law produced a non-finite torque (never returned).
        """
        # Fast path: one run given as float64 vectors (the node's call), checked on Python floats;
        # anything else, or anything these checks refuse, takes the detailed checks below.
        q, w, q_d = _as_vector(q_BN, 4), _as_vector(omega_BN_B, 3), _as_vector(q_RN, 4)
        w_d, wdot_d = _as_vector(omega_RN_R, 3), _as_vector(omegadot_RN_R, 3)
        if q is not None and w is not None and q_d is not None and w_d is not None and wdot_d is not None and self.n_runs in (None, 1):
            try:
                t_f, dt_f = float(t), float(dt)
            except (TypeError, ValueError):
                t_f = dt_f = math.nan
            # the rates, t and dt are all finite iff their sum is (a NaN or an infinity propagates; an
            # overflow of finite values is a false alarm that the detailed checks accept); the
            # quaternions' norm check fails on a non-finite component
            rates = sum(w.tolist() + w_d.tolist() + wdot_d.tolist())
            if math.isfinite(rates + t_f + dt_f) and dt_f > 0.0 and _is_unit(q.tolist()) and _is_unit(q_d.tolist()):
                if self.n_runs is None:
                    self._start(t_f, q[None], q_d[None])
                self._K.controller_step_one(self.kind, t_f, dt_f, q, w, q_d, w_d, wdot_d, self._prm, self._coef, self._state,
                                            self._work, self._out, self._sat)
                torque = self._torque_rows.tolist()  # produced and commanded torque
                if not math.isfinite(sum(torque[0]) + sum(torque[1])):
                    raise FloatingPointError("controller produced a non-finite torque; refusing to output it")
                assert self._single_output is not None
                return self._single_output
        t_f, dt_f, inputs, single = self._checked_inputs(t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R)
        out = self._step_batch(t_f, dt_f, inputs)
        if single:
            assert self._single_output is not None
            return self._single_output  # out.first(), built once
        return out

    @staticmethod
    def _checked_inputs(
        t: float, dt: float, *arrays: ArrayLike
    ) -> tuple[float, float, StepInputs, bool]:
        """Every input checked (a batch, or one run the fast path did not take): ``t``, ``dt``, the
        inputs as C-contiguous (N, k) arrays, and whether ``q_BN`` was a single quaternion.

        Raises
        ------
        InputError
            Naming the offending value.
        """
        t_f = float(as_finite_array("t", t))
        dt_f = float(as_finite_array("dt", dt))
        if dt_f <= 0.0:
            raise InputError(f"dt must be > 0, got {dt!r}")
        q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R = arrays
        checked = (
            check_unit_quaternion("q_BN", q_BN),
            as_finite_array("omega_BN_B", omega_BN_B, shape_tail=(3,)),
            check_unit_quaternion("q_RN", q_RN),
            as_finite_array("omega_RN_R", omega_RN_R, shape_tail=(3,)),
            as_finite_array("omegadot_RN_R", omegadot_RN_R, shape_tail=(3,)),
        )
        single = checked[0].ndim == 1
        q2 = np.atleast_2d(checked[0])
        if q2.ndim != 2:
            raise InputError(f"q_BN must have shape (4,) or (N, 4), got {checked[0].shape}")
        n = q2.shape[0]
        rows: list[Array] = [q2]
        for name, a in zip(("omega_BN_B", "q_RN", "omega_RN_R", "omegadot_RN_R"), checked[1:]):
            a2 = np.atleast_2d(a)
            if a2.ndim != 2 or a2.shape[0] not in (1, n):
                raise InputError(f"{name} must have shape {a2.shape[-1:]} or ({n}, {a2.shape[-1]}) for a batch of {n} runs, got {a.shape}")
            rows.append(a2)
        if rows[1].shape[0] != n:  # the measured rate belongs to each run
            rows[1] = np.broadcast_to(rows[1], (n, 3))
        c = [np.array(a, dtype=np.float64, order="C") for a in rows]  # own, writable, C-contiguous
        return t_f, dt_f, StepInputs(c[0], c[1], c[2], c[3], c[4]), single

    def _step_batch(self, t: float, dt: float, inputs: StepInputs) -> ControlOutput:
        """:meth:`step` for a batch whose inputs are checked, with the batch axis in the result.

        A run starts here or in :meth:`step`'s fast path, both through :meth:`_start`, so that every
        caller refuses the same starts with the same error (:func:`.packing.start_coef`:
        :func:`check_start`, the funnels, the RPF).

        Raises
        ------
        InputError
            If the batch size changed, or at the first step of a run that starts at the 180 deg
            singularity (the controller then stays unstarted).
        FloatingPointError
            If the law produced a non-finite torque.
        """
        K = self._K
        q = inputs.q_BN
        n = q.shape[0]
        if self.n_runs is not None and n != self.n_runs:
            raise InputError(f"q_BN has {n} runs but this run started with {self.n_runs}; call reset() first")
        q, w, q_d, w_d, wdot_d = inputs
        if self.n_runs is None:
            self._start(t, q, q_d)
        K.controller_step_batch(self.kind, float(t), float(dt), q, w, q_d, w_d, wdot_d, self._prm, self._coef, self._state,
                                self._work, self._out, self._sat)
        if not np.isfinite(self._out[:, K.O_TORQUE : K.O_CMD + 1]).all():
            raise FloatingPointError("controller produced a non-finite torque; refusing to output it")
        assert self._batch_output is not None
        return self._batch_output

    def _start(self, t: float, q_BN: Array, q_RN: Array) -> None:
        """Start a run of ``q_BN.shape[0]`` runs at time ``t``: start checks and run constants
        (:func:`.packing.start_coef`), packed parameters, a fresh state and the output buffers."""
        K = self._K
        n = q_BN.shape[0]
        if q_RN.shape[0] == 1:
            q_BR0 = K.error_quaternions(q_RN[0], q_BN)
        else:
            q_BR0 = np.concatenate([K.error_quaternions(q_RN[k], q_BN[k : k + 1]) for k in range(n)])
        coef, flags = self._pack.start_coef(self.config, q_BR0, on_infeasible=self.on_infeasible)  # raises before anything changes
        self._prm = self._pack.pack_params(self.config, n)
        self._coef = np.ascontiguousarray(coef)
        self._state = K.new_state(n, t0=t)
        if self._out.shape[0] != n:
            self._out = np.zeros((n, K.N_OUT, 4))
            self._sat = np.zeros((n, 3), dtype=bool)
            o, s = self._out, self._sat
            self._batch_output = ControlOutput(
                torque_B=o[:, K.O_TORQUE, :3], torque_cmd_B=o[:, K.O_CMD, :3], saturated=s, q_BR=o[:, K.O_QBR],
                rho=o[:, K.O_RHO, :3], band_lower=o[:, K.O_BL, :3], band_upper=o[:, K.O_BU, :3], eps=o[:, K.O_EPS, :3],
                z=o[:, K.O_Z, :3], V=o[:, K.O_V, :3],
            )
            self._single_output = self._batch_output.first()
            self._torque_rows = o[0, K.O_TORQUE : K.O_CMD + 1, :3]
        self.start_flags = flags
        self.t0 = t
        self.n_runs = n

"""The momentum-management node (``python -m sappc_momentum``): the magnetorquers' dumping law and
the wheels' feed-forward on the graph (issue 36), flight software beside the estimator.

For each sample it takes, all of one stamp (lockstep: the plant owns time):

- the wheels' tachometers, ``state/wheel_speed`` (``sensor_msgs/JointState``, ``velocity``);
- the magnetometer, ``state/magnetic_field`` (``sensor_msgs/MagneticField``, B frame, tesla);
- the controller's attitude and rate inputs, ``state/attitude`` and ``state/rate`` (remapped to
  what the controller reads: ``estimate/*`` with an estimator, a fault relay's output with sensor
  faults); a "no data" sample (NaN) keeps the previous one, as a dropped input leaves the
  controller's (the attitude is the predictive law's: the wheels' momentum turned into N; before
  the first, the law is the cross-product law);
- the controller's torque, ``control/torque`` (a fault relay's output with actuator faults);

and publishes, with that stamp, the rods' dipole commands on ``control/dipole`` and the wheels'
body torque on ``control/wheel_torque``, which the plant takes as its torque command.  The law is
:func:`sappc_momentum.core.law.momentum_management_step`, the compiled kernel the offline loop
calls on the same inputs in the same order, at the sample's stamp in seconds, so a lockstep bag
equals the offline run bit for bit.  The predictive law (``law: predictive``) plans with the
onboard orbit and field models of ``orbit_params`` and ``field_params`` (``sappc run`` passes the
scenario's).

Parameters: :data:`PARAMETERS` (``python -m sappc_momentum --help``).  The wheels and the rods
are given as the flight software's configuration tables: the axes, and the allocation and
steering matrices themselves (``sappc run`` computes them with the functions the offline loop
uses, and passes them exactly), so that the node needs no simulator.  A missing or invalid
parameter stops the node with one line naming it (exit status 2); a message with a wrong frame,
a wrong count or a non-finite field, speed or torque is rejected, logged and counted (the
plant then holds its last command when its own wait runs out).  Real time is not supported yet
(the node refuses ``mode: realtime``; a managed node's configure transition fails instead).

Managed (``managed:=true``; default false: the plain node above): a ROS 2 managed (lifecycle) node,
as :class:`~sappc_msgs_py.runtime.ManagedNode` says for every node; for this one:

- configure (:meth:`MomentumNode.configure_node`, the plain node's start-up): the parameters
  declared and validated (the tables, the law's settings, the onboard models), the compiled
  kernels loaded, the inputs subscribed, ``control/dipole`` and ``control/wheel_torque`` offered.
- inactive (after configure, or deactivate): no management and no B-dot (neither law's state is
  stepped), but every sample is still answered, when it is complete, with its stamp, so a plant in
  lockstep never waits: the rods commanded zero on ``control/dipole`` and the wheels given the
  controller's own torque, unchanged, on ``control/wheel_torque`` (what the plant would apply with
  no management node).  Inputs are still checked and counted, and the last delivered attitude and
  rate still kept (they are the inputs' hold, not the law's state).  Counted apart:
  ``inactive_samples`` in the closing line and ``timing_file``.
- activate: the law afresh from the next sample: a fresh predictive state (no plan, no disturbance
  estimate: it plans at once) and a fresh B-dot state (no previous field sample), as a new
  configure would build them, whether or not the law had stepped before.
- cleanup: a new configure builds a new law (and new counts) from the same parameters.
"""

from __future__ import annotations

import math
import sys
from functools import partial
from typing import Any

import numpy as np

from gnc_common.validation import ConfigError, InputError, as_finite_array
from sappc_momentum.core.law import LAWS, N_MM_WORK, MomentumManagement, momentum_management_step, pack_momentum
from sappc_momentum.core.law import MomentumArrays, dipole_mapping
from sappc_momentum.core.predictive import new_state
from sappc_modes.core.bdot import bdot_step, new_bdot_state, pack_bdot, reset_bdot_state
from sappc_modes.core.modes import DETUMBLE, R_NONE, TRACK
from sappc_msgs_py.contract import (CONTROL_DIPOLE, CONTROL_TORQUE, CONTROL_WHEEL_TORQUE, MODE_STATUS, STATE_ATTITUDE, STATE_MAGNETIC_FIELD, STATE_RATE,
                                    STATE_WHEEL_SPEED, Topic, qos_profile)
from sappc_msgs_py.inputs import NS_PER_S  # the kernel's time: the stamp in seconds, ns / NS_PER_S (the offline loop's)
from sappc_msgs_py import wire
from sappc_msgs_py.convert import cdr_stamp_ns, magnetic_field_from_msg, time_to_ns, torque_from_msg, wheel_speed_from_msg
from sappc_msgs_py.parameters import REQUIRED, Param
from sappc_msgs_py.runtime import LOCKSTEP, MANAGED, MODE, ManagedNode, run_node, write_json_whole

__all__ = ["INPUTS", "MomentumNode", "PARAMETERS", "RIGHT_INVERSE_TOL", "main"]

#: How far ``G A`` may be from the identity for an allocation (or steering) matrix ``A`` of axes
#: ``G`` [-]: a minimum-norm inverse computed in double precision is within 1e-15 of a right
#: inverse; 1e-9 catches a table of other axes or a transposed one, not rounding.
RIGHT_INVERSE_TOL = 1e-9

#: The node's inputs of one sample.
INPUTS = (STATE_WHEEL_SPEED, STATE_MAGNETIC_FIELD, STATE_ATTITUDE, STATE_RATE, CONTROL_TORQUE)
_DEFAULTS = MomentumManagement(gain_per_s=1.0)
#: The rods' steering matrix and limits among the law's arrays (B-dot's dipole mapping, flight modes).
_STEERING, _M_MAX = MomentumArrays._fields.index("steering"), MomentumArrays._fields.index("m_max")

PARAMETERS = (
    MODE,
    MANAGED,
    Param("gain_per_s", REQUIRED, "K_p: the rate at which the wheels' excess momentum is dumped (normal to the field)", "1/s", check="> 0",
          type="double"),
    Param("target_momentum_B_Nms", [0.0, 0.0, 0.0], "h*_B: the wheels' momentum to hold, in B", "N m s", check="3 finite values"),
    Param("gyroscopic_feedforward", False, "add omega x (G_s h_s) to the wheels' torque and scale the rods down when the motors cannot "
          "carry it all (attitude first; docs/how-to/momentum.md)"),
    Param("wheel_axes_B", REQUIRED, "G_s: the wheels' spin axes in B, (3, W) row major", check="3 W finite values", type="double[]"),
    Param("wheel_spin_inertia_kg_m2", REQUIRED, "J_s: each wheel's spin inertia", "kg m^2", check="W values > 0", type="double[]"),
    Param("wheel_max_torque_Nm", REQUIRED, "each wheel's motor torque limit", "N m", check="W values > 0", type="double[]"),
    Param("wheel_allocation", REQUIRED, "G_s^+: the wheels' minimum-norm allocation (W, 3) row major, the plant's own",
          check="a right inverse of wheel_axes_B", type="double[]"),
    Param("rod_axes_B", REQUIRED, "G_t: the rods' axes in B, (3, M) row major", check="3 M finite values", type="double[]"),
    Param("rod_steering", REQUIRED, "the rods' steering matrix (M, 3) row major (Basilisk dipoleMapping's; pinv(G_t))",
          check="a right inverse of rod_axes_B", type="double[]"),
    Param("rod_max_dipole_Am2", REQUIRED, "each rod's dipole limit", "A m^2", check="M values > 0", type="double[]"),
    Param("law", _DEFAULTS.law, "the request: Basilisk's cross-product law, or the LQR along the predicted field "
          "(sappc_momentum.core.predictive)", choices=tuple(LAWS)),
    Param("horizon_s", _DEFAULTS.horizon_s, "the predictive law's horizon", "s", check="> 0"),
    Param("replan_s", _DEFAULTS.replan_s, "how often the predictive law plans again", "s", check="> 0, <= horizon_s"),
    Param("plan_step_s", _DEFAULTS.plan_step_s, "the predictive law's RK4 step", "s", check="> 0, <= replan_s"),
    Param("disturbance_time_constant_s", _DEFAULTS.disturbance_time_constant_s,
          "the predictive law's low pass on the controller's torque (the disturbance's estimate)", "s", check="> 0"),
    Param("orbit_params", [], "the predictive law's onboard orbit: a, e, i, node, argument of periapsis, M_0, n, mu, theta_0, "
          "omega_E (spacecraft_sim.core.orbit.Orbit.params; [] with the cross-product law)", check="10 finite values", type="double[]"),
    Param("field_params", [], "the predictive law's onboard dipole field: g11, h11, g10 [T], R [m] "
          "(spacecraft_sim.core.magnetic_field.DipoleField.params; [] with the cross-product law)", check="4 finite values", type="double[]"),
    Param("timing_file", "", "where to write the node's counts at the end (JSON: samples, rejected messages); '' for none"),
    Param("flight_modes", False, "take each sample's mode (mode/status): in DETUMBLE B-dot on the rods and nothing on the wheels "
          "instead of the management law (docs/design/modes.md)"),
    Param("bdot_gain_N_m_s", 0.0, "flight modes: B-dot's gain k (the scenario's modes.detumble_gain_N_m_s)", "N m s", check="> 0 with flight_modes"),
    Param("magnetometer_stride", 1, "flight modes: the loop's samples per magnetometer update (B-dot differentiates new samples only; "
          "1: every sample)", check=">= 1"),
    Param("control_period_s", 0.01, "flight modes: the loop's sample period (a magnetometer update's time is its sample's k dt)", "s",
          check="> 0"),
)
_P = {p.name: p for p in PARAMETERS}


def _matrix(name: str, values: Any, rows: int | None, cols: int | None) -> np.ndarray:
    """``values`` (a flat list) as a (rows, cols) matrix, one of them given; errors name the parameter and value."""
    a = as_finite_array(name, values)
    if a.ndim != 1 or a.size == 0:
        raise ConfigError(f"{name} must be a non-empty list of numbers, got {values!r}")
    if rows is not None:
        if a.size % rows:
            raise ConfigError(f"{name} must hold {rows} rows (a multiple of {rows} values), got {a.size} values")
        return np.ascontiguousarray(a.reshape(rows, a.size // rows))
    assert cols is not None
    if a.size % cols:
        raise ConfigError(f"{name} must hold rows of {cols} values (a multiple of {cols}), got {a.size} values")
    return np.ascontiguousarray(a.reshape(a.size // cols, cols))


def _positive(name: str, values: Any, n: int) -> np.ndarray:
    a = as_finite_array(name, values)
    if a.shape != (n,) or not np.all(a > 0):
        raise ConfigError(f"{name} must be {n} values > 0 (one per axis of the table), got {list(values)!r}")
    return a


def _right_inverse(name: str, A: np.ndarray, axes_name: str, G: np.ndarray) -> None:
    if A.shape != (G.shape[1], 3) or np.abs(G @ A - np.eye(3)).max() > RIGHT_INVERSE_TOL:
        raise ConfigError(f"{name} must be a right inverse of {axes_name} ({G.shape[1]} x 3 with {axes_name} @ {name} = I to "
                          f"{RIGHT_INVERSE_TOL}), got {A.tolist()!r}")


class MomentumNode(ManagedNode):
    """See the module docstring (its section "Managed" for the lifecycle)."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m sappc_momentum"

    def __init__(self, node_name: str = "momentum", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)  # not managed: configured (configure_node) and active; managed: unconfigured

    def configure_node(self) -> None:
        """The parameters declared and validated into the law's arrays, the compiled kernel loaded,
        the inputs subscribed and the outputs offered (:class:`~sappc_msgs_py.runtime.ManagedNode`:
        while the node is built, or at a managed node's configure transition).  Raises
        ``ConfigError`` naming a bad parameter."""
        self.mode = self.mode_param()
        if self.mode != LOCKSTEP:
            raise ConfigError(f"mode: the momentum-management node runs in lockstep only (real time: not yet), got {self.mode!r}")
        gain = self.param(_P["gain_per_s"])
        if gain is None:
            raise ConfigError("gain_per_s is required (K_p [1/s] > 0)")
        config = MomentumManagement(gain_per_s=float(gain), target_momentum_B_Nms=tuple(self.param(_P["target_momentum_B_Nms"])),
                                    gyroscopic_feedforward=bool(self.param(_P["gyroscopic_feedforward"])), law=str(self.param(_P["law"])),
                                    horizon_s=float(self.param(_P["horizon_s"])), replan_s=float(self.param(_P["replan_s"])),
                                    plan_step_s=float(self.param(_P["plan_step_s"])),
                                    disturbance_time_constant_s=float(self.param(_P["disturbance_time_constant_s"])))
        orbit = field = None
        if config.law == "predictive":
            orbit = as_finite_array("orbit_params", self.param(_P["orbit_params"]))
            field = as_finite_array("field_params", self.param(_P["field_params"]))
            if orbit.shape != (10,) or field.shape != (4,):
                raise ConfigError(f"the predictive law needs orbit_params (10 values) and field_params (4 values), got "
                                  f"{orbit.tolist()!r} and {field.tolist()!r}")
        tables = {}
        for p in ("wheel_axes_B", "wheel_spin_inertia_kg_m2", "wheel_max_torque_Nm", "wheel_allocation", "rod_axes_B", "rod_steering",
                  "rod_max_dipole_Am2"):
            value = self.param(_P[p])
            if value is None:
                raise ConfigError(f"{p} is required ({_P[p].description})")
            tables[p] = value
        self.timing_file = str(self.param(_P["timing_file"]))
        self.flight_modes = bool(self.param(_P["flight_modes"]))
        gain = float(self.param(_P["bdot_gain_N_m_s"]))
        self._bdot_prm = pack_bdot(gain) if self.flight_modes else None  # raises ConfigError naming a bad gain
        self._mag_stride = int(self.param(_P["magnetometer_stride"]))
        if self._mag_stride < 1:
            raise ConfigError(f"magnetometer_stride must be >= 1, got {self._mag_stride}")
        self.dt = float(self.param(_P["control_period_s"]))
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ConfigError(f"control_period_s must be > 0, got {self.dt!r}")
        self.dt_ns = time_to_ns(self.dt)
        self._bdot_state = new_bdot_state()
        self._m_B = np.zeros(3)
        self.check_unknown_overrides()
        Gs = _matrix("wheel_axes_B", tables["wheel_axes_B"], 3, None)
        Gt = _matrix("rod_axes_B", tables["rod_axes_B"], 3, None)
        W, M = Gs.shape[1], Gt.shape[1]
        Js = _positive("wheel_spin_inertia_kg_m2", tables["wheel_spin_inertia_kg_m2"], W)
        u_max = _positive("wheel_max_torque_Nm", tables["wheel_max_torque_Nm"], W)
        m_max = _positive("rod_max_dipole_Am2", tables["rod_max_dipole_Am2"], M)
        Gs_pinv = _matrix("wheel_allocation", tables["wheel_allocation"], None, 3)
        steering = _matrix("rod_steering", tables["rod_steering"], None, 3)
        _right_inverse("wheel_allocation", Gs_pinv, "wheel_axes_B", Gs)
        _right_inverse("rod_steering", steering, "rod_axes_B", Gt)
        # the offline loop's arrays (pack_momentum), run 0
        self._mm = [a[0] for a in pack_momentum(config, 1, Gs, Js, Gs_pinv, u_max, Gt, steering, m_max, orbit, field)]
        self.n_wheels, self.n_rods = W, M
        self._m = np.zeros(M)
        self._tau_w = np.zeros(3)
        self._tmp = np.zeros((N_MM_WORK, 3))
        self._omega = np.zeros(3)  # the last delivered finite rate (the offline loop's omega_ff)
        self._q = np.full(4, np.nan)  # the last delivered finite attitude (the offline loop's q_ff)
        self._state = new_state()
        self._step(0.0, np.zeros(W), np.zeros(3), np.zeros(3))  # load the compiled kernel now, not at the first sample
        self._state = new_state()
        if self.flight_modes:  # B-dot's kernels too (a direct dispatch each: a cache load at DETUMBLE's first sample otherwise), then afresh
            bdot_step(self._bdot_prm, np.array([1e-5, 0.0, 0.0]), 0.0, self._bdot_state, np.zeros(3))
            dipole_mapping(self._mm[_STEERING], np.zeros(3), self._mm[_M_MAX], np.zeros(M))
            self._bdot_state = new_bdot_state()
        self.pub_dipole = self.counting_publisher(CONTROL_DIPOLE, 1)
        self.pub_torque = self.counting_publisher(CONTROL_WHEEL_TORQUE, 1)
        self._pending: dict[int, dict[str, Any]] = {}
        self.samples = 0
        self.inactive_samples = 0  # samples answered inactive (managed: module docstring, "Managed")
        self.rejected = 0
        qos = qos_profile()
        # every topic as CDR bytes (sappc_msgs_py.wire): the inputs' layouts (the field's covariance, whatever the
        # magnetometer's, read as values), what each picks, and the object decoder of any other message
        field_layout = wire.stamped(STATE_MAGNETIC_FIELD, "field_and_covariance", 12)
        self._takes: dict[str, tuple[wire.Codec, Any, Any]] = {
            STATE_WHEEL_SPEED.name: (wire.Codec(wire.joint_state(STATE_WHEEL_SPEED, W, "speed", None), STATE_WHEEL_SPEED.name), wire.PICK_ALL,
                                     lambda msg: wheel_speed_from_msg(msg, W)),
            STATE_MAGNETIC_FIELD.name: (wire.Codec(field_layout, STATE_MAGNETIC_FIELD.name), _field,
                                        lambda msg: magnetic_field_from_msg(msg, STATE_MAGNETIC_FIELD)),
            CONTROL_TORQUE.name: (wire.codec(CONTROL_TORQUE), wire.PICK_ALL, lambda msg: torque_from_msg(msg, CONTROL_TORQUE)),
            STATE_ATTITUDE.name: (wire.codec(STATE_ATTITUDE), wire.PICK_ALL, partial(_state_or_no_data, topic=STATE_ATTITUDE)),
            STATE_RATE.name: (wire.codec(STATE_RATE), wire.PICK_ALL, partial(_state_or_no_data, topic=STATE_RATE)),
        }
        self._wire_dipole = wire.Codec(wire.dipole(M), CONTROL_DIPOLE.name, finite=False)  # as dipole_msg: taken as computed (the plant checks)
        self._wire_torque = wire.codec(CONTROL_WHEEL_TORQUE)
        self._inputs = INPUTS + ((MODE_STATUS,) if self.flight_modes else ())
        self._wire_mode = wire.codec(MODE_STATUS)
        for topic in self._inputs:
            self.create_subscription(topic.msg_class, topic.name, partial(self._on_input, topic=topic), qos, raw=True)
        self.get_logger().info(f"momentum management ready (lockstep; {config.law} law, K_p {config.gain_per_s:g} 1/s, {W} wheels, {M} rods, "
                               f"gyroscopic feed-forward {'on' if config.gyroscopic_feedforward else 'off'})")

    def _step(self, t_s: float, speeds: np.ndarray, field_T: np.ndarray, torque_B: np.ndarray) -> None:
        momentum_management_step(*self._mm, t_s, speeds, field_T, self._q, self._omega, torque_B, self._m, self._tau_w,
                                 self._tmp, self._state)

    def _decode(self, raw: bytes, topic: Topic) -> Any:
        """The value of one input received as CDR bytes (``None`` for a state that is "no data");
        :class:`InputError` for a bad message (:func:`sappc_msgs_py.wire.take`)."""
        fast, pick, decoder = self._takes[topic.name]
        return wire.take(raw, topic, decoder, fast, pick)

    def _on_input(self, raw: bytes, topic: Topic) -> None:
        if topic is MODE_STATUS:  # the mode node's (flight modes): its time in data[0] (exact in lockstep)
            values = self._wire_mode.values(raw)
            if values is None:
                self.rejected += 1
                self.get_logger().warning(f"rejected a {topic.name} message of another layout ({self.rejected} so far)")
                return
            ns, value = time_to_ns(values[0]), (int(values[1]), int(values[2]))
        else:
            try:
                value = self._decode(raw, topic)
            except InputError as exc:
                self.rejected += 1
                self.get_logger().warning(f"rejected a message ({self.rejected} so far): {exc}")
                return
            ns = cdr_stamp_ns(topic.type_name, raw)
        sample = self._pending.setdefault(ns, {})
        sample[topic.name] = value
        if len(sample) < len(self._inputs):
            return
        del self._pending[ns]
        for old in [k for k in self._pending if k < ns]:  # an earlier sample that never completed (the plant held its command)
            del self._pending[old]
        rate, attitude = sample[STATE_RATE.name], sample[STATE_ATTITUDE.name]
        if rate is not None:
            self._omega[:] = rate
        if attitude is not None:
            self._q[:] = attitude
        if not self.active:  # managed, inactive: the rods at zero, the controller's torque to the wheels, no law stepped ("Managed")
            self.pub_dipole.publish(self._wire_dipole.encode(None, [ns / NS_PER_S, *([0.0] * self.n_rods)]))
            self.pub_torque.publish(self._wire_torque.encode(ns, sample[CONTROL_TORQUE.name]))
            self.samples += 1
            self.inactive_samples += 1
            return
        mode, reason = sample[MODE_STATUS.name] if self.flight_modes else (TRACK, R_NONE)
        if mode == DETUMBLE:  # B-dot on the rods, on each new magnetometer sample (its update's time), nothing on the wheels
            if reason != R_NONE:
                reset_bdot_state(self._bdot_state)
            k = ns // self.dt_ns
            bdot_step(self._bdot_prm, sample[STATE_MAGNETIC_FIELD.name], float(k - k % self._mag_stride) * self.dt, self._bdot_state, self._m_B)
            dipole_mapping(self._mm[_STEERING], self._m_B, self._mm[_M_MAX], self._m)
            self._tau_w[:] = 0.0
        else:
            self._step(ns / NS_PER_S, sample[STATE_WHEEL_SPEED.name], sample[STATE_MAGNETIC_FIELD.name], sample[CONTROL_TORQUE.name])
        self.pub_dipole.publish(self._wire_dipole.encode(None, [ns / NS_PER_S, *self._m.tolist()]))  # data[0]: the time [s]
        self.pub_torque.publish(self._wire_torque.encode(ns, self._tau_w))
        self.samples += 1

    # ---- lifecycle --------------------------------------------------------------------------
    def on_activate(self, state: Any) -> Any:
        """An activation: the law afresh from the next sample (module docstring, "Managed"): a fresh
        predictive state and a fresh B-dot state (what configure built, unchanged at a first
        activation); then active."""
        self._state = new_state()
        reset_bdot_state(self._bdot_state)
        return super().on_activate(state)

    # ---- the end --------------------------------------------------------------------------
    def finish(self) -> None:
        if self.finished_unconfigured():
            return
        inactive = f" ({self.inactive_samples} inactive)" if self.managed else ""
        self.get_logger().info(f"finished: {self.samples} samples{inactive}, {self.rejected} rejected messages")
        super().finish()
        if self.timing_file:
            counts = {"samples": self.samples, "rejected": self.rejected, **({"inactive_samples": self.inactive_samples} if self.managed else {})}
            write_json_whole(self.timing_file, counts)  # whole or not at all (sappc run reads it)


def _field(values: tuple[float, ...]) -> np.ndarray | None:
    """:func:`~sappc_msgs_py.wire.take`'s pick of a ``MagneticField`` (its field, then its
    covariance): the field [T] when finite (what :func:`~sappc_msgs_py.convert.magnetic_field_from_msg` gives)."""
    return np.array(values[:3]) if all(map(math.isfinite, values[:3])) else None


def _state_or_no_data(msg: Any, topic: Topic) -> np.ndarray | None:
    """An attitude or rate message: its values, or ``None`` for "no data" (non-finite: the previous
    value is kept); :class:`InputError` for a wrong frame id."""
    if msg.header.frame_id != topic.frame_id:
        raise InputError(f"{topic.name}: frame_id must be {topic.frame_id!r}, got {msg.header.frame_id!r}")
    if topic is STATE_ATTITUDE:
        q = msg.quaternion
        values = [q.x, q.y, q.z, q.w]
    else:
        v = msg.vector
        values = [v.x, v.y, v.z]
    return np.array(values) if all(map(math.isfinite, values)) else None


def main(argv: list[str] | None = None) -> int:
    """Run the momentum-management node until stopped."""
    return run_node(lambda args: MomentumNode(), argv, MomentumNode)


if __name__ == "__main__":
    sys.exit(main())

"""An offline run's full-rate record as a bag (``sappc simulate --record DIR``): the graph's topics,
types and stamps, written block by block as the run goes.

:class:`OfflineBagWriter` is a sink of :func:`sappc.offline.simulate.run_scenario` (``sinks``):
called with every block of a one-run :class:`~sappc.evaluation.history.History`, in order, it
encodes the block's messages and writes them to a rosbag2 version 9 directory laid out as the
graph's recorder lays it out (:mod:`sappc.graph.recorder`): ``<name>_0.mcap`` (profile ``ros2``,
``ros2msg`` schemas with their dependencies, CDR, channels carrying ``offered_qos_profiles`` and
``topic_type_hash``), ``metadata.yaml``, and the run's ``scenario.yaml`` and ``params.yaml`` (the
controller node's parameters, as ``sappc run`` gives them), also stored as the metadata records
``sappc/scenario.yaml`` and ``sappc/params.yaml``.  :meth:`~OfflineBagWriter.close` finishes the
file (summary, indexes) and ``metadata.yaml``.  ``sappc report``, ``compare``, ``rerun``,
:func:`~sappc.bag.read.bag_run` and Foxglove then read an offline run as they read a lockstep
graph run.

Memory is set by the block, not by the run: nothing of a block is kept once it is written but
the last partial chunk (under :data:`CHUNK_SIZE_BYTES`).

The file is what the lockstep recorder writes once it has sorted its bag
(:func:`~sappc.bag.rosbag2.sort_by_log_time`): every message's log and publish time is its stamp,
the messages in (stamp, channel, sequence) order, each topic's sequence counting its messages
from 1, zstd chunks of :data:`CHUNK_SIZE_BYTES`.  The chunks break at whole samples, after as
many samples as fit (not at the History's blocks), so a run written in any blocks is the same
file, byte for byte.

Stamps: sample ``k``'s stamp is the plant's, ``seconds_to_ns(k dt)``
(:func:`~sappc_msgs_py.convert.seconds_to_ns`, computed here for a whole block at once by
:func:`~sappc_msgs_py.convert.seconds_to_ns_array`: the same integers); the float arrays' ``data[0]`` is
``stamp / 1e9``, as the nodes compute it.

Topics, and what each holds (the names are resolved in the root namespace, ``/state/attitude``):

``/clock``, ``state/tf``, ``reference/tf``
    The plant's clock; the body (the true ``q_BN``, as the plant publishes it) and the reference
    in ``inertial``.
``state/attitude``, ``state/rate``
    The true state, without sensor models (the plant's measurements are then exact).
``truth/attitude``, ``truth/rate``
    With sensor models: the true state (``state/*`` are then measurements, which the record
    does not hold).
``truth/gyro_bias``
    With sensor models and an estimator: the gyro's true bias (the estimator's record holds it).
``reference/attitude``, ``reference/rate``, ``reference/acceleration``
    The scenario's reference at the sample times (:meth:`spacecraft_sim.core.reference.PaperReference.sample`,
    carried from block to block: the loop's and the reference node's values, bit for bit).
``control/torque``
    The torque the controller answered (the delivered torque: without an actuator fault they
    are one); with an actuator fault the delivered torque goes on ``fault/control/torque``, the
    relay's output, and ``control/torque`` is not written (the record does not hold the answer
    before the fault).
``disturbance/torque``
    The injected disturbance (the orbit's environmental torque is not published, as on the graph).
``controller/diagnostics``
    The rows of :data:`~sappc_msgs_py.contract.DIAGNOSTICS_LAYOUT` as the node publishes them:
    ``rho``, the band, ``eps``, ``z``, ``V``, the command and the saturation flags from the
    record; the answer's code and stale flag, and the input stamps (the sample's own for a
    computed answer, zero otherwise) from the History's ``answer`` (``(T, N)`` int8, the
    contract's ``ANSWER_*`` codes), NaN when the History has none; the count of rejected input
    messages NaN (the record holds the run's count, not one per sample).
``joint_states``, ``state/wheel_speed``
    The wheels' speeds and motor torques; the tachometers (momentum management only).
``estimate/*``, ``estimator/*`` (but the health on ``diagnostics``)
    The estimator's record: estimate, bias, the 1-sigmas (``sqrt`` of ``P``'s diagonal, as the
    filter computes them), covariance; its diagnostics with ``nis``, ``status``, the monitor's
    level and NIS sum, the recoveries, and the counts of "no data" and withheld samples (counted
    from the record); ``updates``, ``gate_rejections``, ``reinitialisations`` and
    ``rejected_messages`` NaN (the filter's counters are not in the record).  NaN where the
    filter gave no estimate, as the node's "no data".
``state/magnetic_field``, ``truth/magnetic_field``, ``control/dipole``
    In orbit: the flight software's field with the magnetometer's variance (zero without one),
    the true field (with a magnetometer), the rods' commands (momentum management only).
``mode/status``
    With flight modes: each sample's mode and the reason of the transition taken at it (the
    History's ``mode`` and ``mode_reason``), ``data[0]`` the sample's time, as the mode node
    publishes them (:data:`~sappc_msgs_py.contract.MODE_STATUS_LAYOUT`); a scenario without
    modes has no such channel.

Not written, because the record does not hold them: the sensors' own topics
(``sensors/gyro``, ``sensors/star_tracker``, ``state/attitude_epoch``) and, with sensor models,
the measurements on ``state/*``; the estimator's health (``diagnostics``); the management
node's ``control/wheel_torque``; the fault relays' outputs but ``fault/control/torque``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import yaml
from numpy.typing import NDArray

from sappc.bag.errors import BagError
from sappc.bag.mcap_write import MESSAGE_HEAD_BYTES, ZSTD_LEVEL, McapWriter, message_head
from sappc.bag.rosbag2 import bag_metadata, offered_qos_v9, write_bag_metadata
from sappc.evaluation.history import History
from sappc.scenario import ControllerKind, Scenario, controller_node_parameters
from sappc_msgs_py.contract import (
    ANSWER_COMMANDED,
    CLOCK,
    CONTROL_DIPOLE,
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    DISTURBANCE_TORQUE,
    ESTIMATE_ATTITUDE,
    ESTIMATE_RATE,
    ESTIMATOR_ATTITUDE_SIGMA,
    ESTIMATOR_BIAS_SIGMA,
    ESTIMATOR_COVARIANCE,
    ESTIMATOR_DIAGNOSTICS,
    ESTIMATOR_GYRO_BIAS,
    FAULT_TOPICS,
    MODE_STATUS,
    REFERENCE_ACCELERATION,
    REFERENCE_ATTITUDE,
    REFERENCE_RATE,
    REFERENCE_TF,
    STATE_ATTITUDE,
    STATE_MAGNETIC_FIELD,
    STATE_RATE,
    STATE_TF,
    STATE_WHEEL_SPEED,
    TOPICS,
    TRUTH_ATTITUDE,
    TRUTH_GYRO_BIAS,
    TRUTH_MAGNETIC_FIELD,
    TRUTH_RATE,
    WHEEL_STATES,
    Topic,
    faulty,
)
from sappc_msgs_py import wire
from sappc_msgs_py.convert import seconds_to_ns_array
from sappc_msgs_py.schemas import schema_text, type_hash
from spacecraft_sim.core.faults import FaultSchedule

__all__ = ["CHUNK_SIZE_BYTES", "ENCODE_BYTES", "LIBRARY", "UNRECORDED_TOPICS", "ZSTD_LEVEL", "OfflineBagWriter", "controller_parameters",
           "offline_topics"]

#: MCAP chunk size [bytes] (uncompressed): the graph recorder's (:data:`sappc.graph.recorder.CHUNK_SIZE`,
#: about 1.5 s of a 100 Hz run), so that an offline bag and a graph bag are read in the same
#: pieces (a reader decompresses a chunk at once; :mod:`sappc.bag.blocks` reads by chunk).
CHUNK_SIZE_BYTES = 256 * 1024
#: Samples' messages encoded at once [bytes]: a block's encoding holds this much beside the
#: block (the messages of a block of the orbit scenario, 2**16 samples of 3460 bytes, are 227 MB), while the numpy
#: calls per piece (a few per field, some 150 fields for the orbit scenario) stay a few percent
#: of its encoding.
ENCODE_BYTES = 4 * 1024 * 1024
#: The ``library`` field of the bags written here.
LIBRARY = "sappc simulate --record (sappc.bag.write_offline)"

#: Topics of a graph run that an offline bag never has (its record does not hold them; module docstring).
UNRECORDED_TOPICS = ("sensors/gyro", "sensors/star_tracker", "state/attitude_epoch", "diagnostics", "control/wheel_torque")

_NS_PER_S = 1_000_000_000

Array = NDArray[np.float64]


# ---- which topics ---------------------------------------------------------------------------
def offline_topics(scenario: Scenario) -> tuple[Topic, ...]:
    """The topics an offline bag of ``scenario`` holds, in the order the graph's recorder registers
    them (the contract's, then the fault relays'): those of a lockstep graph run of it whose
    content the offline record holds (module docstring)."""
    sensors = scenario.sensors is not None
    estimating = scenario.estimator is not None
    env = scenario.environment
    managing = scenario.momentum is not None
    actuator_fault = FaultSchedule(scenario.faults).acts_on("actuator")
    wanted = {CLOCK, STATE_TF, REFERENCE_TF, REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION, DISTURBANCE_TORQUE,
              CONTROLLER_DIAGNOSTICS}
    wanted |= {TRUTH_ATTITUDE, TRUTH_RATE} if sensors else {STATE_ATTITUDE, STATE_RATE}
    wanted |= {faulty(CONTROL_TORQUE)} if actuator_fault else {CONTROL_TORQUE}
    if sensors and estimating:
        wanted.add(TRUTH_GYRO_BIAS)
    if estimating:
        wanted |= {ESTIMATE_ATTITUDE, ESTIMATE_RATE, ESTIMATOR_GYRO_BIAS, ESTIMATOR_ATTITUDE_SIGMA, ESTIMATOR_BIAS_SIGMA,
                   ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS}
    if scenario.wheels is not None:
        wanted.add(WHEEL_STATES)
    if env is not None:
        wanted.add(STATE_MAGNETIC_FIELD)
        if env.magnetometer is not None:
            wanted.add(TRUTH_MAGNETIC_FIELD)
    if managing:
        wanted |= {STATE_WHEEL_SPEED, CONTROL_DIPOLE}
    if scenario.modes is not None:
        wanted.add(MODE_STATUS)
    return tuple(t for t in TOPICS + FAULT_TOPICS if t in wanted)


def _payload(topic: Topic, scenario: Scenario) -> wire.Layout:
    """The layout of ``topic``'s messages for ``scenario`` (its keys those of :func:`_block_values`)."""
    n_wheels = 0 if scenario.wheels is None else scenario.wheels.n
    layouts: dict[Topic, Callable[[], wire.Layout]] = {
        CLOCK: wire.clock,
        STATE_ATTITUDE: lambda: wire.stamped(STATE_ATTITUDE, "q_BN", 4),
        STATE_RATE: lambda: wire.stamped(STATE_RATE, "omega_BN_B", 3),
        TRUTH_ATTITUDE: lambda: wire.stamped(TRUTH_ATTITUDE, "q_BN", 4),
        TRUTH_RATE: lambda: wire.stamped(TRUTH_RATE, "omega_BN_B", 3),
        TRUTH_GYRO_BIAS: lambda: wire.stamped(TRUTH_GYRO_BIAS, "gyro_bias_true", 3),
        STATE_TF: lambda: wire.transform(STATE_TF, "q_BN"),
        REFERENCE_TF: lambda: wire.transform(REFERENCE_TF, "q_RN"),
        REFERENCE_ATTITUDE: lambda: wire.stamped(REFERENCE_ATTITUDE, "q_RN", 4),
        REFERENCE_RATE: lambda: wire.stamped(REFERENCE_RATE, "omega_RN_R", 3),
        REFERENCE_ACCELERATION: lambda: wire.stamped(REFERENCE_ACCELERATION, "omegadot_RN_R", 3),
        CONTROL_TORQUE: lambda: wire.stamped(CONTROL_TORQUE, "torque_B", 3, before=3),
        faulty(CONTROL_TORQUE): lambda: wire.stamped(faulty(CONTROL_TORQUE), "torque_B", 3, before=3),
        DISTURBANCE_TORQUE: lambda: wire.stamped(DISTURBANCE_TORQUE, "disturbance_B", 3, before=3),
        CONTROLLER_DIAGNOSTICS: wire.controller_diagnostics,
        WHEEL_STATES: lambda: wire.joint_state(WHEEL_STATES, n_wheels, "wheel_speed", "wheel_torque"),
        STATE_WHEEL_SPEED: lambda: wire.joint_state(STATE_WHEEL_SPEED, n_wheels, "wheel_speed", None),
        ESTIMATE_ATTITUDE: lambda: wire.stamped(ESTIMATE_ATTITUDE, "est_q_BN", 4),
        ESTIMATE_RATE: lambda: wire.stamped(ESTIMATE_RATE, "est_omega_BN_B", 3),
        ESTIMATOR_GYRO_BIAS: lambda: wire.stamped(ESTIMATOR_GYRO_BIAS, "est_gyro_bias", 3),
        ESTIMATOR_ATTITUDE_SIGMA: lambda: wire.stamped(ESTIMATOR_ATTITUDE_SIGMA, "est_attitude_sigma", 3),
        ESTIMATOR_BIAS_SIGMA: lambda: wire.stamped(ESTIMATOR_BIAS_SIGMA, "est_bias_sigma", 3),
        ESTIMATOR_COVARIANCE: wire.covariance,
        ESTIMATOR_DIAGNOSTICS: wire.estimator_diagnostics,
        STATE_MAGNETIC_FIELD: lambda: wire.magnetic_field(STATE_MAGNETIC_FIELD, "B_meas", _magnetometer_variance(scenario)),
        TRUTH_MAGNETIC_FIELD: lambda: wire.magnetic_field(TRUTH_MAGNETIC_FIELD, "B_B", np.zeros(3)),
        CONTROL_DIPOLE: lambda: wire.dipole(_n_rods(scenario)),
        MODE_STATUS: wire.mode_status,
    }
    return layouts[topic]()


def _magnetometer_variance(scenario: Scenario) -> Array:
    """The plant's ``state/magnetic_field`` covariance diagonal [T^2]: the magnetometer's noise
    squared (zero without one: the field is known exactly)."""
    mag = None if scenario.environment is None else scenario.environment.magnetometer
    if mag is None:
        return np.zeros(3)
    variance: Array = np.broadcast_to(np.asarray(mag.noise_T, dtype=np.float64), (3,)) ** 2
    return variance


def _n_rods(scenario: Scenario) -> int:
    env = scenario.environment
    return 0 if env is None or env.magnetorquers is None else int(np.asarray(env.magnetorquers.max_dipoles()).size)


def controller_parameters(scenario: Scenario, controller: ControllerKind | str | None = None) -> dict[str, Any]:
    """The controller node's ROS parameters of a lockstep graph run of ``scenario``
    (``{"/controller": {"ros__parameters": ...}}``: the controller's configuration, its period,
    mode, watchdog and input bounds, with flight modes HOLD's and SAFE's gains, as
    :func:`sappc.graph.launch.node_parameters` gives them, but the graph's plumbing: expected
    subscribers, counts and timing files)."""
    params = controller_node_parameters(scenario, controller)
    return {"/controller": {"ros__parameters": params}}


# ---- the writer ------------------------------------------------------------------------------
@dataclass
class _Channel:
    topic: Topic
    id: int
    payload: wire.Layout
    offset: int  # of its message record in a sample's row [bytes]


class OfflineBagWriter:
    """Writes the blocks of an offline run into the bag directory ``out_dir`` (module docstring).

    ``scenario``: the run's (its topics, reference, magnetometer, controller parameters);
    ``controller``: the controller flown (default: the scenario's).  The directory must not exist
    (a recorder never overwrites a bag); it is created with ``metadata.yaml`` at once (the topics,
    no messages), so a run killed midway leaves a bag that ``sappc repair`` completes.

    Call it with each block of the run (:class:`~sappc.evaluation.history.History` of one run, the
    next samples, ``t`` the samples' ``k dt``), then :meth:`close` (or use it as a context manager,
    which closes it).  ``history`` may carry ``answer`` ((T, N) int8: how the controller answered
    each sample, the contract's ``ANSWER_*`` codes) for the diagnostics' status and input stamps.

    Raises
    ------
    BagError
        When ``out_dir`` exists.
    """

    def __init__(self, scenario: Scenario, out_dir: str | Path, *, controller: ControllerKind | str | None = None) -> None:
        self.dir = Path(out_dir)
        if self.dir.exists():
            raise BagError(f"{self.dir} already exists; a recorder never overwrites a bag")
        self.scenario = scenario
        self.mcap_name = f"{self.dir.name}_0.mcap"
        self._carry = scenario.reference.start()  # the reference's integration, block to block
        topics = offline_topics(scenario)
        self.channels: list[_Channel] = []
        offset = 0
        for cid, topic in enumerate(topics, start=1):
            payload = _payload(topic, scenario)
            self.channels.append(_Channel(topic, cid, payload, offset))
            offset += MESSAGE_HEAD_BYTES + len(payload.buf)
        self.row_bytes = offset  # one sample's messages, every topic
        self._template = self._row_template()
        self.samples_per_chunk = max(1, CHUNK_SIZE_BYTES // self.row_bytes)
        self.topic_names = [("/" + t.name.lstrip("/"), t.type_name) for t in topics]  # resolved in the root namespace
        self.modes = MODE_STATUS in topics  # each block's History must carry its mode record
        self.samples = 0  # samples written (and so each topic's messages)
        self.start_ns: int | None = None
        self.end_ns = 0
        self._pending = np.zeros((0, self.row_bytes), np.uint8)  # the rows of a chunk not yet full
        self._pending_ns = np.zeros(0, np.int64)
        self._no_data = 0  # the estimator's "no data" and withheld samples so far (its diagnostics' counts)
        self._withheld = 0
        self.closed = False

        self.dir.mkdir(parents=True)
        scenario_text = yaml.safe_dump(scenario.raw, sort_keys=False)
        params_text = yaml.safe_dump(controller_parameters(scenario, controller), sort_keys=False)
        self.custom = {"sappc/scenario.yaml": "scenario.yaml", "sappc/params.yaml": "params.yaml"}
        (self.dir / "scenario.yaml").write_text(scenario_text)
        (self.dir / "params.yaml").write_text(params_text)
        self._file: IO[bytes] = open(self.dir / self.mcap_name, "wb")  # noqa: SIM115 (closed in close)
        self._mcap = McapWriter(self._file, LIBRARY, level=ZSTD_LEVEL)
        # the schemas (each before its first channel, as the recorder registers them) and the
        # channels, here and again in the summary section
        qos_text = yaml.safe_dump(offered_qos_v9(), sort_keys=False)
        schemas: dict[str, int] = {}
        for ch, (name, type_name) in zip(self.channels, self.topic_names):
            if type_name not in schemas:
                schemas[type_name] = self._mcap.schema(type_name, "ros2msg", schema_text(type_name).encode())
            cid = self._mcap.channel(name, "cdr", schemas[type_name], {"offered_qos_profiles": qos_text, "topic_type_hash": type_hash(type_name)})
            assert cid == ch.id  # the channels' ids are their order, from 1
        self._mcap.metadata("sappc/scenario.yaml", {"text": scenario_text})
        self._mcap.metadata("sappc/params.yaml", {"text": params_text})
        self._file.flush()
        write_bag_metadata(self.dir, self._bag_metadata())  # the topics now, the counts at the close

    # -- the blocks ------------------------------------------------------------------------
    def __call__(self, history: History) -> None:
        """Encode and write the samples of ``history`` (one run: the run's next block)."""
        if self.closed:
            raise ValueError(f"{self.dir}: the bag is closed")
        if history.q_BN.shape[1] != 1:
            raise ValueError(f"a bag holds one run, got a history of {history.q_BN.shape[1]}")
        if self.modes and (history.mode is None or history.mode_reason is None):
            raise ValueError(f"{self.dir}: the scenario has flight modes: the History must carry its mode record (mode, mode_reason)")
        T = history.t.size
        if T == 0:
            return
        piece = max(1, ENCODE_BYTES // self.row_bytes)
        ref = self.scenario.reference.sample(history.t, self._carry)  # the carry advances to the block's end
        for lo in range(0, T, piece):
            hi = min(lo + piece, T)
            t_ns = seconds_to_ns_array(history.t[lo:hi])
            values = self._values(history, lo, hi, t_ns, ref.q_RN[lo:hi], ref.omega_RN_R[lo:hi], ref.omegadot_RN_R[lo:hi])
            rows = self._rows(t_ns, values)
            self.samples += hi - lo
            self._write_rows(rows, t_ns)

    def _values(self, h: History, lo: int, hi: int, t_ns: NDArray[np.int64], q_RN: Array, w_RN: Array,
                wd_RN: Array) -> dict[str, Array]:
        """Every key of the payloads (:func:`_payload`) for samples ``lo .. hi - 1`` of ``h``: (n, count) float64."""
        n = hi - lo
        t_s = (t_ns / _NS_PER_S)[:, None]  # as the nodes compute the float arrays' data[0]

        def one(a: NDArray[Any] | None) -> Array:
            return np.zeros((n, 0)) if a is None else np.asarray(a[lo:hi, 0], dtype=np.float64).reshape(n, -1)

        v: dict[str, Array] = {
            "q_BN": one(h.q_BN), "omega_BN_B": one(h.omega_BN_B), "q_RN": q_RN, "omega_RN_R": w_RN, "omegadot_RN_R": wd_RN,
            "torque_B": one(h.torque_B), "disturbance_B": one(h.disturbance_B),
        }
        answer = getattr(h, "answer", None)
        if answer is None:  # not in the record: unknown
            status = np.full((n, 2), np.nan)
            stamps = np.full((n, 6), np.nan)
        else:
            code = np.asarray(answer[lo:hi, 0], dtype=np.float64)
            computed = code == ANSWER_COMMANDED
            status = np.stack((np.where(computed, 0.0, 1.0), code), axis=1)  # the stale flag, the answer's code
            own = np.where(computed[:, None], t_s, 0.0)  # lockstep: every input of a computed sample has its stamp
            stamps = own * np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0])  # state's attitude and rate, 0.0; the reference's three
        v["diagnostics"] = np.concatenate((
            np.repeat(t_s, 3, axis=1), one(h.rho), one(h.band_lower), one(h.band_upper), one(h.eps), one(h.z), one(h.V),
            one(h.torque_cmd_B), one(h.saturated), np.full((n, 1), np.nan), status, stamps), axis=1)
        if h.wheel_speed_rad_s is not None and h.wheel_torque_Nm is not None:
            v["wheel_speed"], v["wheel_torque"] = one(h.wheel_speed_rad_s), one(h.wheel_torque_Nm)
        est = h.estimate
        if est is not None:
            P = one(est.covariance)  # (n, 36) row major
            diag = P[:, [0, 7, 14, 21, 28, 35]]
            q = one(est.q_BN)
            figures = np.all(np.isfinite(one(est.gyro_bias)), axis=1)
            no_data = ~np.all(np.isfinite(q), axis=1)  # the estimate not given: the node's no_data count
            withheld = figures & no_data
            no_data_count = self._no_data + np.cumsum(no_data)
            withheld_count = self._withheld + np.cumsum(withheld)
            self._no_data, self._withheld = int(no_data_count[-1]), int(withheld_count[-1])

            def column(a: NDArray[Any] | None) -> Array:
                return np.full((n, 1), np.nan) if a is None else one(a).reshape(n, 1)

            unknown = np.full((n, 1), np.nan)
            v.update(est_q_BN=q, est_omega_BN_B=one(est.omega_BN_B), est_gyro_bias=one(est.gyro_bias),
                     est_attitude_sigma=np.sqrt(diag[:, :3]), est_bias_sigma=np.sqrt(diag[:, 3:]),
                     covariance=np.concatenate((t_s, P), axis=1),
                     gyro_bias_true=one(est.gyro_bias_true) if est.gyro_bias_true is not None else np.full((n, 3), np.nan),
                     estimator_diagnostics=np.concatenate((
                         t_s, column(est.nis), column(est.status), unknown, unknown, unknown,
                         no_data_count[:, None].astype(np.float64), unknown,
                         column(est.monitor_level), column(est.monitor_nis_sum), column(est.recoveries),
                         withheld_count[:, None].astype(np.float64)), axis=1))
        if h.orbit is not None:
            o = one(h.orbit)
            v.update(B_B=o[:, 0:3], B_meas=o[:, 3:6], dipole=np.concatenate((t_s, o[:, 9:]), axis=1))
        if h.mode is not None and h.mode_reason is not None:  # the mode node's [time_s, mode, reason]
            v["mode_status"] = np.concatenate((t_s, one(h.mode), one(h.mode_reason)), axis=1)
        return v

    def _row_template(self) -> NDArray[np.uint8]:
        """One sample's messages with every varying value zero: the message records' heads (but
        the sequence and times) and the payloads' fixed bytes."""
        row = bytearray()
        for ch in self.channels:
            row += message_head(ch.id, 0, 0, 0, len(ch.payload.buf)) + ch.payload.buf
        return np.frombuffer(bytes(row), np.uint8)

    def _rows(self, t_ns: NDArray[np.int64], values: dict[str, Array]) -> NDArray[np.uint8]:
        """The samples' messages, one row of :attr:`row_bytes` a sample (every topic, in channel order)."""
        n = t_ns.size
        rows = np.empty((n, self.row_bytes), np.uint8)
        rows[:] = self._template
        seq = (self.samples + 1 + np.arange(n)).astype("<u4")  # each topic's sequence: its messages from 1
        sec = (t_ns // _NS_PER_S).astype("<i4")
        nsec = (t_ns % _NS_PER_S).astype("<u4")
        log = t_ns.astype("<u8")
        for ch in self.channels:
            at = ch.offset
            _put(rows, at + 11, seq[:, None])
            _put(rows, at + 15, log[:, None])  # log time
            _put(rows, at + 23, log[:, None])  # publish time
            base = at + MESSAGE_HEAD_BYTES
            for f in ch.payload.fields:
                if f.key == "stamp":
                    _put(rows, base + f.offset, sec[:, None])
                    _put(rows, base + f.offset + 4, nsec[:, None])
                else:
                    value = values[f.key]
                    if value.shape != (n, f.count):
                        raise ValueError(f"{ch.topic.name}: {f.key} has shape {value.shape}, the message {(n, f.count)}")
                    _put(rows, base + f.offset, value.astype("<f8", copy=False))
        return rows

    def _write_rows(self, rows: NDArray[np.uint8], t_ns: NDArray[np.int64]) -> None:
        """The full chunks of the pending rows and ``rows``; the rest stays pending."""
        if self._pending.shape[0]:
            rows = np.concatenate((self._pending, rows))
            t_ns = np.concatenate((self._pending_ns, t_ns))
        k = self.samples_per_chunk
        full = rows.shape[0] // k * k
        for lo in range(0, full, k):
            self._chunk(rows[lo : lo + k], t_ns[lo : lo + k])
        self._pending, self._pending_ns = rows[full:].copy(), t_ns[full:].copy()

    @property
    def messages(self) -> int:
        """Messages written: a sample's of every topic."""
        return self.samples * len(self.channels)

    @property
    def chunks(self) -> int:
        """Chunks written."""
        return self._mcap.chunks

    def _chunk(self, rows: NDArray[np.uint8], t_ns: NDArray[np.int64]) -> None:
        """One chunk of the samples' ``rows`` (stamps ``t_ns``), then its message indexes."""
        n = t_ns.size
        index: dict[int, NDArray[np.uint64]] = {}
        for ch in self.channels:
            pairs = np.empty((n, 2), np.uint64)
            pairs[:, 0] = t_ns
            pairs[:, 1] = ch.offset + self.row_bytes * np.arange(n, dtype=np.uint64)
            index[ch.id] = pairs
        self._mcap.chunk(np.ascontiguousarray(rows).data, int(t_ns[0]), int(t_ns[-1]), index)
        if self.start_ns is None:
            self.start_ns = int(t_ns[0])
        self.end_ns = int(t_ns[-1])

    # -- the end -----------------------------------------------------------------------------
    def close(self) -> Path:
        """Write the last chunk, the summary and ``metadata.yaml`` (the counts); the bag directory.
        A second call does nothing."""
        if self.closed:
            return self.dir
        if self._pending.shape[0]:
            self._chunk(self._pending, self._pending_ns)
            self._pending = self._pending[:0]
        meta = self._bag_metadata()
        self._mcap.metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(meta["rosbag2_bagfile_information"], sort_keys=False)})
        self._mcap.finish()
        self._file.close()
        self.closed = True
        write_bag_metadata(self.dir, meta)
        return self.dir

    def __enter__(self) -> OfflineBagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()  # also when the run failed: what was written stays, a whole file

    def _bag_metadata(self) -> dict[str, Any]:
        counts = {name: self.samples for name, _ in self.topic_names}
        return bag_metadata(self.mcap_name, self.topic_names, counts, self.start_ns or 0, self.end_ns, self.custom)


def _put(rows: NDArray[np.uint8], offset: int, values: NDArray[Any]) -> None:
    """``values`` (n, m) into bytes ``offset ..`` of each row of ``rows``, in their dtype's bytes."""
    width = values.shape[1] * values.dtype.itemsize
    rows[:, offset : offset + width] = np.ascontiguousarray(values).view(np.uint8).reshape(values.shape[0], width)

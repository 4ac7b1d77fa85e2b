"""Read a recorded bag back into arrays, and compute a run's metrics from it.

Works on any bag that follows the topic contract (``sappc run``'s, or a user plant's): a rosbag2
directory with ``metadata.yaml`` and an MCAP file, or a bare ``.mcap`` file.  The file is read
sequentially (:mod:`sappc.bag.mcap_scan`), so a bag cut short by a crash (no summary, a torn last
chunk) yields every message before the tear and says where it ends, and decoded without ROS
(:mod:`sappc.bag.cdr`).

Samples are aligned on the plant's state stamps (``state/attitude`` and ``state/rate``, the
truth even when a fault relay feeds the controller; ``truth/attitude`` and ``truth/rate`` when the
plant has sensor models and ``state/*`` are its measurements): the reference is interpolated at each stamp
(exact when the stamps coincide, as in lockstep), torques, disturbances and diagnostics are the
latest at or before it (zero-order hold, as the plant applies them).

Flight modes: a bag with ``mode/status`` (whoever wrote it: ``sappc simulate --record`` or the
graph's mode node) gives each sample's mode and transition reason (:func:`_mode_record`), as the
offline loop records them; a bag without it has no mode record (``History.mode`` ``None``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_msgs_py.contract import (
    ESTIMATOR_NO_INPUT,
    TRUTH_GYRO_BIAS,
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    ERROR_STATE,
    ESTIMATE_ATTITUDE,
    ESTIMATE_RATE,
    ESTIMATOR_ATTITUDE_SIGMA,
    ESTIMATOR_BIAS_SIGMA,
    ESTIMATOR_COVARIANCE,
    ESTIMATOR_DIAGNOSTICS,
    ESTIMATOR_DIAGNOSTICS_LAYOUT,
    ESTIMATOR_GYRO_BIAS,
    DISTURBANCE_TORQUE,
    ANSWER_COMMANDED,
    ANSWER_NAMES,
    ANSWER_HELD,
    ANSWER_REFUSED,
    ANSWER_WATCHDOG_ZERO,
    FAULT_PREFIX,
    REFERENCE_ATTITUDE,
    STATE_ATTITUDE,
    STATE_RATE,
    TRUTH_ATTITUDE,
    TRUTH_RATE,
    WHEEL_STATES,
    CONTROL_DIPOLE,
    MODE_STATUS,
    MODE_STATUS_LAYOUT,
    STATE_MAGNETIC_FIELD,
    TRUTH_MAGNETIC_FIELD,
    consumed_names,
)
from gnc_common.attitude import error_quaternion, quat_normalize
from gnc_common.validation import ConfigError, read_yaml_file

from sappc.bag.cdr import decode
from sappc.bag.errors import BagError
from sappc.evaluation.estimation import EstimateHistory
from sappc.evaluation.history import History
from sappc.bag.mcap_scan import Scan, scan_mcap
from sappc.evaluation.metrics import MetricsAccumulator

__all__ = ["PARAMS_RECORD", "SCENARIO_RECORD", "TICK_PERIOD_S", "Bag", "BagError", "BagEstimate", "BagRun", "Ticker", "bag_estimate", "bag_metrics",
           "aligned", "aligned_topics", "bag_run", "find_topic", "frames_lacking_inputs", "latest_index", "nearest_index", "STAMP_TOL_NS", "read_bag",
           "sample_stamps", "scan_bag", "state_topics", "torque_topic"]

#: Metadata records that ``sappc run``'s recorder embeds in the bag: the scenario file and the
#: ROS parameters of every node (the recorder names them ``sappc/<file name>``).
SCENARIO_RECORD = "sappc/scenario.yaml"
PARAMS_RECORD = "sappc/params.yaml"

Array = NDArray[np.float64]

#: The period of a :class:`Ticker`'s line [s]: ``sappc run`` prints a line at least every 2 s to
#: its last (issue 46), one a second as its progress line during the run
#: (``sappc.graph.launch.PROGRESS_PERIOD_S``).
TICK_PERIOD_S = 1.0
#: How often a ticker's thread looks whether a line is due [s]: a line comes at most this late.
TICK_POLL_S = 0.25


class Ticker:
    """A progress line while slow steps run: ``say("STEP: DETAIL (N s)")`` when a step starts
    (:meth:`step`), then every ``period_s`` until the next step or :meth:`idle`; ``DETAIL`` is how
    far the step says it is (:meth:`detail`, e.g. ``"12.0 of 40.3 MB"``), ``N`` the seconds since
    the step started.

    The lines come from a thread of the ticker's own while it is entered as a context (``with
    Ticker(say) as ticker:``), so a step that cannot report (a system call, one numpy operation
    over a whole bag, a process that takes its time to exit) still shows it is alive (issue 46:
    ``sappc run`` was silent for up to 10 s while it stopped its nodes and read its bag back).
    Outside a ``with`` nothing is printed but by :meth:`step`, :meth:`detail` and :meth:`poll`.
    Every decision reads ``clock`` (a test gives one of its own and drives :meth:`poll` as the
    thread does, every ``poll_s`` of real time).
    """

    def __init__(self, say: Callable[[str], object], *, period_s: float = TICK_PERIOD_S, poll_s: float = TICK_POLL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._say, self._clock = say, clock
        self.period_s, self.poll_s = period_s, poll_s
        self._lock = threading.Lock()  # the thread and the steps' calls print one at a time
        self._step: str | None = None  # None: idle, no line
        self._detail = ""
        self._started = self._last = 0.0  # when the step started, when the last line was said
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def step(self, text: str, detail: str = "") -> None:
        """A new step: its line now, then one every period."""
        with self._lock:
            self._step, self._detail = text, detail
            self._started = self._clock()
            self._line(self._started)

    def detail(self, text: str) -> None:
        """How far the current step is, shown in its next line (said now when one is due: a step
        that reports often enough needs no thread)."""
        with self._lock:
            self._detail = text
            self._due()

    def idle(self) -> None:
        """No step: no line until the next :meth:`step` (the caller prints lines of its own)."""
        with self._lock:
            self._step = None

    def poll(self) -> None:
        """The current step's line, when ``period_s`` has passed since the last line."""
        with self._lock:
            self._due()

    def _due(self) -> None:
        now = self._clock()
        if self._step is not None and now - self._last >= self.period_s:
            self._line(now)

    def _line(self, now: float) -> None:
        self._last = now
        elapsed = now - self._started
        self._say(f"{self._step}{': ' + self._detail if self._detail else ''}" + (f" ({elapsed:.0f} s)" if elapsed > 0 else ""))

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            self.poll()

    def __enter__(self) -> Ticker:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sappc-ticker", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.idle()


def _reading(ticker: Ticker | None) -> Callable[[int, int], object] | None:
    """The read-back's progress for :func:`~sappc.bag.mcap_scan.scan_mcap`: ``X of Y MB``."""
    if ticker is None:
        return None
    return lambda done, total: ticker.detail(f"{done / 1e6:.1f} of {total / 1e6:.1f} MB")


@dataclass
class Series:
    """One topic: header stamps [ns] and values, in recording order."""

    stamps_ns: NDArray[np.int64]
    values: Array
    log_time_ns: NDArray[np.int64]  # each message's log time: its stamp (lockstep bags) or when the recorder received it (real time)


@dataclass
class Bag:
    """The messages of a bag as arrays (see :func:`read_bag`)."""

    path: Path
    series: dict[str, Series]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: str | None = None  # why reading stopped early, None when the file is whole
    diagnostics_labels: tuple[str, ...] = ()
    undecodable: dict[str, int] = field(default_factory=dict)  # topic -> messages not fitting its type
    frame_ids: dict[str, tuple[str, ...]] = field(default_factory=dict)  # topic -> header frame ids seen
    array_labels: dict[str, tuple[str, ...]] = field(default_factory=dict)  # Float64MultiArray topic -> its first dimension's labels
    # a bag read in blocks (:mod:`sappc.bag.blocks`) keeps no series: each topic's messages read
    # (decoded), in the order ``series`` would have them; None: the counts are the series'
    message_counts: dict[str, int] | None = None

    @property
    def counts(self) -> dict[str, int]:
        """Messages read per topic."""
        if self.message_counts is not None:
            return dict(self.message_counts)
        return {t: s.stamps_ns.size for t, s in self.series.items()}

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics read (those of :attr:`series`, or of :attr:`message_counts` for a bag read in blocks)."""
        return tuple(self.message_counts if self.message_counts is not None else self.series)


def mcap_file(path: Path) -> Path:
    """The MCAP file of a bag: ``path`` itself, or the one a rosbag2 directory lists."""
    if path.is_file():
        return path
    if not path.is_dir():
        raise BagError(f"{path}: no such bag (a rosbag2 directory or an .mcap file)")
    meta = path / "metadata.yaml"
    if meta.exists():
        try:
            info = read_yaml_file(meta, "rosbag2 metadata")["rosbag2_bagfile_information"]
            files: list[Path] = [path / f for f in info["relative_file_paths"]]
        except ConfigError as exc:  # not readable, not YAML, or past a limit (the message names the file)
            raise BagError(str(exc)) from None
        except (KeyError, TypeError) as exc:
            raise BagError(f"{meta}: not a rosbag2 metadata file ({exc})") from None
        if len(files) > 1:
            raise BagError(f"{path}: a bag split into {len(files)} files is not supported; give one of them")
        if len(files) == 1 and files[0].exists():
            return files[0]
    found = sorted(path.glob("*.mcap"))
    if not found:
        raise BagError(f"{path}: no .mcap file in the bag directory")
    return found[0]


def scan_bag(path: str | Path, *, ticker: Ticker | None = None) -> Scan:
    """The raw messages of the bag at ``path`` (see :func:`sappc.bag.mcap_scan.scan_mcap`);
    ``ticker``: the bytes read so far are its current step's detail."""
    mcap_path = mcap_file(Path(path))
    try:
        return scan_mcap(mcap_path, progress=_reading(ticker))
    except ValueError as exc:
        raise BagError(str(exc)) from None
    except OSError as exc:
        raise BagError(f"{mcap_path}: cannot read ({exc.strerror})") from None


def read_bag(path: str | Path, *, ticker: Ticker | None = None) -> Bag:
    """Every message of the contract's types in the bag at ``path``, as arrays.

    ``ticker``: the read's progress as its step "reading the bag back" (the megabytes read, then
    the topic being decoded).

    Raises
    ------
    BagError
        If ``path`` is not a bag (no MCAP file, not MCAP, no message of the contract's types).
    """
    p = Path(path)
    if ticker is not None:
        ticker.step("reading the bag back")
    scan = scan_bag(p, ticker=ticker)
    series: dict[str, Series] = {}
    labels: tuple[str, ...] = ()
    undecodable: dict[str, int] = {}
    frame_ids: dict[str, tuple[str, ...]] = {}
    array_labels: dict[str, tuple[str, ...]] = {}
    for n, (cid, channel) in enumerate(scan.channels.items()):
        if ticker is not None:
            ticker.detail(f"decoding {channel.topic}, topic {n + 1} of {len(scan.channels)}")
        start, length, log_time = scan.payloads(cid)
        if channel.message_encoding != "cdr" or start.size == 0:
            continue
        d = decode(channel.schema_name, scan.buffer, start, length)
        if d is None:
            continue
        series[channel.topic] = Series(d.stamps_ns, d.values, log_time[d.index])
        # the controller's diagnostics: time_s first, not the estimator's nor the mode's (joint_states' labels are its joint names)
        if channel.schema_name == CONTROLLER_DIAGNOSTICS.type_name and d.labels[:1] == ("time_s",) and d.labels != ESTIMATOR_DIAGNOSTICS_LAYOUT \
                and d.labels != MODE_STATUS_LAYOUT:
            labels = labels or d.labels
        frame_ids[channel.topic] = d.frame_ids
        if channel.schema_name == ESTIMATOR_DIAGNOSTICS.type_name:
            array_labels[channel.topic] = d.labels
        if d.undecodable:
            undecodable[channel.topic] = d.undecodable
    if not any(s.stamps_ns.size for s in series.values()):
        raise BagError(f"{p}: the bag holds no messages of the topic contract" + (f" (reading stopped: {scan.truncated})" if scan.truncated else ""))
    return Bag(path=p, series=series, metadata=scan.metadata, truncated=scan.truncated, diagnostics_labels=labels,
               undecodable=undecodable, frame_ids=frame_ids, array_labels=array_labels)


def find_topic(bag: Bag, name: str) -> str | None:
    """The recorded topic whose name is ``name``, else one that ends with ``/name`` (a namespaced
    run) and is not a fault relay's output (``fault/state/attitude`` is not ``state/attitude``)."""
    name = name.lstrip("/")
    topics = bag.topics
    for t in topics:
        if t.lstrip("/") == name:
            return t
    relay = "/" + FAULT_PREFIX.strip("/") + "/" + name
    for t in topics:
        if t.endswith("/" + name) and not ("/" + t.lstrip("/")).endswith(relay):
            return t
    return None


#: Stamps carried as float seconds (the diagnostics' ``time_s`` and input stamps: epoch times in
#: real time) are exact to ~0.24 us; messages of one topic are milliseconds apart, so 1 us
#: identifies one unambiguously.
STAMP_TOL_NS = 1_000


def nearest_index(stamps_ns: NDArray[np.int64], at_ns: NDArray[np.int64], tol_ns: int = STAMP_TOL_NS) -> NDArray[np.int64]:
    """Index of the sample whose stamp is nearest each of ``at_ns``, or -1 when none is within ``tol_ns``."""
    if stamps_ns.size == 0:
        return np.full(np.shape(at_ns), -1, dtype=np.int64)
    order = np.argsort(stamps_ns, kind="stable")
    s = stamps_ns[order]
    hi = np.clip(np.searchsorted(s, at_ns), 0, s.size - 1)
    lo = np.maximum(hi - 1, 0)
    best = np.where(np.abs(s[lo] - at_ns) <= np.abs(s[hi] - at_ns), lo, hi)
    return np.where(np.abs(s[best] - at_ns) <= tol_ns, order[best], -1)


def latest_index(stamps: NDArray[np.int64], at: NDArray[np.int64]) -> NDArray[np.int64]:
    """Index of the latest sample at or before each of ``at`` (-1 if none)."""
    order = np.argsort(stamps, kind="stable")
    idx = np.searchsorted(stamps[order], at, side="right") - 1
    return np.where(idx >= 0, order[np.maximum(idx, 0)], -1)


@dataclass
class BagRun:
    """A run recovered from a bag, aligned on the state stamps."""

    history: History  # one run (N = 1), t in seconds since the first aligned state
    t0_ns: int  # stamp of the first aligned state
    answer: NDArray[np.int8]  # (T,) how the controller answered each sample (contract ANSWER_* codes)
    rejected: int  # messages the controller rejected (the largest count of its diagnostics in the bag)
    torque_topic: str | None  # the topic the plant applied (a fault relay's when there was one)
    has_diagnostics: bool  # controller/diagnostics present (rho, band, saturation, Lyapunov values)
    # the last sample's time [s] when ``history`` is not every sample (a long bag read in blocks,
    # :mod:`sappc.bag.blocks`: a bounded history for the figures); None: ``history.t[-1]``
    t_end_s: float | None = None

    @property
    def samples(self) -> int:
        """The run's aligned samples."""
        return int(self.answer.size)

    @property
    def end_s(self) -> float:
        """The last sample's time from the first [s]."""
        return float(self.history.t[-1]) if self.t_end_s is None else self.t_end_s

    @property
    def stale(self) -> NDArray[np.bool_]:
        """(T,) samples answered with zero torque (the watchdog, or a refused step)."""
        return np.isin(self.answer, (ANSWER_WATCHDOG_ZERO, ANSWER_REFUSED))

    def controller_summary(self) -> dict[str, Any]:
        """What the controller did, from its diagnostics: ``samples`` aligned, then the samples
        answered in each way (:data:`~sappc_msgs_py.contract.ANSWER_NAMES`: the same counts as
        ``sappc simulate``'s summary) and ``rejected_inputs``; ``None`` values without diagnostics."""
        if not self.has_diagnostics:
            return {"samples": int(self.answer.size), **{name: None for name in ANSWER_NAMES}, "rejected_inputs": None}
        counts = {name: int(np.count_nonzero(self.answer == code)) for code, name in enumerate(ANSWER_NAMES)}
        return {"samples": int(self.answer.size), **counts, "rejected_inputs": self.rejected}


def bag_run(bag: Bag, duration_s: float | None = None, *, ticker: Ticker | None = None) -> BagRun:
    """Align the bag's topics on the state stamps (see the module docstring); with
    ``duration_s``, only the states of ``[0, duration_s]`` from the first (a run's own span: a
    state recorded after it, e.g. from a plant that ran on, is no sample of the run).
    ``ticker``: the alignment is its step "aligning the samples".

    Raises
    ------
    BagError
        If the bag lacks the state or the reference, or they never overlap.
    """
    if ticker is not None:
        ticker.step("aligning the samples")
    common = sample_stamps(bag, duration_s)
    history, answer, has_diagnostics = aligned(bag, common, int(common[0]))
    diag_topic = find_topic(bag, CONTROLLER_DIAGNOSTICS.name)
    return BagRun(
        history=history,
        t0_ns=int(common[0]),
        answer=answer,
        rejected=_rejected_count(bag, diag_topic, bag.diagnostics_labels),
        torque_topic=torque_topic(bag),
        has_diagnostics=has_diagnostics,
    )


def state_topics(bag: Bag) -> dict[str, str | None]:
    """The topics a run's samples are aligned on: ``att``, ``rate`` (the truth: ``truth/*`` from a
    plant with sensor models, whose ``state/*`` are measurements, else ``state/*``) and ``ref``
    (``reference/attitude``); ``None`` for one the bag lacks."""
    return {k: find_topic(bag, v) for k, v in _state_names(bag).items()}


def _state_names(bag: Bag) -> dict[str, str]:
    truth = find_topic(bag, TRUTH_ATTITUDE.name) is not None and find_topic(bag, TRUTH_RATE.name) is not None
    return {
        "att": TRUTH_ATTITUDE.name if truth else STATE_ATTITUDE.name,
        "rate": TRUTH_RATE.name if truth else STATE_RATE.name,
        "ref": REFERENCE_ATTITUDE.name,
    }


def sample_stamps(bag: Bag, duration_s: float | None = None) -> NDArray[np.int64]:
    """The stamps of the run's samples [ns], sorted: those of both an attitude and a rate
    (:func:`state_topics`) from the first reference on; with ``duration_s``, only those of
    ``[0, duration_s]`` from the first.  Reads only the three topics' stamps.

    Raises
    ------
    BagError
        If the bag lacks the state or the reference, or they never overlap.
    """
    names = _state_names(bag)
    found = {k: find_topic(bag, v) for k, v in names.items()}
    missing = [names[k] for k, v in found.items() if v is None or bag.series[v].stamps_ns.size == 0]
    if missing:
        raise BagError(f"{bag.path}: the bag lacks {', '.join(missing)}; metrics need the state and the reference")
    att, rate, ref = (bag.series[found[k]] for k in ("att", "rate", "ref"))  # type: ignore[index]  # no found[k] is None: `missing` raised
    common = np.intersect1d(att.stamps_ns, rate.stamps_ns)
    common = common[common >= ref.stamps_ns.min()]
    if common.size == 0:
        raise BagError(f"{bag.path}: no state sample has both attitude and rate after the first reference")
    if duration_s is not None:
        common = common[common - common[0] <= round(duration_s * 1e9)]
    stamps: NDArray[np.int64] = common
    return stamps


def torque_topic(bag: Bag) -> str | None:
    """The torque the plant applied: the actuator relay's output when the run relayed it."""
    return next((t for name in consumed_names(CONTROL_TORQUE) if (t := find_topic(bag, name)) is not None), None)


def aligned_topics(bag: Bag) -> tuple[str, ...]:
    """Every topic :func:`aligned` reads, each once: a bag read in blocks keeps a window of these
    (:mod:`sappc.bag.blocks`)."""
    found = state_topics(bag)
    names = (DISTURBANCE_TORQUE, CONTROLLER_DIAGNOSTICS, WHEEL_STATES, TRUTH_GYRO_BIAS, STATE_MAGNETIC_FIELD, TRUTH_MAGNETIC_FIELD,
             CONTROL_DIPOLE, ESTIMATE_ATTITUDE, ESTIMATE_RATE, ESTIMATOR_GYRO_BIAS, ESTIMATOR_ATTITUDE_SIGMA, ESTIMATOR_BIAS_SIGMA,
             ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS, MODE_STATUS)
    topics = [found["att"], found["rate"], found["ref"], torque_topic(bag)] + [find_topic(bag, t.name) for t in names]
    return tuple(dict.fromkeys(t for t in topics if t is not None))


def aligned(bag: Bag, common: NDArray[np.int64], t0_ns: int) -> tuple[History, NDArray[np.int8], bool]:
    """The run's samples at the stamps ``common`` (ns; sorted, a part of :func:`sample_stamps`'s),
    ``t`` counted from ``t0_ns`` (the first sample's stamp): the History (N = 1), how the
    controller answered each sample, and whether the bag has the controller's diagnostics.

    Each sample reads only the messages near its stamp (its own, the latest before it, the
    reference's next after it), so a bag whose series hold every message within
    ``2 STAMP_TOL_NS`` of each stamp of ``common``, the latest before and the next after (a
    window of :mod:`sappc.bag.blocks`), gives the same values as the whole bag, bit for bit."""
    found = state_topics(bag)
    att, rate, ref = (bag.series[found[k]] for k in ("att", "rate", "ref"))  # type: ignore[index]  # sample_stamps found them
    ia = latest_index(att.stamps_ns, common)
    ir = latest_index(rate.stamps_ns, common)
    q_BN, w_BN_B = att.values[ia, :4], rate.values[ir, :3]
    # reference attitude at the state stamps: exact where they coincide, else normalised lerp
    order = np.argsort(ref.stamps_ns, kind="stable")
    rs, rq = ref.stamps_ns[order], ref.values[order, :4]
    j = np.clip(np.searchsorted(rs, common, side="right") - 1, 0, rs.size - 1)
    j1 = np.minimum(j + 1, rs.size - 1)
    exact = rs[j] == common
    span = (rs[j1] - rs[j]).astype(np.float64)
    w = np.where(span > 0, (common - rs[j]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
    q1 = np.where((np.sum(rq[j] * rq[j1], axis=1) < 0)[:, None], -rq[j1], rq[j1])
    q_RN = np.where(exact[:, None], rq[j], quat_normalize((1.0 - w) * rq[j] + w * q1))
    q_BR = error_quaternion(q_RN, q_BN)

    T = common.size

    def held(topic: str | None, width: int) -> Array:
        if topic is None:
            return np.zeros((T, width))
        s = bag.series[topic]
        i = latest_index(s.stamps_ns, common)
        return np.where((i >= 0)[:, None], s.values[np.maximum(i, 0), :width], 0.0)

    rows: dict[str, Array] = {}
    diag_topic = find_topic(bag, CONTROLLER_DIAGNOSTICS.name)
    labels = bag.diagnostics_labels
    exact = np.zeros(T, dtype=bool)  # a diagnostics message of the sample's own stamp
    if diag_topic is not None and labels and bag.series[diag_topic].values.shape[1] >= 3 * len(labels):
        d = bag.series[diag_topic]
        # the diagnostics of the sample's own stamp (their time_s is float seconds: exact in
        # lockstep, within STAMP_TOL_NS for the epoch times of real time), else the latest before it
        own = nearest_index(d.stamps_ns, common)
        exact = own >= 0
        i = np.where(exact, own, latest_index(d.stamps_ns, common))
        data = d.values[np.maximum(i, 0), : 3 * len(labels)].reshape(T, len(labels), 3)
        data[i < 0] = np.nan
        rows = {label: data[:, n] for n, label in enumerate(labels)}
    nan3 = np.full((T, 3), np.nan)
    status = rows.get("status", np.zeros((T, 3)))
    # the answer: the code of the sample's diagnostics (a bag from before the codes: stale flag ->
    # watchdog); no message of its stamp: no answer (the plant held its torque)
    code = np.where((status[:, 1] > 0.5) & (status[:, 2] == 0.0), float(ANSWER_WATCHDOG_ZERO), np.nan_to_num(status[:, 2]))
    answer = np.where(exact, code, float(ANSWER_HELD)).astype(np.int8)

    def one(a: NDArray[Any]) -> NDArray[Any]:
        return a[:, None, :]  # (T, 3) -> (T, 1, 3): one run

    history = History(
        t=(common - t0_ns) / 1e9,
        q_BN=q_BN[:, None, :],
        omega_BN_B=w_BN_B[:, None, :],
        q_BR=q_BR[:, None, :],
        torque_B=one(held(torque_topic(bag), 3)),
        torque_cmd_B=one(rows.get("torque_cmd_Nm", nan3)),
        saturated=one(rows.get("saturated", np.zeros((T, 3))) > 0.5),
        disturbance_B=one(held(find_topic(bag, DISTURBANCE_TORQUE.name), 3)),
        rho=one(rows.get("rho", nan3)),
        band_lower=one(rows.get("band_lower", nan3)),
        band_upper=one(rows.get("band_upper", nan3)),
        eps=one(rows.get("eps", nan3)),
        z=one(rows.get("z", nan3)),
        V=one(rows.get("lyapunov_V", nan3)),
        **_wheel_records(bag, common),
        estimate=_estimate_record(bag, common),
        orbit=_orbit_record(bag, common),
        **_mode_record(bag, common),
    )
    return history, answer, bool(rows)


def _mode_record(bag: Bag, stamps_ns: NDArray[np.int64]) -> dict[str, Any]:
    """``mode`` and ``mode_reason`` (T, 1) int8 from ``mode/status`` at the state stamps, as the
    offline loop records them (:attr:`~sappc.evaluation.history.History.mode`); nothing when the bag
    has no ``mode/status`` (a run without flight modes).

    Each sample takes the message of its own stamp (``data[0]``, float seconds: exact in lockstep,
    within :data:`STAMP_TOL_NS` in real time); a sample without one (a message lost in real time)
    keeps the mode of the latest message before it (a mode holds until a transition), or, before
    the first message, the first message's, and no reason (``R_NONE``, 0: a transition taken at a
    sample whose message is missing is not known).  The columns are found by their labels
    (``layout.dim[0]``): a float array on that name without ``time_s`` first and a ``mode`` and a
    ``reason`` gives no mode record."""
    topic = find_topic(bag, MODE_STATUS.name)
    if topic is None:
        return {}
    s = bag.series[topic]
    labels = bag.array_labels.get(topic) or MODE_STATUS_LAYOUT
    if labels[:1] != MODE_STATUS_LAYOUT[:1] or "mode" not in labels or "reason" not in labels or s.stamps_ns.size == 0 \
            or s.values.shape[1] < len(labels):
        return {}
    own = nearest_index(s.stamps_ns, stamps_ns)
    exact = own >= 0
    held = latest_index(s.stamps_ns, stamps_ns)
    first = int(np.argmin(s.stamps_ns))  # (the first of the least stamps: argmin's)
    i = np.where(exact, own, np.where(held >= 0, held, first))
    mode = s.values[i, labels.index("mode")]
    reason = np.where(exact, s.values[i, labels.index("reason")], 0.0)
    return {"mode": mode.astype(np.int8)[:, None], "mode_reason": reason.astype(np.int8)[:, None]}


def _rejected_count(bag: Bag, diag_topic: str | None, labels: tuple[str, ...]) -> int:
    """The controller's count of rejected input messages: ``status[0]`` of its diagnostics, a count
    that only grows, at its largest over *every* diagnostics message of the bag (0 without).

    Not the last sample's of the run's span: a rejection after the last sample answered (a late
    input at the run's end) would be missing.  A rejection after the controller's last diagnostics
    message is in no bag (the node's own count, its ``timing_file``'s ``rejected_inputs``, has it; a
    real-time controller looks at no input after the run's last frame, so there is none to miss)."""
    if diag_topic is None or "status" not in labels:
        return 0
    values = bag.series[diag_topic].values
    col = 3 * labels.index("status")
    if values.shape[1] <= col or values.shape[0] == 0:
        return 0
    counts = values[:, col]
    counts = counts[np.isfinite(counts)]
    return int(counts.max()) if counts.size else 0


def frames_lacking_inputs(bag: Bag, run: BagRun, dt_s: float, duration_s: float) -> dict[str, int]:
    """A real-time run's frames ``0 .. n`` (``n = duration_s / dt_s``, on the grid of the first
    state's stamp, :mod:`sappc_msgs_py.timeline`) that lacked an input of their own stamp, from
    what the bag holds:

    - ``state``: no state (attitude and rate) stamped with the frame (the plant missed its tick);
    - ``reference``: the frame's control step held an earlier reference (its diagnostics'
      ``input_stamps_reference_s`` are not the frame's stamp);
    - ``torque``: no torque stamped with the frame (the plant held the one before over it).

    A lockstep run has none by construction (the plant waits for every input of a sample).
    """
    dt_ns = round(dt_s * 1e9)
    frames = run.t0_ns + dt_ns * np.arange(round(duration_s / dt_s) + 1, dtype=np.int64)

    def has(topic_name: str | None, at: NDArray[np.int64]) -> NDArray[np.bool_]:
        topic = find_topic(bag, topic_name) if topic_name is not None else None
        return np.zeros(at.size, dtype=bool) if topic is None else np.isin(at, bag.series[topic].stamps_ns)

    state = has(STATE_ATTITUDE.name, frames) & has(STATE_RATE.name, frames)
    torque = has(CONTROL_TORQUE.name, frames)
    held_reference = np.zeros(frames.size, dtype=bool)
    diag_topic = find_topic(bag, CONTROLLER_DIAGNOSTICS.name)
    labels = bag.diagnostics_labels
    if diag_topic is not None and "input_stamps_reference_s" in labels:
        d = bag.series[diag_topic]
        i = nearest_index(d.stamps_ns, frames)  # the frame's own step (time_s is float epoch seconds: within STAMP_TOL_NS)
        col = 3 * labels.index("input_stamps_reference_s")
        used_ns = np.round(d.values[np.maximum(i, 0), col : col + 3] * 1e9)
        own = np.all(np.abs(used_ns - frames[:, None].astype(np.float64)) <= STAMP_TOL_NS, axis=1)
        status = d.values[np.maximum(i, 0), 3 * labels.index("status") + 2] if "status" in labels else np.zeros(frames.size)
        held_reference = (i >= 0) & ~own & (status == ANSWER_COMMANDED)  # a control step on another stamp's reference
    return {"frames": int(frames.size), "state": int(np.count_nonzero(~state)), "reference": int(np.count_nonzero(held_reference)),
            "torque": int(np.count_nonzero(~torque))}


def _estimate_record(bag: Bag, stamps_ns: NDArray[np.int64]) -> EstimateHistory | None:
    """The estimator's record (T, 1, ...) at the state stamps, as the offline loop records it: each
    estimator topic's message of the same stamp (NaN where there is none: "no data"), the status
    from ``estimator/diagnostics``, the gyro's true bias from ``truth/gyro_bias``; ``None`` when
    the bag has no estimator."""
    est = bag_estimate(bag)
    if est is None:
        return None
    T = stamps_ns.size
    i = nearest_index(est.stamps_ns, stamps_ns)
    got = i >= 0

    def at(a: Array) -> Array:
        out = np.full((T,) + a.shape[1:], np.nan)
        out[got] = a[i[got]]
        return out[:, None]

    status = at(est.diagnostics.get("status", np.full(est.stamps_ns.size, np.nan)))
    nis = at(est.diagnostics.get("nis", np.full(est.stamps_ns.size, np.nan)))
    truth = find_topic(bag, TRUTH_GYRO_BIAS.name)
    bias_true = None
    if truth is not None:
        s = bag.series[truth]
        j = nearest_index(s.stamps_ns, stamps_ns)
        bias_true = np.full((T, 3), np.nan)
        bias_true[j >= 0] = s.values[j[j >= 0], :3]
        bias_true = bias_true[:, None]
    no_figures = ~np.all(np.isfinite(at(est.gyro_bias_rad_s)), axis=-1)  # the filter's figures (its estimate may be withheld)
    used = np.all(np.isfinite(at(est.q_BN)), axis=-1)

    def figure(label: str) -> Array | None:  # a diagnostics column where the filter had figures (None: an older bag)
        return None if label not in est.diagnostics else np.where(no_figures, np.nan, at(est.diagnostics[label]))

    return EstimateHistory(q_BN=at(est.q_BN), omega_BN_B=at(est.omega_BN_B), gyro_bias=at(est.gyro_bias_rad_s),
                           covariance=at(est.covariance), nis=np.where(no_figures, np.nan, nis),
                           status=np.nan_to_num(status, nan=float(ESTIMATOR_NO_INPUT)).astype(np.int8), gyro_bias_true=bias_true,
                           monitor_level=figure("monitor_level"), monitor_nis_sum=figure("monitor_nis_sum"),
                           usable=np.where(no_figures, np.nan, used.astype(np.float64)), recoveries=figure("recoveries"))


def _wheel_records(bag: Bag, stamps_ns: NDArray[np.int64]) -> dict[str, Any]:
    """``wheel_speed_rad_s`` and ``wheel_torque_Nm`` (T, 1, W) from ``joint_states`` at the state
    stamps (the message of the same stamp, else the latest before it: NaN before the first);
    nothing when the bag has no wheels."""
    topic = find_topic(bag, WHEEL_STATES.name)
    if topic is None or bag.series[topic].values.shape[1] < 2:
        return {}
    s = bag.series[topic]
    w = s.values.shape[1] // 2
    i = latest_index(s.stamps_ns, stamps_ns)
    v = np.where((i >= 0)[:, None], s.values[np.maximum(i, 0)], np.nan)
    return {"wheel_speed_rad_s": v[:, None, :w], "wheel_torque_Nm": v[:, None, w : 2 * w]}


def _orbit_record(bag: Bag, stamps_ns: NDArray[np.int64]) -> Array | None:
    """The orbit's record (T, 1, 9 + M) at the state stamps, as the offline loop records it
    (:attr:`~sappc.evaluation.history.History.orbit`): ``truth/magnetic_field`` (without a
    magnetometer the field is read exactly: ``state/magnetic_field``), ``state/magnetic_field``, NaN
    for the environment's torque (not published), the rods' commands of ``control/dipole`` when a
    management node published them; each the message of the same stamp (NaN where there is none);
    ``None`` when the bag has no ``state/magnetic_field`` (no orbit)."""
    measured = find_topic(bag, STATE_MAGNETIC_FIELD.name)
    if measured is None:
        return None
    T = stamps_ns.size

    def at(topic: str, first: int, width: int) -> Array:
        s = bag.series[topic]
        i = nearest_index(s.stamps_ns, stamps_ns)
        out = np.full((T, width), np.nan)
        out[i >= 0] = s.values[i[i >= 0], first : first + width]
        return out

    truth = find_topic(bag, TRUTH_MAGNETIC_FIELD.name) or measured
    dipole = find_topic(bag, CONTROL_DIPOLE.name)
    rods = [] if dipole is None else [at(dipole, 1, bag.series[dipole].values.shape[1] - 1)]  # data[0] is the time
    return np.concatenate([at(truth, 0, 3), at(measured, 0, 3), np.full((T, 3), np.nan), *rods], axis=1)[:, None]


@dataclass
class BagEstimate:
    """An estimator's topics in a bag, on the stamps of ``estimate/attitude`` (see :func:`bag_estimate`).

    Every array has one row per stamp; a row of NaN is a "no data" sample (the filter had no
    estimate at that stamp), or a topic's message missing at that stamp.
    """

    stamps_ns: NDArray[np.int64]  # (T,) header stamps of estimate/attitude [ns]
    q_BN: Array  # (T, 4) estimated attitude (x, y, z, w)
    omega_BN_B: Array  # (T, 3) estimated body rate [rad/s]
    gyro_bias_rad_s: Array  # (T, 3) estimated gyro bias [rad/s]
    attitude_sigma_rad: Array  # (T, 3) 1-sigma attitude error per body axis [rad]
    bias_sigma_rad_s: Array  # (T, 3) 1-sigma bias error per axis [rad/s]
    covariance: Array  # (T, 6, 6) P of contract.ERROR_STATE
    diagnostics: dict[str, Array]  # label of contract.ESTIMATOR_DIAGNOSTICS_LAYOUT -> (T,)


def bag_estimate(bag: Bag) -> BagEstimate | None:
    """The estimator's topics of ``bag`` as arrays, each topic's message of the same stamp as
    ``estimate/attitude`` (``None`` when the bag has no ``estimate/attitude``: a run without an
    estimator)."""
    att = find_topic(bag, ESTIMATE_ATTITUDE.name)
    if att is None:
        return None
    stamps = bag.series[att].stamps_ns
    T = stamps.size

    def at_stamps(name: str, width: int, first: int = 0) -> Array:
        topic = find_topic(bag, name)
        out = np.full((T, width), np.nan)
        if topic is None or bag.series[topic].values.shape[1] < first + width:
            return out
        s = bag.series[topic]
        i = nearest_index(s.stamps_ns, stamps)  # the same stamp (float-second times: within STAMP_TOL_NS)
        out[i >= 0] = s.values[i[i >= 0], first : first + width]
        return out

    n = len(ERROR_STATE)
    diag_topic = find_topic(bag, ESTIMATOR_DIAGNOSTICS.name)
    labels = bag.array_labels.get(diag_topic, ()) if diag_topic else ()
    diag = at_stamps(ESTIMATOR_DIAGNOSTICS.name, len(labels)) if labels else np.zeros((T, 0))
    return BagEstimate(
        stamps_ns=stamps,
        q_BN=bag.series[att].values[:, :4],
        omega_BN_B=at_stamps(ESTIMATE_RATE.name, 3),
        gyro_bias_rad_s=at_stamps(ESTIMATOR_GYRO_BIAS.name, 3),
        attitude_sigma_rad=at_stamps(ESTIMATOR_ATTITUDE_SIGMA.name, 3),
        bias_sigma_rad_s=at_stamps(ESTIMATOR_BIAS_SIGMA.name, 3),
        covariance=at_stamps(ESTIMATOR_COVARIANCE.name, n * n, first=1).reshape(T, n, n),  # data[0] is the time
        diagnostics={label: diag[:, k] for k, label in enumerate(labels)},
    )


def bag_metrics(bag: Bag, *, steady_from_s: float, settle_threshold: float, t2_s: float, fault_windows: list[tuple[float, float]],
                run: BagRun | None = None, orbit_bins: Any = None, ticker: Ticker | None = None,
                origin: str = "first_track") -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The metrics of :mod:`sappc.evaluation.metrics` for the run in ``bag`` (``run``: its alignment,
    if made already), and its per-orbit metrics (``orbit_bins``: a scenario in orbit's,
    :meth:`sappc.scenario.Scenario.orbit_bins`; none without).  ``origin``: with flight modes (a bag
    with ``mode/status``), where the tracking metrics count from (the scenario's ``metrics.origin``).
    ``ticker``: the computation is its step "computing the metrics"."""
    run = run or bag_run(bag, ticker=ticker)
    if ticker is not None:
        ticker.step("computing the metrics")
    acc = MetricsAccumulator(run.history.t, 1, steady_from_s=steady_from_s, settle_threshold=settle_threshold, t2_s=t2_s,
                             fault_windows=fault_windows, orbit_bins=orbit_bins, origin=origin)
    acc.add_history(run.history)
    metrics = acc.run_metrics(0)
    if not run.has_diagnostics:  # no rho, band or saturation flags: these are unknown, not zero
        for key in _NEED_DIAGNOSTICS:
            metrics[key] = None
    return metrics, acc.orbit_metrics(0)


#: Metrics that need ``controller/diagnostics``.
_NEED_DIAGNOSTICS = ("rpf_error_at_t2", "saturation_fraction", "time_outside_constraint_s", "returned_to_constraint",
                     "left_constraint_after_fault", "returned_at_s")

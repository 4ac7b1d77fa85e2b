"""The recorder (``python -m sappc.graph.recorder``): every topic of a run, raw CDR, into an MCAP bag.

The bag is a rosbag2 version 9 directory (``output_dir``): ``<name>_0.mcap`` (profile ``ros2``,
``ros2msg`` schemas with their full dependency text, channels carrying ``offered_qos_profiles``
and ``topic_type_hash`` as rosbag2 writes them) and ``metadata.yaml``, plus copies of the files
listed in ``metadata_files`` (the scenario and parameters of the run), which are also stored in
the MCAP file as metadata records named ``sappc/<file name>``.

Two threads, as rosbag2's recorder has: the executor's thread only *takes* each message (its raw
CDR bytes, and in real time the wall time it was taken) and hands it to a queue; a writer thread
does everything else (the stamp, the counts, the MCAP record, compression, the flush every
:data:`FLUSH_PERIOD_S`), in passes every :data:`WRITE_PASS_PERIOD_S` (not woken per message).
The records are built by :mod:`sappc.bag.mcap_write` (about a microsecond of Python a message;
the ``mcap`` package's writer spent several, holding the interpreter lock the executor's thread
waits for: 0.3 s of a 2.3 s composed loop, issue 48).  The middleware's queues are so emptied at the pace messages arrive,
whatever compressing a chunk costs: a recorder that fell behind used to leave the samples in the
publishers' histories, which overflowed when it was late enough (issue 25).

Reliability: each subscription is RELIABLE with KEEP_ALL history, so Fast DDS acknowledges a
sample once it is in the recorder's queue, independently of how fast Python writes it; the
project's publishers wait for every acknowledgement before they exit
(:meth:`~sappc_msgs_py.runtime.ProjectNode.finish`).  On SIGINT or SIGTERM the recorder drains
its queues until they stay empty for :data:`DRAIN_QUIET_S`, lets the writer thread write what
it was handed, then finalises the file (summary, index) and ``metadata.yaml``.  The MCAP file is
flushed every :data:`FLUSH_PERIOD_S`: after a SIGKILL every flushed chunk is still readable
(``metadata.yaml`` is written at start with the topics and rewritten with the counts at the end).

Start (parameter ``expected_publishers``, set by ``sappc run`` for a lockstep run of its own
plant): the recorder subscribes to ``/clock`` only once each listed topic's subscription has
matched that many publishers, on the recorder's side of the match.  The plant starts the run only
once its ``/clock`` subscribers are matched, so the run starts when the recorder is matched with
every publisher, not a wall-clock while later: a publisher matched with the recorder on its own
side only (which lets it publish) no longer relies on its history to keep what it sends before
the recorder's side completes.

Time (parameter ``mode``):

``lockstep`` (default)
    The bag is on simulated time, as ``ros2 bag record --use-sim-time`` records it: a message's
    ``log_time`` and ``publish_time`` are the time it belongs to, its own stamp
    (:func:`~sappc_msgs_py.convert.cdr_stamp_ns`: the header stamp, ``/clock``'s clock, the
    diagnostics' ``time_s``), so Foxglove's timeline, seeking and 1x playback follow the
    experiment.  While recording, messages are written as they arrive; when the bag is closed
    the file is rewritten in the order of (stamp, topic, arrival on the topic)
    (:func:`~sappc.bag.rosbag2.sort_by_log_time`), so it does not depend on how the middleware
    interleaved the topics (under load the recorder takes one topic's queue up to 2 s of stamps
    behind another's): the same run gives the same bag, byte for byte, whether its nodes ran in
    five processes or one (``sappc run --compose``).  A bag whose recorder was killed is in
    arrival order (readers that follow ``log_time`` are not affected).
``realtime``
    The bag is on wall time: ``log_time`` is when the message was taken from the queue, in that
    order.

The end of a run driven by a plant the recorder does not know (``sappc run --plant external``):
with ``end_after_s`` > 0, once it has recorded a ``control/torque`` stamped ``end_after_s`` or more
after the first one (lockstep: the torque of the scenario's last sample), the recorder writes
``end_file`` (and goes on recording until it is stopped, so what is published after it, the last
sample's diagnostics included, is still recorded).

Parameters: :data:`PARAMETERS` (``python -m sappc.graph.recorder --help``), and those of
:class:`~sappc_msgs_py.runtime.ProjectNode` (``counts_file`` receives the messages recorded per topic).
"""

from __future__ import annotations

import json
import queue
import resource
import shutil
import sys
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import yaml
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sappc_msgs_py.contract import (
    CLOCK,
    CONTROL_TORQUE,
    FAULT_TOPICS,
    STATE_ATTITUDE,
    TOPICS,
)
from sappc.bag.mcap_write import ChunkBuilder, McapWriter
from sappc.bag.rosbag2 import bag_metadata, offered_qos_v9, sort_by_log_time, write_bag_metadata
from sappc_msgs_py.convert import cdr_stamp_ns
from sappc_msgs_py.parameters import REQUIRED, Param
from sappc_msgs_py.runtime import LOCKSTEP, MODE, ProjectNode, parse_expected, run_node
from sappc_msgs_py.schemas import schema_text, type_hash
from gnc_common.validation import ConfigError, check_positive

__all__ = ["DEFAULT_TOPICS", "RecorderNode", "main"]

#: Quiet time that ends the drain after a signal [s]: every publisher's samples are already in the
#: local KEEP_ALL queues by then (publishers wait for acknowledgements), so this only bounds how
#: long an empty pass of the executor may take.
DRAIN_QUIET_S = 0.3
#: Longest drain [s], in case a publisher keeps publishing after the signal.
DRAIN_MAX_S = 10.0
#: Period of the MCAP flush [s]: what a SIGKILL can lose (with the messages still in the queues);
#: half the documented 1 s bound (docs/recorder.md), so that a recorder lagging by a few hundred ms still meets it.
FLUSH_PERIOD_S = 0.5
#: Period of the writer thread's passes [s]: it writes everything handed over, then waits this long
#: before the next pass.  Woken for each message instead (11,000 a second in a lockstep run), it
#: cost a thread switch and a hand-over of the interpreter lock per message, which the executor's
#: thread waited for: 2.5 s of a 6 s composed run.  The hand-over queue then holds a few hundred
#: messages at most (a pass's 20 ms is ~220 of them; 578 seen in a composed run of experiment 1,
#: ~100 kB), written well inside the flush period.
WRITE_PASS_PERIOD_S = 0.02
#: The ``library`` field of the bags the recorder writes.
RECORDER_LIBRARY = "sappc recorder (sappc.bag.mcap_write)"
#: MCAP chunk size [bytes]: about 1.5 s of a 100 Hz run; compression per chunk (zstd).
CHUNK_SIZE = 256 * 1024

#: Every topic of the contract and of the fault relays.
#: Tolerance of the end check [ns]: a grid time in float seconds and its nanosecond stamp differ
#: by less than 1 ns (rounding), and 1 us is far below any control period.
END_TOLERANCE_NS = 1000
DEFAULT_TOPICS = tuple(t.name for t in TOPICS + FAULT_TOPICS)
_KNOWN = {t.name: t for t in TOPICS + FAULT_TOPICS}

#: The recorder's parameters (``--help``), in the order the node declares them.
PARAMETERS = (
    Param("output_dir", REQUIRED, "the bag directory to create (rosbag2 v9: <name>_0.mcap and metadata.yaml)", type="string",
          check="a path that does not exist"),
    Param("topics", list(DEFAULT_TOPICS), "the topics to record (the contract's names)", check="topics of the contract"),
    Param("metadata_files", [""], "files copied into the bag directory and stored as MCAP metadata records (the run's scenario and "
          "parameters)", check="existing files ('' entries are ignored)"),
    MODE,
    Param("end_after_s", 0.0, "with an external plant: write end_file once the recorded torques span this (0: never)", "s", check=">= 0"),
    Param("end_file", "", "the file written when end_after_s is reached; '' for none"),
    Param("progress_file", "", "where the writer thread writes, at each flush, the run's progress as it records it (JSON: "
          "state_samples, the state samples recorded; t_s, the newest state's time since the first) for sappc run's progress "
          "line; '' for none"),
    Param("expected_publishers", [], "subscribe to /clock only once each listed topic has matched this many publishers on the "
          "recorder's side, as 'topic=count' entries (sappc run: the plant starts when its /clock subscribers are matched); "
          "none: /clock at once", type="string[]", check="topics the recorder records, other than /clock"),
)
_P = {p.name: p for p in PARAMETERS}


class RecorderNode(ProjectNode):
    """See the module docstring."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m sappc.graph.recorder"

    def __init__(self, node_name: str = "recorder", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        out = str(self.param(_P["output_dir"]) or "")
        if not out:
            raise ConfigError("output_dir must be set (the bag directory to create)")
        self.dir = Path(out)
        if self.dir.exists():
            raise ConfigError(f"output_dir {self.dir} already exists; a recorder never overwrites a bag")
        names = list(self.param(_P["topics"]))
        unknown = [n for n in names if n.lstrip("/") not in _KNOWN and n not in _KNOWN]
        if unknown:
            raise ConfigError(f"topics: {unknown[0]!r} is not a topic of the contract; known: {sorted(_KNOWN)}")
        recorded = [_KNOWN.get(n.lstrip("/")) or _KNOWN[n] for n in names]  # known: checked above
        names_recorded = {t.name for t in recorded}
        self._expected = parse_expected(list(self.param(_P["expected_publishers"])), "expected_publishers")
        wrong = [t for t in self._expected if t == CLOCK.name or t not in names_recorded]
        if wrong:
            raise ConfigError(f"expected_publishers: {wrong[0]!r} must be a recorded topic other than {CLOCK.name} "
                              f"(recorded: {sorted(names_recorded)})")
        files = [Path(f) for f in (self.param(_P["metadata_files"]) or []) if f]
        for f in files:
            if not f.is_file():
                raise ConfigError(f"metadata_files: {f} is not a file")

        self.dir.mkdir(parents=True)
        self.mcap_name = f"{self.dir.name}_0.mcap"
        self._file = open(self.dir / self.mcap_name, "wb")  # noqa: SIM115 (closed in finish)
        self._mcap = McapWriter(self._file, RECORDER_LIBRARY)
        self.writer = ChunkBuilder(self._mcap, CHUNK_SIZE)  # the messages, a chunk at a time
        self.custom: dict[str, str] = {}
        for f in files:
            shutil.copyfile(f, self.dir / f.name)
            self._mcap.metadata(f"sappc/{f.name}", {"text": f.read_text()})
            self.custom[f"sappc/{f.name}"] = f.name

        self._qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_ALL)
        schemas: dict[str, int] = {}
        self.topics: list[tuple[str, str]] = []
        self.counts: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._recorded_subs: dict[str, Any] = {}
        qos_text = yaml.safe_dump(offered_qos_v9(), sort_keys=False)
        for topic in recorded:  # every channel now, in the topics' order: the bag does not depend on when /clock is subscribed
            if topic.type_name not in schemas:
                schemas[topic.type_name] = self._mcap.schema(topic.type_name, "ros2msg", schema_text(topic.type_name).encode())
            if topic is CLOCK and self._expected:
                resolved = self.resolve_topic_name(topic.name)  # subscribed once the others are matched (module docstring)
            else:
                self._subscribe(topic)
                resolved = str(self._recorded_subs[topic.name].topic_name)
            self._channels[topic.name] = self._mcap.channel(
                resolved, "cdr", schemas[topic.type_name], {"offered_qos_profiles": qos_text, "topic_type_hash": type_hash(topic.type_name)}
            )
            self.topics.append((resolved, topic.type_name))
            self.counts[resolved] = 0
        self._resolved = {topic.name: r for topic, (r, _) in zip(recorded, self.topics)}
        self._types = {topic.name: topic.type_name for topic in recorded}
        self.start_ns: int | None = None
        self.end_ns = 0
        self._last_message = time.monotonic()
        self.sim_time = self.mode_param() == LOCKSTEP
        self._end_after_ns = int(round(check_positive("end_after_s", self.param(_P["end_after_s"]), allow_zero=True) * 1e9))
        self._end_file = str(self.param(_P["end_file"]))
        self._first_torque_ns: int | None = None
        self.end_reached = False
        self._progress_file = str(self.param(_P["progress_file"]))
        self._states = 0  # state samples written
        self._first_state_ns: int | None = None  # the first state's stamp and the newest one's [ns]
        self._newest_state_ns = 0
        self._write_metadata()
        self._file.flush()
        if self._expected and CLOCK.name in names_recorded:
            self.start_when(self._publishers_missing, lambda: self._subscribe(CLOCK))
        # the hand-over from the taking thread (the executor's) to the writer thread: (topic, raw CDR, wall time taken [ns])
        self._handover: queue.SimpleQueue[tuple[str, bytes, int] | None] = queue.SimpleQueue()
        self._writer_error: BaseException | None = None
        self.max_backlog = 0  # the most messages taken but not yet written, seen by the writer thread
        self._writer_thread = threading.Thread(target=self._write_loop, name="recorder-writer", daemon=True)
        self._writer_thread.start()
        self.get_logger().info(f"recording {len(self.topics)} topics into {self.dir} on {'simulated' if self.sim_time else 'wall'} time")

    def _subscribe(self, topic: Any) -> None:
        self._recorded_subs[topic.name] = self.create_subscription(topic.msg_class, topic.name, partial(self._on_message, topic.name),
                                                                   self._qos, raw=True)

    def _publishers_missing(self) -> list[str]:
        """The ``expected_publishers`` not yet matched on the recorder's side, in words (empty: subscribe to /clock)."""
        return [f"{n - self._recorded_subs[t].get_publisher_count()} publisher(s) of {t}" for t, n in self._expected.items()
                if self._recorded_subs[t].get_publisher_count() < n]

    def _on_message(self, name: str, data: bytes) -> None:
        """The executor's thread: take the message and hand it to the writer thread, nothing more."""
        self._last_message = time.monotonic()
        self._handover.put((name, data, 0 if self.sim_time else time.time_ns()))

    def _write_loop(self) -> None:
        """The writer thread: write what is handed over, in passes every :data:`WRITE_PASS_PERIOD_S`
        (each pass everything handed over by then, :meth:`_write_batch`), flush every
        :data:`FLUSH_PERIOD_S`, until ``None``."""
        try:
            next_flush = time.monotonic() + FLUSH_PERIOD_S
            get, get_nowait = self._handover.get, self._handover.get_nowait
            while True:
                try:
                    batch = [get(timeout=max(0.0, next_flush - time.monotonic()))]
                except queue.Empty:
                    pass  # no message before the next flush
                else:
                    try:
                        while batch[-1] is not None:  # the pass: everything handed over by now
                            batch.append(get_nowait())
                    except queue.Empty:
                        pass
                    done = batch[-1] is None
                    messages = [m for m in batch if m is not None]  # (None only last: the end)
                    self.max_backlog = max(self.max_backlog, len(messages))
                    self._write_batch(messages)
                    if done:
                        return
                if time.monotonic() >= next_flush:
                    self.writer.flush()
                    self._write_progress()
                    next_flush = time.monotonic() + FLUSH_PERIOD_S
                time.sleep(WRITE_PASS_PERIOD_S)
        except BaseException as exc:  # noqa: BLE001 (reported by finish, and logged now)
            self._writer_error = exc
            self.get_logger().error(f"the bag writer stopped: {type(exc).__name__}: {exc}")

    def _write_batch(self, batch: list[tuple[str, bytes, int]]) -> None:
        """Write a pass's messages, in the order taken: each one's log time (its stamp on simulated
        time, the wall time it was taken otherwise), count, record; the end check on the torque and
        the progress on the states.  One loop over the pass with its lookups local (a message costs
        about a microsecond of the interpreter lock the executor's thread waits for)."""
        sim, types, resolved, counts, channels = self.sim_time, self._types, self._resolved, self.counts, self._channels
        records = []
        start, end = self.start_ns, self.end_ns
        torque_name, state_name = CONTROL_TORQUE.name, STATE_ATTITUDE.name
        for name, data, taken_ns in batch:
            log_ns = cdr_stamp_ns(types[name], data) if sim else taken_ns
            if start is None or log_ns < start:
                start = log_ns
            if log_ns > end:
                end = log_ns
            r = resolved[name]
            n = counts[r] = counts[r] + 1
            records.append((channels[name], n, log_ns, log_ns, data))
            if name == torque_name and self._end_after_ns and not self.end_reached:
                self._check_end(log_ns if sim else cdr_stamp_ns(types[name], data))
            elif name == state_name:  # the run's progress: the plant's samples
                stamp_ns = log_ns if sim else cdr_stamp_ns(types[name], data)
                self._states += 1
                if self._first_state_ns is None:
                    self._first_state_ns = stamp_ns
                self._newest_state_ns = max(self._newest_state_ns, stamp_ns)
        self.start_ns, self.end_ns = start, end
        self.writer.add_messages(records)

    def _write_progress(self) -> None:
        """The run's progress, for ``sappc run``'s progress line (``progress_file``; replaced whole)."""
        if not self._progress_file or self._first_state_ns is None:
            return
        path = Path(self._progress_file)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"state_samples": self._states, "t_s": (self._newest_state_ns - self._first_state_ns) / 1e9}))
        tmp.replace(path)

    def _check_end(self, torque_ns: int) -> None:
        """``end_file`` once the recorded torques span ``end_after_s`` (module docstring)."""
        if self._first_torque_ns is None:
            self._first_torque_ns = torque_ns
        if torque_ns - self._first_torque_ns >= self._end_after_ns - END_TOLERANCE_NS:
            self.end_reached = True
            if self._end_file:
                Path(self._end_file).write_text(f"{torque_ns}\n")
            self.get_logger().info(f"the torque of t = {torque_ns / 1e9:.3f} s is recorded: the run has reached end_after_s")

    def _write_metadata(self) -> None:
        write_bag_metadata(self.dir, bag_metadata(self.mcap_name, self.topics, self.counts, self.start_ns or 0, self.end_ns, self.custom))

    def drain(self, spin_once: Any) -> None:
        """Take every queued message until the queues stay empty for :data:`DRAIN_QUIET_S`."""
        start = time.monotonic()
        self._last_message = start
        while time.monotonic() - self._last_message < DRAIN_QUIET_S and time.monotonic() - start < DRAIN_MAX_S:
            spin_once(DRAIN_QUIET_S / 3)

    def publish_counts(self) -> dict[str, int]:
        return dict(self.counts)

    def finish(self) -> None:
        self._handover.put(None)  # after every message taken: the writer thread writes them all, then stops
        self._writer_thread.join()
        if self._writer_error is not None:
            raise RuntimeError(f"{self.dir}: the bag writer failed: {self._writer_error}") from self._writer_error
        meta = bag_metadata(self.mcap_name, self.topics, self.counts, self.start_ns or 0, self.end_ns, self.custom)
        self.writer.flush()
        self._mcap.metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(meta["rosbag2_bagfile_information"], sort_keys=False)})
        self._mcap.finish()
        self._file.close()
        if self.sim_time:  # the file in time order, whatever order the middleware delivered the topics in
            sort_by_log_time(self.dir / self.mcap_name, chunk_size=CHUNK_SIZE, library=RECORDER_LIBRARY)
        self._write_metadata()
        peak_mib = _peak_rss_mib()
        self.get_logger().info(f"bag {self.dir} closed: {sum(self.counts.values())} messages; the writer thread was at most "
                               f"{self.max_backlog} messages behind; peak memory {peak_mib:.1f} MiB")
        super().finish()


def _peak_rss_mib() -> float:
    """The most resident memory this process has had [MiB]: the kernel's ``VmHWM`` of its own image.

    Not ``getrusage``'s ``ru_maxrss``: Linux carries it across ``execve``, so a node started by
    ``sappc run`` (a fork of the launcher, numba and scipy loaded, then exec) would report the
    launcher's 190 MiB.  ``ru_maxrss`` only where ``/proc`` is missing.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def main(argv: list[str] | None = None) -> int:
    """Record until SIGINT or SIGTERM, then finalise the bag."""
    return run_node(lambda args: RecorderNode(), argv, RecorderNode)


if __name__ == "__main__":
    sys.exit(main())

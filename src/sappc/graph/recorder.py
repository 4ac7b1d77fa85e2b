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

Live view (``sappc run --live``, parameter ``live_port`` >= 0): the recorder also serves every
recorded topic to Foxglove through a :class:`~sappc.bag.live.LiveServer` (on ``live_host``,
127.0.0.1 unless told otherwise: the view is unauthenticated): the writer thread hands each message
it writes to the server as the same bytes, on a channel with the bag's topic and ``ros2msg``
schema, stamped with its log time.  :meth:`LiveServer.log <sappc.bag.live.LiveServer.log>` never
blocks (the SDK queues :data:`~sappc.bag.live.MESSAGE_BACKLOG` messages per client and drops the
oldest), so a viewer costs neither the bag nor lockstep anything but the hand-over.  At each flush
the run's progress goes to the view: Foxglove status messages, and a JSON message on
:data:`RUN_TOPIC` (``{"phase": "running", "t_s", "state_samples", "messages"}``), with the server's
time set to the newest log time.  When the bag is closed: ``"phase": "closed"``; then, with
``live_verdict_file``, the recorder writes ``<live_verdict_file>.wait`` and waits (at most
``live_verdict_wait_s``) for ``sappc run`` to write the run's verdict there and shows it (``"phase": "verdict"``, ``"failed"``, ``"text"``), and
stops the server before it exits.  With ``live_wait_subscribers`` (lockstep, with
``expected_publishers``), the recorder also waits until every recorded topic has that many
live-view subscriptions before it subscribes to ``/clock``, so the run starts once a viewer
is there.  The address is written to ``live_file`` as JSON (``{"url"}``).

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
from sappc_msgs_py.runtime import LOCKSTEP, MODE, ProjectNode, parse_expected, run_node, write_json_whole
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
#: The live view's own channel (``--live``): the run's progress and verdict as JSON.
RUN_TOPIC = "/sappc/run"
#: Its JSON schema (Foxglove's Raw Messages and Plot panels read its fields).
RUN_SCHEMA = json.dumps({"title": "sappc run status", "type": "object", "properties": {
    "phase": {"type": "string", "enum": ["running", "closed", "verdict"]},
    "t_s": {"type": "number"}, "state_samples": {"type": "integer"}, "messages": {"type": "integer"},
    "failed": {"type": "boolean"}, "text": {"type": "string"}}}).encode()
#: The live view's channel id of :data:`RUN_TOPIC` (the bag's channels have theirs, from 1).
_RUN_CHANNEL_ID = -1
#: Longest wait for a client to receive what is queued before the live server stops [s] (only
#: while a client subscribes).
LIVE_LINGER_S = 1.0
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
    Param("live_port", -1, "serve every recorded topic to Foxglove on a Foxglove WebSocket at this port (0: any free port; -1: no "
          "live view)", check="-1 to 65535"),
    Param("live_host", "127.0.0.1", "the address the live view listens on (the view is unauthenticated)"),
    Param("live_file", "", "where the live view's address is written (JSON: url); '' for none"),
    Param("live_verdict_file", "", "after closing the bag, wait for this file (the run's verdict, JSON: failed, text) and show it "
          "in the live view; '' for none"),
    Param("live_wait_subscribers", 0, "lockstep with expected_publishers: subscribe to /clock (which starts the run) only once every "
          "recorded topic has this many live-view subscriptions (sappc run --live --wait-subscribers)", check=">= 0"),
    Param("live_verdict_wait_s", 120.0, "the longest wait for live_verdict_file", "s", check="> 0"),
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
        self.live: Any = None  # the LiveServer of --live
        self._live_messages = 0
        live_port = int(self.param(_P["live_port"]))
        self._live_verdict_file = str(self.param(_P["live_verdict_file"]))
        self._live_verdict_wait_s = check_positive("live_verdict_wait_s", self.param(_P["live_verdict_wait_s"]))
        live_host, live_file = str(self.param(_P["live_host"])), str(self.param(_P["live_file"]))  # declared either way (the help lists them)
        if live_port >= 0:
            self._start_live(live_port, live_host, live_file, recorded, schemas)
        self._live_wait = int(self.param(_P["live_wait_subscribers"]))
        if self._live_wait < 0:
            raise ConfigError(f"live_wait_subscribers must be >= 0, got {self._live_wait}")
        if self._live_wait and (self.live is None or not (self._expected and CLOCK.name in names_recorded)):
            raise ConfigError("live_wait_subscribers is for a live view (live_port >= 0) of a lockstep run with expected_publishers")
        if self._expected and CLOCK.name in names_recorded:
            self.start_when(lambda: self._publishers_missing() + self._live_missing(), lambda: self._subscribe(CLOCK))
        # the hand-over from the taking thread (the executor's) to the writer thread: (topic, raw CDR, wall time taken [ns])
        self._handover: queue.SimpleQueue[tuple[str, bytes, int] | None] = queue.SimpleQueue()
        self._writer_error: BaseException | None = None
        self.max_backlog = 0  # the most messages taken but not yet written, seen by the writer thread
        self._writer_thread = threading.Thread(target=self._write_loop, name="recorder-writer", daemon=True)
        self._writer_thread.start()
        self.get_logger().info(f"recording {len(self.topics)} topics into {self.dir} on {'simulated' if self.sim_time else 'wall'} time")

    def _start_live(self, port: int, host: str, live_file: str, recorded: list[Any], schemas: dict[str, int]) -> None:
        """The live view (module docstring): a channel per recorded topic as the bag has it, and :data:`RUN_TOPIC`."""
        from sappc.bag.live import LiveServer
        from sappc.bag.mcap_scan import Channel

        channels = [Channel(self._channels[t.name], resolved, t.type_name, "ros2msg", "cdr", schema_text(t.type_name).encode())
                    for t, (resolved, _) in zip(recorded, self.topics)]
        channels.append(Channel(_RUN_CHANNEL_ID, RUN_TOPIC, "sappc.RunStatus", "jsonschema", "json", RUN_SCHEMA))
        self.live = LiveServer(channels, host=host, port=port, name="sappc run")
        if live_file:
            write_json_whole(live_file, {"url": self.live.url, "port": self.live.port, "host": host})
        self.get_logger().info(f"live view at {self.live.url}")

    def _live_missing(self) -> list[str]:
        """The live-view subscriptions ``live_wait_subscribers`` still waits for, in words."""
        if not self._live_wait:
            return []
        short = [t for (t, _), cid in zip(self.topics, self._channels.values()) if self.live.subscriptions(cid) < self._live_wait]
        return [f"{self._live_wait} live-view subscription(s) of {len(short)} topic(s), {short[0]} first"] if short else []

    def _live_run(self, phase: str, **fields: Any) -> None:
        """A message on :data:`RUN_TOPIC`, stamped with the newest log time."""
        body = {"phase": phase, "t_s": self._t_s(), "state_samples": self._states, "messages": sum(self.counts.values()), **fields}
        self.live.log(_RUN_CHANNEL_ID, json.dumps(body).encode(), self.end_ns)

    def _t_s(self) -> float:
        return 0.0 if self._first_state_ns is None else (self._newest_state_ns - self._first_state_ns) / 1e9

    def _live_progress(self) -> None:
        """The run's progress to the live view (each flush)."""
        if self.live is None or self._first_state_ns is None:
            return
        self.live.broadcast_time(self.end_ns)
        self.live.status(f"sappc run: t = {self._t_s():.1f} s, {self._states} samples recorded")
        self._live_run("running")

    def _live_end(self) -> None:
        """The bag closed, then the run's verdict (``live_verdict_file``), then the server stopped."""
        live = self.live
        if live is None:
            return
        try:
            live.broadcast_time(self.end_ns)
            live.status(f"sappc run: bag closed, {sum(self.counts.values())} messages recorded")
            self._live_run("closed")
            if self._live_verdict_file:
                path = Path(self._live_verdict_file)
                Path(f"{path}.wait").write_text("")  # sappc run: the bag is closed, the verdict is due
                end = time.monotonic() + self._live_verdict_wait_s
                while not path.exists() and time.monotonic() < end:
                    time.sleep(0.05)
                try:
                    verdict = json.loads(path.read_text())
                except (OSError, ValueError):
                    verdict = {"failed": True, "text": "no verdict came from sappc run"}
                failed, text = bool(verdict.get("failed")), str(verdict.get("text", ""))
                live.status(f"sappc run: {text}", level="warning" if failed else "info")
                self._live_run("verdict", failed=failed, text=text)
            end = time.monotonic() + LIVE_LINGER_S  # queued messages reach a subscribed client
            while live.any_subscription() and time.monotonic() < end:
                time.sleep(0.05)
        finally:
            live.close()

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
                    if done:  # the last samples in the progress file too (sappc run's progress line and its end)
                        self._write_progress()
                        return
                if time.monotonic() >= next_flush:
                    self.writer.flush()
                    self._write_progress()
                    self._live_progress()
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
        live = self.live
        if live is not None:  # the same bytes, stamped with their log time; never blocks (module docstring)
            for cid, _, log_ns, _, data in records:
                live.log(cid, data, log_ns)

    def _write_progress(self) -> None:
        """The run's progress, for ``sappc run``'s progress line (``progress_file``; replaced whole)."""
        if not self._progress_file or self._first_state_ns is None:
            return
        write_json_whole(self._progress_file, {"state_samples": self._states, "t_s": self._t_s()})

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
        self._live_end()
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

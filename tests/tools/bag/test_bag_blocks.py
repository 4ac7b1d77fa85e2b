"""Bags read in blocks (issue 47 item 6, :mod:`sappc.bag.blocks`): the History, the answers, the
counts and the metrics of a bag read a block at a time equal those of the bag read whole
(:func:`~sappc.bag.read.read_bag`, :func:`~sappc.bag.read.bag_run`,
:func:`~sappc.bag.read.bag_metrics`) bit for bit, for blocks of every size down to one message
(a sample's messages cut anywhere); the file is walked a chunk at a time with the messages,
channels, metadata and end of :func:`~sappc.bag.mcap_scan.scan_mcap`.  Bags written by
``tests/bagmaker.py`` (the mcap package and rclpy's serializer), their topics recorded with lags
(a sample's reference before its state, its diagnostics three samples after), a topic that stops,
held torques, missing diagnostics, duplicate stamps, "no data" estimates; in lockstep and with
real-time epoch stamps."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest


from sappc.bag import blocks as bag_blocks
from sappc.bag.blocks import BagBlocks, FullHistory, concatenate_histories
from sappc.bag.mcap_scan import McapWalk, scan_mcap
from sappc.bag.read import aligned_topics, bag_metrics, bag_run, read_bag
from sappc.scenario import OrbitBins
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (covariance_msg, diagnostics_msg, dipole_msg, estimator_diagnostics_msg, joint_state_msg, magnetic_field_msg,
                                   no_data_msg, quaternion_msg, torque_msg, vector3_msg)

from bagmaker import write_bag

DT_NS = 10_000_000
#: A wall-clock epoch for the real-time bags' stamps [ns] (float seconds of it are exact to ~0.24 us).
EPOCH_NS = 1_796_530_310_000_000_000
#: How many samples after its stamp each topic is recorded (its log time): the reference ahead,
#: the diagnostics and the estimator behind; a block cuts a sample's messages anywhere.  (The
#: rods' float array after the diagnostics': read_bag takes the labels of the first float array
#: timed by ``time_s`` in channel order as the diagnostics'.)
LAG_SAMPLES = {c.REFERENCE_ATTITUDE.name: -2, c.CONTROLLER_DIAGNOSTICS.name: 3, c.ESTIMATE_ATTITUDE.name: 1, c.ESTIMATOR_COVARIANCE.name: 2,
               c.CONTROL_TORQUE.name: 1, c.WHEEL_STATES.name: 2, c.CONTROL_DIPOLE.name: 4}
#: Block sizes [messages]: one message, a few, a sample's worth, more than a sample's.
BLOCK_MESSAGES = (1, 7, 29, 500)
SETTINGS: dict[str, Any] = {"steady_from_s": 0.5, "settle_threshold": 1e-3, "t2_s": 0.8, "fault_windows": [(0.9, 1.1)]}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _flight_messages(n: int, rng: np.random.Generator, *, realtime: bool = False) -> list[tuple[str, str, object, int]]:
    """``n`` samples of a flight-like run (every topic the alignment reads), sorted by log time."""
    out: list[tuple[int, int, str, str, object]] = []
    order = {}

    def add(topic: c.Topic | str, type_name: str, msg: object, stamp_ns: int, k: int) -> None:
        name = topic if isinstance(topic, str) else topic.name
        log = stamp_ns + (LAG_SAMPLES.get(name, 0) + 10) * DT_NS + (int(rng.integers(0, 300_000)) if realtime else 0)  # log times from 0
        out.append((log, order.setdefault(name, len(order)), name, type_name, msg))

    base = EPOCH_NS if realtime else 0
    q, q_ref = _unit(rng.standard_normal(4)), _unit(rng.standard_normal(4))
    for k in range(n):
        ns = base + k * DT_NS + (int(rng.integers(-400_000, 400_000)) if realtime and k else 0)
        t = ns / 1e9
        q = _unit(q + 1e-3 * rng.standard_normal(4))
        w = 1e-2 * rng.standard_normal(3)
        for topic in (c.TRUTH_ATTITUDE, c.STATE_ATTITUDE):
            add(topic, topic.type_name, quaternion_msg(q, t, topic), ns, k)
        if k % 37 == 5:  # a second truth message of the same stamp: the latest is the sample's
            add(c.TRUTH_ATTITUDE, c.TRUTH_ATTITUDE.type_name, quaternion_msg(_unit(q + 0.01), t, c.TRUTH_ATTITUDE), ns, k)
        for topic in (c.TRUTH_RATE, c.STATE_RATE):
            add(topic, topic.type_name, vector3_msg(w, t, topic), ns, k)
        if k % 2 == 0:  # the reference at every other sample, between the state stamps: interpolated
            q_ref = _unit(q_ref + 2e-3 * rng.standard_normal(4))
            r_ns = ns + DT_NS // 2 if k else ns
            add(c.REFERENCE_ATTITUDE, c.REFERENCE_ATTITUDE.type_name, quaternion_msg(q_ref if k % 6 else -q_ref, r_ns / 1e9, c.REFERENCE_ATTITUDE), r_ns, k)
        if k % 5:  # every fifth torque missing: the plant held the last
            add(c.CONTROL_TORQUE, c.CONTROL_TORQUE.type_name, torque_msg(1e-3 * rng.standard_normal(3), t), ns, k)
        if k < n // 3:  # the disturbance stops a third of the way
            add(c.DISTURBANCE_TORQUE, c.DISTURBANCE_TORQUE.type_name, torque_msg(1e-4 * rng.standard_normal(3), t, c.DISTURBANCE_TORQUE), ns, k)
        if k % 7 != 3:  # every seventh sample without its diagnostics: held, no answer
            rows = {label: 1e-3 * rng.standard_normal(3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
            rows["status"] = np.array([float(k // 50), float(k % 11 == 0), float(k % 4)])
            rows["saturated"] = (rng.random(3) > 0.8).astype(float)
            add(c.CONTROLLER_DIAGNOSTICS, c.CONTROLLER_DIAGNOSTICS.type_name, diagnostics_msg(t, rows), ns, k)
        add(c.WHEEL_STATES, c.WHEEL_STATES.type_name, joint_state_msg(rng.standard_normal(4), 1e-3 * rng.standard_normal(4), t), ns, k)
        add(c.TRUTH_GYRO_BIAS, c.TRUTH_GYRO_BIAS.type_name, vector3_msg(1e-5 * rng.standard_normal(3), t, c.TRUTH_GYRO_BIAS), ns, k)
        if k % 11 == 4:  # the filter's "no data"
            for topic in c.ESTIMATOR_TOPICS[:5]:
                add(topic, topic.type_name, no_data_msg(topic, t), ns, k)
            P = None
        else:
            add(c.ESTIMATE_ATTITUDE, c.ESTIMATE_ATTITUDE.type_name, quaternion_msg(_unit(q + 1e-4 * rng.standard_normal(4)), t, c.ESTIMATE_ATTITUDE), ns, k)
            for topic in c.ESTIMATOR_TOPICS[1:5]:
                add(topic, topic.type_name, vector3_msg(1e-4 * rng.standard_normal(3), t, topic), ns, k)
            A = 1e-3 * rng.standard_normal((6, 6))
            P = A @ A.T + 1e-9 * np.eye(6)
        add(c.ESTIMATOR_COVARIANCE, c.ESTIMATOR_COVARIANCE.type_name, covariance_msg(t, P), ns, k)
        diag = [t, 1.0, float(k % 4), k % 3, 0.0, 0.0, 0.0, 0.0, 0.0, 60.0 + k, 0.0, float(k % 9 == 0)]
        add(c.ESTIMATOR_DIAGNOSTICS, c.ESTIMATOR_DIAGNOSTICS.type_name, estimator_diagnostics_msg(diag), ns, k)
        B = 3e-5 * rng.standard_normal(3)
        add(c.TRUTH_MAGNETIC_FIELD, c.TRUTH_MAGNETIC_FIELD.type_name, magnetic_field_msg(B, t, c.TRUTH_MAGNETIC_FIELD), ns, k)
        if k % 10 == 0:  # the magnetometer at 10 Hz
            add(c.STATE_MAGNETIC_FIELD, c.STATE_MAGNETIC_FIELD.type_name, magnetic_field_msg(B + 1e-7, t, c.STATE_MAGNETIC_FIELD), ns, k)
        add(c.CONTROL_DIPOLE, c.CONTROL_DIPOLE.type_name, dipole_msg(t, 100.0 * rng.standard_normal(3)), ns, k)
    out.sort(key=lambda m: (m[0], m[1]))
    return [(name, type_name, msg, log) for log, _, name, type_name, msg in out]


@pytest.fixture(scope="module")
def flight_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A lockstep and a real-time flight bag of 240 samples each (about 4800 messages)."""
    d = tmp_path_factory.mktemp("blocks")
    return {kind: write_bag(d / f"{kind}.mcap", _flight_messages(240, np.random.default_rng(11 + i), realtime=kind == "realtime"), chunk_size=8192)
            for i, kind in enumerate(("lockstep", "realtime"))}


def _arrays(record: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in dataclasses.fields(record):
        v = getattr(record, f.name)
        if dataclasses.is_dataclass(v):
            out.update(_arrays(v, f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = v
    return out


def _assert_same_bits(a: Any, b: Any) -> None:
    """Two Histories (or arrays) equal bit for bit: the same fields, shapes, dtypes and bytes (NaN included)."""
    fa, fb = _arrays(a), _arrays(b)
    assert fa.keys() == fb.keys()
    for key in fa:
        x, y = fa[key], fb[key]
        if x is None or y is None:
            assert x is None and y is None, key
            continue
        x, y = np.asarray(x), np.asarray(y)
        assert (x.shape, x.dtype) == (y.shape, y.dtype) and x.tobytes() == y.tobytes(), key


def _read_in_blocks(path: Path, **kwargs: Any) -> tuple[BagBlocks, Any, np.ndarray, int]:
    bb = BagBlocks(path, **kwargs)
    parts = list(bb.blocks())
    return bb, concatenate_histories([h for h, _ in parts]), np.concatenate([a for _, a in parts]), len(parts)


@pytest.mark.parametrize("kind", ["lockstep", "realtime"])
@pytest.mark.parametrize("block_messages", BLOCK_MESSAGES)
def test_a_bag_read_in_blocks_is_the_bag_read_whole_bit_for_bit(flight_bags: dict[str, Path], kind: str, block_messages: int) -> None:
    """The History (every field, the estimator's and the orbit's included), the answers, the
    rejected count, the counts, undecodable messages, frame ids and labels of the bag read in blocks
    of 1, 7, 29 and 500 messages equal :func:`bag_run`'s of the bag read whole."""
    path = flight_bags[kind]
    bag = read_bag(path)
    whole = bag_run(bag)
    bb, history, answer, n_blocks = _read_in_blocks(path, block_messages=block_messages)
    assert n_blocks > 1
    _assert_same_bits(history, whole.history)
    assert answer.tobytes() == whole.answer.tobytes()
    assert (bb.t0_ns, bb.rejected, bb.torque_topic, bb.has_diagnostics) == (whole.t0_ns, whole.rejected, whole.torque_topic, whole.has_diagnostics)
    assert np.array_equal(bb.t_s, whole.history.t)
    h = bb.bag
    assert h.counts == bag.counts and list(h.counts) == list(bag.counts) and h.undecodable == bag.undecodable and h.frame_ids == bag.frame_ids
    assert (h.diagnostics_labels, h.array_labels, h.metadata, h.truncated) == (bag.diagnostics_labels, bag.array_labels, bag.metadata, bag.truncated)
    # what the bag exercises: held torques and answers, duplicates, no-data estimates, a topic that stopped
    assert whole.rejected > 0 and np.count_nonzero(whole.answer == c.ANSWER_HELD) > 20
    assert whole.history.estimate is not None and np.isnan(whole.history.estimate.q_BN).any()
    assert whole.history.orbit is not None and np.isnan(whole.history.orbit[:, 0, 3]).sum() > 100  # the magnetometer at 10 Hz


def test_blocks_of_bytes_and_a_duration_cut_the_run_as_bag_run_does(flight_bags: dict[str, Path]) -> None:
    """Blocks of a few chunks (``block_bytes``), and only the samples of the run's span
    (``duration_s``), as :func:`bag_run` ``(bag, duration_s)``."""
    path = flight_bags["lockstep"]
    whole = bag_run(read_bag(path), duration_s=1.0)
    _, history, answer, n_blocks = _read_in_blocks(path, block_bytes=20_000, duration_s=1.0)
    assert n_blocks > 3 and history.t.size == 101
    _assert_same_bits(history, whole.history)
    assert answer.tobytes() == whole.answer.tobytes()


def test_the_metrics_and_per_orbit_table_from_blocks_are_the_whole_bags(flight_bags: dict[str, Path]) -> None:
    """:meth:`BagBlocks.measure` gives :func:`bag_metrics`'s run metrics and per-orbit table (four
    orbits in the run, each cut by blocks), its BagRun's answers and History (every sample: a
    short run), for blocks of every size."""
    path = flight_bags["lockstep"]
    bins = OrbitBins(period_s=0.7, wheel_spin_inertia_kg_m2=np.full(4, 0.01), wheel_axes_B=np.eye(3, 4) + 0.1, rod_max_dipole_Am2=np.full(3, 400.0))
    bag = read_bag(path)
    whole = bag_run(bag)
    metrics, per_orbit = bag_metrics(bag, run=whole, orbit_bins=bins, **SETTINGS)
    assert len(per_orbit) == 4 and metrics["returned_to_constraint"] is not None
    for block_messages in BLOCK_MESSAGES[1:]:
        m = BagBlocks(path, block_messages=block_messages).measure(orbit_bins=bins, figures=lambda t_end_s: FullHistory(), **SETTINGS)
        assert m.read_whole is None and m.problem is None and m.run is not None
        assert m.metrics == metrics and m.per_orbit == per_orbit, block_messages
        _assert_same_bits(m.run.history, whole.history)
        assert m.run.controller_summary() == whole.controller_summary() and m.run.end_s == float(whole.history.t[-1])


def test_the_windows_hold_what_the_next_samples_read_not_the_bag(tmp_path: Path) -> None:
    """The memory is set by the block: read in blocks of 200 messages (about 8 samples), a bag of
    1200 samples holds windows no larger than one of 300 samples: a block's samples, the lags'
    and the latest message before them, whatever the bag's length."""
    def largest_window(n: int) -> int:
        path = write_bag(tmp_path / f"long{n}.mcap", _flight_messages(n, np.random.default_rng(5)), chunk_size=8192)
        bb = BagBlocks(path, block_messages=200)
        largest = 0
        for _ in bb.blocks():  # (each window as the block left it, before it is cut)
            largest = max(largest, max(t.window.stamps_ns.size for t in bb._topics.values() if t.window is not None))
        return largest

    short, long = largest_window(300), largest_window(1200)
    assert 0 < long == short <= 8 + 6 + 8 + 4  # a block's samples, the lags' (-2 to 4), the next block's first, the edge


def test_a_bag_whose_stamps_go_back_is_read_whole_with_the_same_numbers(tmp_path: Path) -> None:
    """A topic the alignment reads whose stamps are not in file order cannot be read in blocks
    exactly: :meth:`BagBlocks.measure` reads it whole (and says so), with :func:`bag_metrics`'s numbers."""
    messages = _flight_messages(120, np.random.default_rng(7))
    torques = [i for i, m in enumerate(messages) if m[0] == c.CONTROL_TORQUE.name]
    a, b = torques[40], torques[41]
    messages[a], messages[b] = messages[b], messages[a]  # two torques recorded out of order
    path = write_bag(tmp_path / "back.mcap", messages)
    bag = read_bag(path)
    metrics, per_orbit = bag_metrics(bag, **SETTINGS)
    m = BagBlocks(path, block_messages=50).measure(**SETTINGS)
    assert m.read_whole is not None and "not in file order" in m.read_whole
    assert m.metrics == metrics and m.per_orbit == per_orbit and m.bag.counts == bag.counts
    from sappc.analysis.report import analyse_bag

    notes = analyse_bag(path).notes
    assert any(n.startswith("the bag was read whole, not in blocks (control/torque: its stamps are not in file order)") for n in notes), notes


def test_a_bag_without_the_reference_has_its_counts_and_no_run(tmp_path: Path) -> None:
    """No reference: no run (the problem is :func:`bag_run`'s error), the counts still read."""
    messages = [m for m in _flight_messages(60, np.random.default_rng(2)) if m[0] != c.REFERENCE_ATTITUDE.name]
    path = write_bag(tmp_path / "noref.mcap", messages)
    m = BagBlocks(path, block_messages=100).measure(**SETTINGS)
    assert m.run is None and m.metrics is None and m.problem is not None and "reference/attitude" in m.problem
    assert m.bag.counts == read_bag(path).counts


def test_aligned_reads_only_the_topics_the_windows_keep(flight_bags: dict[str, Path]) -> None:
    """Every series :func:`~sappc.bag.read.aligned` reads is one of :func:`aligned_topics` (the
    blocks keep a window of those only)."""
    bag = read_bag(flight_bags["lockstep"])
    read: list[str] = []

    class Watched(dict):  # type: ignore[type-arg]
        def __getitem__(self, key: str) -> Any:
            read.append(key)
            return super().__getitem__(key)

    bag.series = Watched(bag.series)
    bag_run(bag)
    assert set(read) <= set(aligned_topics(bag)) and len(set(read)) > 10


# ---- the file a chunk at a time ------------------------------------------------------------------


def _walked(path: Path) -> tuple[np.ndarray, np.ndarray, list[bytes], McapWalk]:
    walk = McapWalk(path)
    channels, logs, payloads = [], [], []
    for piece in walk.pieces():
        channels.append(piece.channel_id)
        logs.append(piece.log_time_ns)
        payloads += [piece.data[s : s + n] for s, n in zip(piece.start.tolist(), piece.length.tolist())]
    empty = np.zeros(0, np.int64)
    return np.concatenate(channels) if channels else empty, np.concatenate(logs) if logs else empty, payloads, walk


def _assert_walk_is_the_scan(path: Path) -> None:
    scan = scan_mcap(path)
    channel_id, log_time, payloads, walk = _walked(path)
    assert np.array_equal(channel_id, scan.channel_id) and np.array_equal(log_time, scan.log_time_ns)
    assert payloads == [scan.buffer[s : s + n] for s, n in zip(scan.start.tolist(), scan.length.tolist())]
    assert walk.channels == scan.channels and list(walk.channels) == list(scan.channels)
    assert (walk.metadata, walk.truncated) == (scan.metadata, scan.truncated)


def _indexless_bag(path: Path, messages: list[tuple[str, str, object, int]]) -> Path:
    """A bag written without message indexes (each chunk is then walked record by record)."""
    return write_bag(path, messages, indexed=False, metadata={"sappc/x": {"text": "y"}})


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("chunked", [True, False])
def test_the_walk_reads_the_scans_messages_a_chunk_at_a_time(tmp_path: Path, compression: str, chunked: bool) -> None:
    messages = _flight_messages(30, np.random.default_rng(3))
    _assert_walk_is_the_scan(write_bag(tmp_path / "a.mcap", messages, compression=compression, use_chunking=chunked,
                                       metadata={"sappc/scenario.yaml": {"text": "name: x"}}))


def test_the_walk_reads_a_bag_without_message_indexes(tmp_path: Path) -> None:
    _assert_walk_is_the_scan(_indexless_bag(tmp_path / "noindex.mcap", _flight_messages(30, np.random.default_rng(4))))


def test_a_bag_cut_anywhere_walks_as_it_scans(tmp_path: Path) -> None:
    """Cut at any byte (in a chunk, in its message index, in the summary), the walk stops where the
    scan stops, with its reason, and a bag read in blocks is still the bag read whole."""
    messages = _flight_messages(60, np.random.default_rng(9))
    whole = write_bag(tmp_path / "whole.mcap", messages, chunk_size=4096).read_bytes()
    rng = np.random.default_rng(1)
    for cut in sorted(rng.integers(2000, len(whole), 12).tolist()) + [len(whole) - 3]:
        part = tmp_path / f"cut{cut}.mcap"
        part.write_bytes(whole[:cut])
        _assert_walk_is_the_scan(part)
        try:
            run = bag_run(read_bag(part))
        except Exception:  # too little left for a run: the blocks' own tests cover that
            continue
        _, history, answer, _ = _read_in_blocks(part, block_messages=13)
        _assert_same_bits(history, run.history)
        assert answer.tobytes() == run.answer.tobytes()


def _message_record(raw: bytearray, nth: int) -> int:
    """The file offset of the ``nth`` message record of the first chunk (an uncompressed one)."""
    off = 8
    while raw[off] != 0x06:  # opcode u8, length u64: the records before the first chunk
        off += 9 + int.from_bytes(raw[off + 1 : off + 9], "little")
    body = off + 9 + 8 + 8 + 8 + 4  # message start and end times, uncompressed size, CRC
    body += 4 + int.from_bytes(raw[body : body + 4], "little") + 8  # the compression's name, the records' length
    seen = 0
    while True:
        if raw[body] == 0x05:
            seen += 1
            if seen == nth:
                return body
        body += 9 + int.from_bytes(raw[body + 1 : body + 9], "little")


def test_a_chunk_whose_records_are_torn_inside_gives_nothing_of_it(tmp_path: Path) -> None:
    """A chunk that decompresses but whose last record runs past its end: the scan and the walk
    keep every message before the chunk and none of it (the scan kept the chunk's first messages
    without their payloads: the decoder then read past the buffer)."""
    messages = _flight_messages(20, np.random.default_rng(6))
    path = write_bag(tmp_path / "torn.mcap", messages, compression="none", chunk_size=4096)
    raw = bytearray(path.read_bytes())
    at = _message_record(raw, 5)  # the fifth message record of the first chunk (uncompressed)
    raw[at + 1 : at + 9] = (10**6).to_bytes(8, "little")  # its length now runs past the chunk
    path.write_bytes(bytes(raw))
    scan = scan_mcap(path)
    assert scan.truncated is not None and "past the end of its chunk" in scan.truncated
    assert int(scan.start.max(initial=0)) + int(scan.length.max(initial=0)) <= len(scan.buffer)
    _assert_walk_is_the_scan(path)


# ---- sappc rerun in blocks ----------------------------------------------------------------------------

PARAMS = Path(__file__).resolve().parents[3] / "config" / "controller_sappc.yaml"


def _rerun_messages(n: int, rng: np.random.Generator, *, held_ref_samples: int = 1, first: int = 100) -> list[tuple[str, str, object, int]]:
    """``n`` steps of the sappc node as its diagnostics report them, from sample ``first``: every
    ninth step holds a reference ``held_ref_samples`` old, every thirteenth is no control step (the
    torque held), every seventeenth has no diagnostics; recorded with lags (the reference ahead,
    the diagnostics three samples behind).  (``first = 0``: a step without diagnostics reports no
    input stamps, -1 ns, which the re-run matches with the inputs stamped 0 within STAMP_TOL_NS.)"""
    from sappc_controller.inputs import ControlSample, step_sample
    from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
    from sappc_msgs_py.convert import clock_msg

    kind, config, dt = controller_from_parameters_file(PARAMS.read_text(), source=str(PARAMS))
    controller = CONTROLLER_CLASSES[kind](config)
    dt_ns = round(dt * 1e9)
    out: list[tuple[int, int, str, str, object]] = []

    def add(topic: c.Topic, msg: object, stamp_ns: int, lag: int = 0) -> None:
        out.append((stamp_ns + (lag + 10) * dt_ns, len(out), topic.name, topic.type_name, msg))

    q = _unit(np.array([0.3, 0.4, -0.3, 0.8]))
    refs: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    torque = np.zeros(3)
    for k in range(first, first + n):
        ns = k * dt_ns
        t = ns / 1e9
        q = _unit(q + 1e-3 * rng.standard_normal(4))
        w = 1e-2 * rng.standard_normal(3)
        refs[k] = (_unit(np.array([0.0, 0.0, 0.1 * np.sin(0.01 * k), 1.0])), 1e-3 * rng.standard_normal(3), np.zeros(3))
        add(c.CLOCK, clock_msg(t), ns)
        add(c.STATE_ATTITUDE, quaternion_msg(q, t, c.STATE_ATTITUDE), ns)
        add(c.STATE_RATE, vector3_msg(w, t, c.STATE_RATE), ns)
        for topic, value in zip((c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION), refs[k]):
            add(topic, quaternion_msg(value, t, topic) if value.size == 4 else vector3_msg(value, t, topic), ns, lag=-2)
        used = max(k - held_ref_samples, first) if k % 9 == 0 else k
        stale = k % 13 == 6
        if not stale:
            sample = ControlSample(ns, (ns, ns, used * dt_ns, used * dt_ns, used * dt_ns), (q, w, *refs[used]))
            torque = step_sample(controller, dt, sample, 0).torque_B
        rows = {label: np.zeros(3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
        rows["status"] = np.array([0.0, float(stale), float(c.ANSWER_HELD if stale else c.ANSWER_COMMANDED)])
        rows["input_stamps_state_s"] = np.array([t, t, 0.0])
        rows["input_stamps_reference_s"] = np.full(3, used * dt_ns / 1e9)
        if k % 17 != 4:
            add(c.CONTROLLER_DIAGNOSTICS, diagnostics_msg(t, rows), ns, lag=3)
        add(c.CONTROL_TORQUE, torque_msg(torque, t), ns, lag=1)
    out.sort(key=lambda m: (m[0], m[1]))
    return [(name, type_name, msg, log) for log, _, name, type_name, msg in out]


def _same_rerun(a: Any, b: Any) -> None:
    assert a.summary() == b.summary() and list(a.skipped) == list(b.skipped)
    for x, y in ((a.stamps_ns, b.stamps_ns), (a.recorded, b.recorded), (a.recomputed, b.recomputed)):
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


@pytest.mark.parametrize("first", (100, 0))
@pytest.mark.parametrize("block_messages", (1, 7, 29, None))
def test_a_rerun_in_blocks_is_the_rerun_of_the_bag_read_whole(tmp_path: Path, block_messages: int | None, first: int) -> None:
    """``sappc rerun``'s recomputed torques, skipped samples and counts from the bag read in blocks
    equal :func:`rerun_bag`'s on the bag read whole, bit for bit; the re-run finds every step."""
    from sappc.analysis.rerun import rerun_bag, rerun_blocks

    path = write_bag(tmp_path / "rerun.mcap", _rerun_messages(150, np.random.default_rng(8), first=first), chunk_size=4096,
                     metadata={"sappc/params.yaml": {"text": PARAMS.read_text()}})
    whole = rerun_bag(read_bag(path))
    _same_rerun(rerun_blocks(path, block_messages=block_messages) if block_messages else rerun_blocks(path, block_bytes=8192), whole)
    if first:  # (from 0, the steps without diagnostics are matched with the inputs of stamp 0: not identical)
        assert whole.summary()["all_identical"] and whole.summary()["samples"] == 131 and whole.skipped == {
            "not a control step (the last torque held, or zero torque)": 10, "an input of the sample is not in the bag": 9}


def test_a_rerun_whose_input_is_older_than_the_windows_reads_the_bag_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A step that used a reference older than the windows keep (a held input): the re-run reads
    the bag whole, with the same result."""
    from sappc.analysis import rerun

    path = write_bag(tmp_path / "held.mcap", _rerun_messages(150, np.random.default_rng(8), held_ref_samples=120), chunk_size=4096,
                     metadata={"sappc/params.yaml": {"text": PARAMS.read_text()}})
    whole = rerun.rerun_bag(read_bag(path))
    with pytest.raises(bag_blocks.NotInBlocks, match="before the windows"):
        rerun._rerun_in_blocks(BagBlocks(path, block_messages=50), None)
    _same_rerun(rerun.rerun_blocks(path, block_messages=50), whole)
    assert whole.summary()["all_identical"]


def test_sappc_runs_read_back_in_blocks_is_the_whole_bags(flight_bags: dict[str, Path]) -> None:
    """``sappc run``'s read-back (the run's span, no figures: :class:`~sappc.bag.blocks.NoFigures`)
    gives the metrics, per-orbit table and controller summary of ``bag_run(bag, duration_s)`` and
    :func:`bag_metrics`."""
    from sappc.bag.blocks import NoFigures

    path = flight_bags["realtime"]
    bins = OrbitBins(period_s=0.5)
    bag = read_bag(path)
    run = bag_run(bag, duration_s=2.0)
    metrics, per_orbit = bag_metrics(bag, run=run, orbit_bins=bins, **SETTINGS)
    m = BagBlocks(path, duration_s=2.0, block_bytes=30_000).measure(orbit_bins=bins, figures=lambda t_end_s: NoFigures(), **SETTINGS)
    assert m.run is not None and (m.metrics, m.per_orbit) == (metrics, per_orbit)
    assert m.run.controller_summary() == run.controller_summary() and m.run.samples == run.samples > 150
    assert m.run.history.t.size == 0 and m.run.end_s == float(run.history.t[-1]) and m.run.t0_ns == run.t0_ns

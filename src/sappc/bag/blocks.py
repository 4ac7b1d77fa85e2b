"""Bags read in blocks: a run's metrics, per-orbit table and figures from a bag in memory set by
the block, not by the bag (issue 47; docs/design/streaming.md, item 6).

:func:`~sappc.bag.read.read_bag` holds every message of a bag at once (its decompressed records
and every topic's arrays: 7.9 GB for the 756 MB bag of one orbit through the graph, 16.5 million
messages).  :class:`BagBlocks` reads the MCAP file twice, a chunk at a time
(:class:`~sappc.bag.mcap_scan.McapWalk`: the file is never read whole):

1. The index (when the object is made): the bag's channels, metadata records and where it ends,
   each channel's message count, and the stamps of the topics the samples are aligned on: the
   run's samples (:func:`~sappc.bag.read.sample_stamps`), known before any sample is aligned (the
   metrics' accumulator takes their times up front, :attr:`BagBlocks.t_s`).
2. The blocks (:meth:`BagBlocks.blocks`, :meth:`BagBlocks.measure`): the messages of about
   ``block_bytes`` of chunk records decoded at once (:mod:`sappc.bag.cdr`), the topics the
   alignment reads appended to a window each; the samples that no later message can change are
   aligned by :func:`~sappc.bag.read.aligned`, the code that aligns a whole bag, on the windows,
   handed on as one :class:`~sappc.evaluation.history.History` block (the same values as the
   whole bag's History, bit for bit), and the windows cut to what the next samples can still read.

When a sample is final: a sample reads, of each topic, the messages within ``2 STAMP_TOL_NS`` of
its stamp, the latest before it and (the reference) the next after it
(:func:`~sappc.bag.read.aligned`).  Each topic's stamps are checked to be non-decreasing in file
order (every bag ``sappc run`` records, lockstep and real time: one publisher a topic), so once
every topic the alignment reads has a message stamped more than :data:`EDGE_NS` after a sample,
or has no message left in the file (the index counted them), no later message can change it.  A
topic's message for a sample may be in the next chunk (a sample's messages are recorded over
several): the sample waits in the window until it is final.

A bag this cannot read exactly (a topic's stamps that go back, a topic on two channels, a float
array whose layout changes between messages, a channel defined after its messages) is read whole
instead (:func:`~sappc.bag.read.read_bag`, as before), and :attr:`MeasuredBag.read_whole` says why.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from sappc_msgs_py.contract import (CONTROLLER_DIAGNOSTICS, ESTIMATOR_DIAGNOSTICS, ESTIMATOR_DIAGNOSTICS_LAYOUT, FAULT_PREFIX,
                                    MODE_STATUS_LAYOUT, REFERENCE_ATTITUDE, STATE_ATTITUDE, STATE_RATE, TRUTH_ATTITUDE, TRUTH_RATE)

from sappc.bag.cdr import DECODERS, Decoded, decode
from sappc.bag.errors import BagError
from sappc.bag.mcap_scan import Channel, McapWalk, Piece
from sappc.bag.read import (_NEED_DIAGNOSTICS, STAMP_TOL_NS, Bag, BagRun, Series, Ticker, aligned, aligned_topics, bag_metrics, bag_run,
                            find_topic, mcap_file, read_bag, sample_stamps, torque_topic)
from sappc.evaluation.envelope import HistoryEnvelope
from sappc.evaluation.history import History

__all__ = ["BLOCK_BYTES", "EDGE_NS", "BagBlocks", "FigureSink", "FullHistory", "MeasuredBag", "NoFigures", "NotInBlocks",
           "concatenate_histories", "figure_sink"]

#: Uncompressed chunk records decoded at once [bytes]: 4 MiB is about 30,000 messages of the
#: graph's orbit bag (140 bytes a message), 1,000 samples.  Measured (``analyse_bag`` of a 200,000
#: sample orbit bag, 5.8 million messages, the 2-core machine): peak resident set 118, 117, 120,
#: 167 and 390 MB and CPU 19.5, 17.0, 16.2, 17.7 and 20.3 s for blocks of 1, 2, 4, 16 and 64 MiB:
#: below 4 MiB the per-block Python costs time, above it the block's arrays cost memory.
BLOCK_BYTES = 4 * 2**20
#: A sample is final once every topic it reads has a message stamped more than this after it [ns]:
#: a sample reads the messages within ``STAMP_TOL_NS`` of its stamp, and the estimator's topics
#: within ``STAMP_TOL_NS`` of an estimate that is within ``STAMP_TOL_NS`` of it (two nearest-stamp
#: matches, :func:`~sappc.bag.read.bag_estimate`).
EDGE_NS = 2 * STAMP_TOL_NS
#: The names the samples are aligned on (:func:`~sappc.bag.read.state_topics`): the index keeps
#: the stamps of every topic that one of them may resolve to.
_SAMPLE_NAMES = tuple(t.name.lstrip("/") for t in (TRUTH_ATTITUDE, TRUTH_RATE, STATE_ATTITUDE, STATE_RATE, REFERENCE_ATTITUDE))
#: Types whose payload layout (hence the columns, and a float array's labels) is parsed per
#: message group, not fixed by the type.
_PARSED_LAYOUTS = ("std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/JointState")


class NotInBlocks(Exception):
    """The bag cannot be read in blocks exactly (why: the message)."""


class FigureSink(Protocol):
    """What the figures of a bag read in blocks are drawn from: fed each History block in order."""

    def add(self, block: History) -> None: ...

    def history(self) -> History: ...


def concatenate_histories(blocks: list[History]) -> History:
    """One History of consecutive History blocks (every array, the estimator's included, joined
    along time)."""
    first = blocks[0]

    def joined(records: list[Any]) -> dict[str, Any]:
        out = {}
        for f in dataclasses.fields(records[0]):
            values = [getattr(r, f.name) for r in records]
            if isinstance(values[0], np.ndarray):
                out[f.name] = np.concatenate(values)
        return out

    est = None if first.estimate is None else dataclasses.replace(first.estimate, **joined([b.estimate for b in blocks]))
    return dataclasses.replace(first, **joined(blocks), estimate=est)


class FullHistory:
    """A :class:`FigureSink` that keeps every sample: the History :func:`~sappc.bag.read.bag_run`
    gives, bit for bit."""

    def __init__(self) -> None:
        self._blocks: list[History] = []

    def add(self, block: History) -> None:
        self._blocks.append(block)

    def history(self) -> History:
        if len(self._blocks) > 1:
            self._blocks = [concatenate_histories(self._blocks)]
        return self._blocks[0]


class NoFigures:
    """A :class:`FigureSink` that keeps no sample (``sappc run`` draws no figure): its History has
    the run's fields and none of its samples."""

    def __init__(self) -> None:
        self._empty: History | None = None

    def add(self, block: History) -> None:
        if self._empty is None:
            self._empty = block.samples(0, 0)

    def history(self) -> History:
        if self._empty is None:
            raise ValueError("no sample was fed")
        return self._empty


@dataclass
class MeasuredBag:
    """A bag's run, metrics and per-orbit table (:meth:`BagBlocks.measure`)."""

    bag: Bag  # what the bag holds, without its messages (a bag read whole: with them)
    run: BagRun | None  # None: no run (``problem`` says why)
    metrics: dict[str, Any] | None
    per_orbit: list[dict[str, Any]]
    problem: str | None = None  # why the bag has no run (it lacks the state or the reference, ...)
    read_whole: str | None = None  # why the bag was read whole, not in blocks (None: in blocks)


@dataclass
class _Topic:
    """A topic of the bag as the blocks read it."""

    channel: Channel
    messages: int  # its messages in the file (the index's count)
    read: int = 0  # of them read so far
    decoded: int = 0
    undecodable: int = 0
    frame_ids: set[str] = dataclasses.field(default_factory=set)
    labels: tuple[str, ...] | None = None  # a float array's labels (None: none decoded yet)
    width: int | None = None  # the columns of its values (None: none decoded yet)
    window: Series | None = None  # the messages the next samples may read (topics the alignment reads)
    head: Series | None = None  # the first message decoded into the window (the least stamp: stamps in file order)
    second_ns: int | None = None  # the second one's stamp
    last_ns: int | None = None  # the last stamp decoded
    dropped_ns: int | None = None  # the latest stamp cut from the window (every message after it is in the window)

    @property
    def complete(self) -> bool:
        return self.read >= self.messages

    def readable(self, at_ns: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Whether a nearest-stamp lookup at each of ``at_ns`` reads from :meth:`lookup_window` what it
        would read from the whole topic: no message within ``STAMP_TOL_NS`` of it was cut (it is
        after every message cut, or before every message but the first)."""
        out: NDArray[np.bool_] = np.ones(np.shape(at_ns), dtype=bool)
        if self.dropped_ns is not None:
            second = self.second_ns if self.second_ns is not None else self.dropped_ns
            out = (at_ns - STAMP_TOL_NS > self.dropped_ns) | (at_ns + STAMP_TOL_NS < second)
        return out

    def lookup_window(self) -> Series | None:
        """The window with the topic's first message before it when it was cut (a lookup before
        every other message, e.g. a stamp not reported, -1, finds it as in the whole topic)."""
        w, head = self.window, self.head
        if w is None or head is None or self.dropped_ns is None:
            return w
        return _joined(head, w)

    @property
    def known(self) -> bool:
        """Its layout is known for good: a message decoded, or none is left."""
        return self.width is not None or self.complete


def _joined(a: Series, b: Series) -> Series:
    """The messages of ``a``, then those of ``b``."""
    return Series(np.concatenate((a.stamps_ns, b.stamps_ns)), np.concatenate((a.values, b.values)), np.concatenate((a.log_time_ns, b.log_time_ns)))


@dataclass
class _Block:
    """The messages of consecutive pieces of the file, decoded at once."""

    data: bytes
    channel_id: NDArray[np.int64]
    log_time_ns: NDArray[np.int64]
    start: NDArray[np.int64]
    length: NDArray[np.int64]
    walked: int

    def by_channel(self) -> Iterator[tuple[int, NDArray[np.int64]]]:
        """Each channel's messages in the block: (channel id, their positions, in file order)."""
        order = np.argsort(self.channel_id, kind="stable")
        ids, first = np.unique(self.channel_id[order], return_index=True)
        for cid, lo, hi in zip(ids.tolist(), first.tolist(), list(first[1:]) + [order.size]):
            yield cid, order[lo:hi]


def _blocks(pieces: Iterator[Piece], block_bytes: int, block_messages: int | None) -> Iterator[_Block]:
    """The pieces' messages gathered into blocks of about ``block_bytes`` of records (whole pieces),
    or of exactly ``block_messages`` messages (a piece cut where the count falls: the tests cut
    between any two messages)."""
    parts: list[tuple[Piece, int, int]] = []
    size = count = 0

    def block() -> _Block:
        datas: list[bytes] = []
        cols: list[list[NDArray[np.int64]]] = [[], [], [], []]
        base = 0
        for piece, lo, hi in parts:
            datas.append(piece.data)
            columns = (piece.channel_id[lo:hi], piece.log_time_ns[lo:hi], piece.start[lo:hi] + base, piece.length[lo:hi])
            for col, a in zip(cols, columns):
                col.append(a)
            base += len(piece.data)
        data = datas[0] if len(datas) == 1 else b"".join(datas)
        channel_id, log_time, start, length = (np.concatenate(c) for c in cols)
        return _Block(data, channel_id, log_time, start, length, walked=parts[-1][0].walked)

    for piece in pieces:
        lo, m = 0, piece.channel_id.size
        while lo < m:
            hi = m if block_messages is None else min(m, lo + block_messages - count)
            parts.append((piece, lo, hi))
            size += len(piece.data)
            count += hi - lo
            lo = hi
            if (block_messages is not None and count >= block_messages) or (block_messages is None and size >= block_bytes):
                yield block()
                parts, size, count = [], 0, 0
    if parts:
        yield block()


def _may_be_sample_topic(topic: str) -> bool:
    """Whether :func:`~sappc.bag.read.find_topic` may resolve one of the names the samples are
    aligned on to ``topic`` (its own name, or a namespaced one that is no fault relay's output)."""
    t = "/" + topic.lstrip("/")
    relay = "/" + FAULT_PREFIX.strip("/") + "/"
    return any(t == "/" + name or (t.endswith("/" + name) and not t.endswith(relay + name)) for name in _SAMPLE_NAMES)


def _reading(ticker: Ticker | None) -> Callable[[int, int], object] | None:
    if ticker is None:
        return None
    return lambda done, total: ticker.detail(f"{done / 1e6:.1f} of {total / 1e6:.1f} MB")


class BagBlocks:
    """A bag read in blocks (module docstring).  Making it reads the index (pass 1): :attr:`bag`
    (the metadata records, the topics; the counts once the blocks are read), the samples' stamps
    (:attr:`t_s`, :attr:`t0_ns`, or :attr:`problem` when the bag has no run).

    ``duration_s``: only the samples of ``[0, duration_s]`` from the first (a run's own span,
    :func:`~sappc.bag.read.bag_run`'s).  ``block_bytes``, ``block_messages``: the size of a block
    (:data:`BLOCK_BYTES` of chunk records; or exactly that many messages: tests).  ``ticker``: the
    passes are its steps "reading the bag back" (the index) and "aligning and measuring the
    samples", each with the megabytes walked.

    Raises
    ------
    BagError
        As :func:`~sappc.bag.read.read_bag`: not a bag, or no message of the contract's types.
    """

    def __init__(self, path: str | Path, *, duration_s: float | None = None, block_bytes: int = BLOCK_BYTES,
                 block_messages: int | None = None, ticker: Ticker | None = None) -> None:
        self.path = Path(path)
        self.mcap_path = mcap_file(self.path)
        self.duration_s = duration_s
        self.block_bytes, self.block_messages = int(block_bytes), block_messages
        self.ticker = ticker
        self.not_in_blocks: str | None = None  # why the bag must be read whole (known from the index)
        self.problem: str | None = None
        self.t0_ns = 0
        self._stamps = np.zeros(0, np.int64)  # the samples' stamps [ns]
        if ticker is not None:
            ticker.step("reading the bag back")
        walk = self._walk()
        counts: dict[int, int] = {}
        stamps: dict[int, list[NDArray[np.int64]]] = {}
        undefined: set[int] = set()  # channels of messages read before their definition
        for block in _blocks(self._pieces(walk), self.block_bytes, self.block_messages):
            for cid, pos in block.by_channel():
                counts[cid] = counts.get(cid, 0) + pos.size
                ch = walk.channels.get(cid)
                if ch is None:
                    undefined.add(cid)
                elif ch.message_encoding == "cdr" and ch.schema_name in DECODERS and _may_be_sample_topic(ch.topic):
                    d = decode(ch.schema_name, block.data, block.start[pos], block.length[pos])
                    assert d is not None  # a type of DECODERS
                    stamps.setdefault(cid, []).append(d.stamps_ns)
        self.channels = dict(walk.channels)
        self.truncated = walk.truncated
        if undefined & set(self.channels):
            self.not_in_blocks = "a channel is defined after its first messages"
        # the topics read_bag makes series of, in its order: cdr channels with messages, of a type decoded
        self._topics: dict[str, _Topic] = {}
        for cid, ch in self.channels.items():
            if ch.message_encoding == "cdr" and counts.get(cid, 0) and ch.schema_name in DECODERS:
                if ch.topic in self._topics:
                    self.not_in_blocks = f"{ch.topic} is recorded on two channels"
                self._topics[ch.topic] = _Topic(ch, counts[cid])
        self.bag = Bag(path=self.path, series={}, metadata=walk.metadata, truncated=walk.truncated,
                       message_counts={t: 0 for t in self._topics})
        if not self._topics:
            raise self.no_messages()
        # the samples, as bag_run finds them, from the stamps alone
        empty = np.zeros(0, np.int64)
        by_topic = {self.channels[cid].topic: np.concatenate(parts) for cid, parts in stamps.items()}
        series = {t: Series(s, np.zeros((s.size, 0)), empty) for t in self._topics for s in [by_topic.get(t, empty)]}
        index = Bag(path=self.path, series=series)
        try:
            self._stamps = sample_stamps(index, duration_s)
            self.t0_ns = int(self._stamps[0])
        except BagError as exc:
            self.problem = str(exc)

    def no_messages(self) -> BagError:
        """:func:`~sappc.bag.read.read_bag`'s error for a bag without a message of the contract."""
        stopped = f" (reading stopped: {self.truncated})" if self.truncated else ""
        return BagError(f"{self.path}: the bag holds no messages of the topic contract{stopped}")

    def has_contract_messages(self) -> bool:
        """Whether a message of the bag decodes (:func:`~sappc.bag.read.read_bag` refuses a bag
        where none does): read until the first one that does."""
        by_id = {topic.channel.id: topic.channel for topic in self._topics.values()}
        for block in _blocks(self._pieces(self._walk()), self.block_bytes, self.block_messages):
            for cid, pos in block.by_channel():
                ch = by_id.get(cid)
                d = None if ch is None else decode(ch.schema_name, block.data, block.start[pos], block.length[pos])
                if d is not None and d.stamps_ns.size:
                    return True
        return False

    def _walk(self) -> McapWalk:
        return McapWalk(self.mcap_path, progress=_reading(self.ticker))

    def _pieces(self, walk: McapWalk) -> Iterator[Piece]:
        """``walk``'s pieces; not an MCAP file, or not readable: :class:`BagError` (as :func:`~sappc.bag.read.scan_bag`)."""
        try:
            yield from walk.pieces()
        except ValueError as exc:
            raise BagError(str(exc)) from None
        except OSError as exc:
            raise BagError(f"{self.mcap_path}: cannot read ({exc.strerror})") from None

    @property
    def samples(self) -> int:
        """The run's samples (0: no run)."""
        return int(self._stamps.size)

    @property
    def t_s(self) -> NDArray[np.float64]:
        """Every sample's time from the first [s] (the History's ``t``, whole): 8 bytes a sample."""
        return (self._stamps - self.t0_ns) / 1e9

    # ---- pass 2 ----------------------------------------------------------------------------------

    def blocks(self) -> Iterator[tuple[History, NDArray[np.int8]]]:
        """The run's samples a block at a time, in time order: (History block, how the controller
        answered each of its samples), the same values as :func:`~sappc.bag.read.bag_run`'s whole
        History and ``answer``.  Once exhausted, :attr:`bag` has its counts, undecodable messages,
        frame ids and labels, and :attr:`rejected`, :attr:`has_diagnostics` are set.

        Raises
        ------
        BagError
            If no message of the bag decodes (as :func:`~sappc.bag.read.read_bag`).
        """
        if self.not_in_blocks is not None:
            raise NotInBlocks(self.not_in_blocks)
        if self.ticker is not None:
            self.ticker.step("aligning and measuring the samples")
        view = self.view()
        used = aligned_topics(view) if self.problem is None else ()
        diag_topic = find_topic(view, CONTROLLER_DIAGNOSTICS.name)
        self._diag_max: NDArray[np.float64] | None = None
        self.has_diagnostics = False
        self.torque_topic = torque_topic(view)
        next_k = 0
        for decoded in self.passes(lambda topic: True, lambda name: name in used and next_k < self._stamps.size):
            d = decoded.get(diag_topic) if diag_topic is not None else None
            if d is not None and d.values.size:
                # each column's largest finite value (the rejected inputs' count is one: read_bag's _rejected_count)
                top = np.fmax.reduce(np.where(np.isfinite(d.values), d.values, np.nan), axis=0)
                self._diag_max = top if self._diag_max is None else np.fmax(self._diag_max, top)
            if next_k < self._stamps.size:
                k_hi = self._final(used)
                if k_hi > next_k:
                    yield self._aligned(next_k, k_hi)
                    next_k = k_hi
                    self._cut(used, next_k)
        if next_k < self._stamps.size:
            k_hi = self._final(used)
            assert k_hi == self._stamps.size  # every topic complete: every sample is final
            yield self._aligned(next_k, k_hi)
        self._finish(diag_topic)

    def passes(self, decoding: Callable[[_Topic], bool], keep: Callable[[str], bool]) -> Iterator[dict[str, Decoded]]:
        """The second pass over the file, a block at a time: the messages of each topic that
        ``decoding`` takes, decoded (its counts and layout checked), appended to its window when
        ``keep`` (its name) is true (its stamps checked to be in file order); yields each block's
        decoded messages by topic.  The other topics' messages are counted, not decoded.

        Raises
        ------
        NotInBlocks
            A window's stamps that go back, a layout that changes, a file that changed since the index.
        """
        topics = self._topics
        by_id = {topic.channel.id: topic for topic in topics.values()}
        for block in _blocks(self._pieces(self._walk()), self.block_bytes, self.block_messages):
            decoded: dict[str, Decoded] = {}
            for cid, pos in block.by_channel():
                topic = by_id.get(cid)
                if topic is None:
                    continue
                if not decoding(topic):
                    topic.read += pos.size
                    continue
                decoded[topic.channel.topic] = self._read(topic, block, pos, keep=keep(topic.channel.topic))
            yield decoded
        if any(not t.complete for t in topics.values()):
            raise NotInBlocks("the file changed between its two readings")

    def view(self) -> Bag:
        """A Bag of the bag's topics (every series empty), in :func:`~sappc.bag.read.read_bag`'s
        order: :func:`~sappc.bag.read.find_topic` resolves names on it as on the bag read whole."""
        empty = np.zeros(0, np.int64)
        series = {t: Series(empty, np.zeros((0, 0)), empty) for t in self._topics}
        return Bag(path=self.path, series=series, metadata=self.bag.metadata)

    def topic(self, name: str) -> _Topic:
        """The stream's state of topic ``name``: its window, its last stamp, whether it is complete."""
        return self._topics[name]

    def float_arrays_known(self) -> bool:
        """Whether the labels of every float array are known (so :meth:`diagnostics_labels` is final)."""
        return all(t.known for t in self._topics.values() if t.channel.schema_name == "std_msgs/msg/Float64MultiArray")

    def _read(self, topic: _Topic, block: _Block, pos: NDArray[np.int64], *, keep: bool) -> Decoded:
        """Decode a topic's messages of a block: its counts and layout; its window when ``keep``."""
        ch = topic.channel
        topic.read += pos.size
        length = block.length[pos]
        d = decode(ch.schema_name, block.data, block.start[pos], length)
        assert d is not None  # a type of DECODERS
        topic.undecodable += d.undecodable
        topic.frame_ids.update(d.frame_ids)
        if d.stamps_ns.size == 0:
            return d
        topic.decoded += d.stamps_ns.size
        width = d.values.shape[1]
        if ch.schema_name in _PARSED_LAYOUTS and (d.slow_path or np.unique(length).size > 1):
            raise NotInBlocks(f"{ch.topic}: messages of several layouts")
        if topic.width is None:
            topic.width, topic.labels = width, d.labels
        elif (width, d.labels) != (topic.width, topic.labels):
            raise NotInBlocks(f"{ch.topic}: its layout changes between messages")
        if not keep:
            return d
        s = d.stamps_ns
        if np.any(s[1:] < s[:-1]) or (topic.last_ns is not None and s[0] < topic.last_ns):
            raise NotInBlocks(f"{ch.topic}: its stamps are not in file order")
        topic.last_ns = int(s[-1])
        if topic.head is None:
            topic.head = Series(s[:1].copy(), d.values[:1].copy(), block.log_time_ns[pos][d.index][:1].copy())
            if s.size > 1:
                topic.second_ns = int(s[1])
        elif topic.second_ns is None:
            topic.second_ns = int(s[0])
        new = Series(s, d.values, block.log_time_ns[pos][d.index])
        w = topic.window
        topic.window = new if w is None else _joined(w, new)
        return d

    def _final(self, used: tuple[str, ...]) -> int:
        """The samples ``0 .. k - 1`` that no message left in the file can change: ``k``."""
        topics = self._topics
        if not self.float_arrays_known():
            return 0  # the labels of the float arrays decide the diagnostics' columns
        bound: int | None = None  # the least last stamp of a topic with messages left
        for name in used:
            t = topics[name]
            if t.complete:
                continue
            if t.last_ns is None:
                return 0
            bound = t.last_ns if bound is None else min(bound, t.last_ns)
        if bound is None:
            return int(self._stamps.size)
        return int(np.searchsorted(self._stamps, bound - EDGE_NS, side="left"))

    def _window_bag(self) -> Bag:
        empty = Series(np.zeros(0, np.int64), np.zeros((0, 0)), np.zeros(0, np.int64))
        series = {}
        for name, t in self._topics.items():
            w = t.window
            width = t.width if t.width is not None else _empty_width(t.channel.schema_name)
            series[name] = w if w is not None else Series(empty.stamps_ns, np.zeros((0, width)), empty.log_time_ns)
        return Bag(path=self.path, series=series, diagnostics_labels=self.diagnostics_labels(), array_labels=self._array_labels())

    def diagnostics_labels(self) -> tuple[str, ...]:
        """As :func:`~sappc.bag.read.read_bag`: the labels of the first float array (in channel order)
        whose first is ``time_s`` and that is neither the estimator's nor the mode's."""
        for t in self._topics.values():
            lab = t.labels or ()
            if t.channel.schema_name == CONTROLLER_DIAGNOSTICS.type_name and lab[:1] == ("time_s",) \
                    and lab != ESTIMATOR_DIAGNOSTICS_LAYOUT and lab != MODE_STATUS_LAYOUT:
                return lab
        return ()

    def _array_labels(self) -> dict[str, tuple[str, ...]]:
        arrays = {name: t for name, t in self._topics.items() if t.channel.schema_name == ESTIMATOR_DIAGNOSTICS.type_name}
        return {name: t.labels or () for name, t in arrays.items()}

    def _aligned(self, lo: int, hi: int) -> tuple[History, NDArray[np.int8]]:
        history, answer, has_diagnostics = aligned(self._window_bag(), self._stamps[lo:hi], self.t0_ns)
        self.has_diagnostics = has_diagnostics
        return history, answer

    def _cut(self, used: tuple[str, ...], next_k: int) -> None:
        """Drop from the windows what the samples from ``next_k`` on cannot read: a topic's
        messages stamped more than :data:`EDGE_NS` before the next sample but the latest of them."""
        if next_k >= self._stamps.size:
            for name in used:
                self._topics[name].window = None
            return
        self.cut_windows(used, int(self._stamps[next_k]) - EDGE_NS)

    def cut_windows(self, names: Iterable[str], below_ns: int) -> None:
        """Drop from the windows of ``names`` the messages stamped before ``below_ns`` but the latest
        of them (a nearest or latest stamp at or after ``below_ns`` reads the same messages)."""
        for name in names:
            topic = self._topics[name]
            w = topic.window
            if w is None:
                continue
            first = max(int(np.searchsorted(w.stamps_ns, below_ns, side="left")) - 1, 0)
            if first:
                topic.dropped_ns = int(w.stamps_ns[first - 1])
                topic.window = Series(w.stamps_ns[first:].copy(), w.values[first:].copy(), w.log_time_ns[first:].copy())

    def _finish(self, diag_topic: str | None) -> None:
        topics = self._topics
        if not any(t.decoded for t in topics.values()):
            raise self.no_messages()
        self.bag = Bag(path=self.path, series={}, metadata=self.bag.metadata, truncated=self.truncated,
                       diagnostics_labels=self.diagnostics_labels(), undecodable={n: t.undecodable for n, t in topics.items() if t.undecodable},
                       frame_ids={n: tuple(sorted(t.frame_ids)) for n, t in topics.items()}, array_labels=self._array_labels(),
                       message_counts={n: t.decoded for n, t in topics.items()})
        self.rejected = 0
        labels = self.bag.diagnostics_labels
        if diag_topic is not None and "status" in labels and self._diag_max is not None:
            col = 3 * labels.index("status")
            if col < self._diag_max.size and np.isfinite(self._diag_max[col]):
                self.rejected = int(self._diag_max[col])

    # ---- the driver --------------------------------------------------------------------------------

    def measure(self, *, steady_from_s: float, settle_threshold: float, t2_s: float, fault_windows: list[tuple[float, float]],
                orbit_bins: Any = None, figures: Callable[[float], FigureSink] | None = None, origin: str = "first_track") -> MeasuredBag:
        """The run's metrics and per-orbit table (:func:`~sappc.bag.read.bag_metrics`'s), its
        History for the figures, read a block at a time (:meth:`blocks`).  ``origin``: with flight
        modes (a bag with ``mode/status``), where the tracking metrics count from (the scenario's
        ``metrics.origin``, :class:`~sappc.evaluation.metrics.MetricsAccumulator`'s).

        ``figures``: given the run's last sample time [s], the sink the History blocks are fed to,
        whose :meth:`FigureSink.history` is the :class:`~sappc.bag.read.BagRun`'s ``history``
        (default: :func:`figure_sink`).  A bag that cannot be read in blocks is read whole
        (:attr:`MeasuredBag.read_whole` says why; its ``history`` is then the whole History).

        Raises
        ------
        BagError
            If no message of the bag decodes.
        """
        from sappc.evaluation.metrics import MetricsAccumulator

        settings: dict[str, Any] = {"steady_from_s": steady_from_s, "settle_threshold": settle_threshold, "t2_s": t2_s,
                                    "fault_windows": fault_windows, "origin": origin}
        try:
            if self.problem is not None:
                for _ in self.blocks():  # the counts, the layouts: no sample
                    pass
                return MeasuredBag(self.bag, None, None, [], problem=self.problem)
            t = self.t_s
            acc = MetricsAccumulator(t, 1, orbit_bins=orbit_bins, **settings)
            sink = (figures or figure_sink)(float(t[-1]))
            answer = np.empty(t.size, np.int8)
            k = 0
            for h, a in self.blocks():
                acc.add_history(h)
                sink.add(h)
                answer[k : k + a.size] = a
                k += a.size
            assert k == t.size
        except NotInBlocks as exc:
            return self._measure_whole(str(exc), orbit_bins=orbit_bins, **settings)
        metrics = acc.run_metrics(0)
        if not self.has_diagnostics:  # no rho, band or saturation flags: these are unknown, not zero
            for key in _NEED_DIAGNOSTICS:
                metrics[key] = None
        run = BagRun(history=sink.history(), t0_ns=self.t0_ns, answer=answer, rejected=self.rejected,
                     torque_topic=self.torque_topic, has_diagnostics=self.has_diagnostics, t_end_s=float(t[-1]))
        return MeasuredBag(self.bag, run, metrics, acc.orbit_metrics(0))

    def _measure_whole(self, why: str, **settings: Any) -> MeasuredBag:
        """:meth:`measure` on the bag read whole (:func:`~sappc.bag.read.read_bag`)."""
        bag = read_bag(self.path, ticker=self.ticker)
        try:
            run = bag_run(bag, self.duration_s, ticker=self.ticker)
        except BagError as exc:
            return MeasuredBag(bag, None, None, [], problem=str(exc), read_whole=why)
        metrics, per_orbit = bag_metrics(bag, run=run, ticker=self.ticker, **settings)
        return MeasuredBag(bag, run, metrics, per_orbit, read_whole=why)


def figure_sink(t_end_s: float, *, wheels: Any = None) -> FigureSink:
    """The History the figures of a bag read in blocks are drawn from: the bounded envelope
    (:class:`~sappc.evaluation.envelope.HistoryEnvelope`, issue 47 item 3: the whole History of a
    run of at most its ``FULL_RATE_MAX_SAMPLES``, each time bin's extremes of a longer one;
    ``wheels``: the scenario's wheel set, for the extremes of the torque not delivered), or the
    whole History of a run of one sample (no span to bin)."""
    if not t_end_s > 0.0:
        return FullHistory()
    return HistoryEnvelope(t_end_s, wheels=wheels)


def _empty_width(type_name: str) -> int:
    """The columns of a topic of ``type_name`` of which no message decodes (as the whole bag's series has them)."""
    d = decode(type_name, b"", np.zeros(0, np.int64), np.zeros(0, np.int64))
    return 0 if d is None else int(d.values.shape[1])

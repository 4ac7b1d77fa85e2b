"""A lean, sequential MCAP scanner: every message's channel, log time and payload position.

``mcap.stream_reader.StreamReader`` builds one Python object per record and tops out near
95,000 messages per second here; reports need more (issue 5: at least 100,000).  This scanner
reads the file once, decompresses each chunk (zstd, lz4 or none) and walks its records with
``struct`` only, so the per-message cost is one ``unpack_from`` and three list appends.  The
payloads are not copied out: :class:`Scan` keeps the decompressed bytes in one buffer and the
start and length of each payload, for vectorised decoding (:mod:`sappc.bag.cdr`).

It follows the MCAP specification (https://mcap.dev/spec, major version 0): records are
``<opcode u8><length u64><content>``; the fields read here are those of Schema (0x03),
Channel (0x04), Message (0x05), Chunk (0x06) and Metadata (0x0C).  Every other record is
skipped by its length.  CRCs are not checked (a torn file is detected by its lengths and by
the decompressor).  Reading stops at the first record that does not fit in the file or does not
decompress; everything before it is returned and :attr:`Scan.truncated` says why it stopped,
so a bag cut short by a crash yields what was flushed.
"""

from __future__ import annotations

import os
import struct
from typing import Any
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import lz4.frame
import numpy as np
import zstandard
from numpy.typing import NDArray

__all__ = ["MAGIC", "Channel", "McapWalk", "Piece", "Scan", "scan_mcap", "summary_channels"]

#: The 8 bytes that open (and close) an MCAP file of major version 0.
MAGIC = b"\x89MCAP0\r\n"

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_METADATA, _OP_DATA_END = 0x03, 0x04, 0x05, 0x06, 0x0C, 0x0F
#: Opcode (u8) and content length (u64) of every record.
_RECORD_HEAD = struct.Struct("<BQ")
#: Message record: channel id u16, sequence u32, log time u64, publish time u64, then the payload.
_MESSAGE_HEAD = struct.Struct("<HIQQ")
#: Chunk record: message start and end times u64, uncompressed size u64, uncompressed CRC u32.
_CHUNK_HEAD = struct.Struct("<QQQI")
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")


@dataclass(frozen=True)
class Channel:
    """A channel of the file: its topic, the name, encoding and text of its schema."""

    id: int
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    schema_data: bytes = b""  # the schema's text as recorded (ros2msg: the message definition)


@dataclass
class Scan:
    """Every message of an MCAP file, by position in :attr:`buffer`."""

    buffer: bytes  # the uncompressed message records, concatenated
    channel_id: NDArray[np.int64]  # (M,) per message, in file order
    log_time_ns: NDArray[np.int64]  # (M,)
    start: NDArray[np.int64]  # (M,) offset of the payload in ``buffer``
    length: NDArray[np.int64]  # (M,) payload length [bytes]
    channels: dict[int, Channel]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: str | None = None  # why reading stopped early; None when the file is whole

    def payloads(self, channel_id: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """(start, length, log time) of every message of ``channel_id``, in file order."""
        sel = self.channel_id == channel_id
        return self.start[sel], self.length[sel], self.log_time_ns[sel]


def _string(buf: bytes | memoryview, off: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, off)
    end = off + 4 + n
    if end > len(buf):
        raise ValueError("string runs past its record")
    return bytes(buf[off + 4 : end]).decode("utf-8"), end


def _chunk_data(buf: Any, at: int, end: int) -> Any:
    """The records of the chunk record whose body starts at ``at`` in ``buf`` and ends before
    ``end``, decompressed (zstd, lz4 or none), checked against the size its header states."""
    _t0, _t1, size, _crc = _CHUNK_HEAD.unpack_from(buf, at)
    compression, pos = _string(buf, at + 28)
    (n,) = _U64.unpack_from(buf, pos)
    if pos + 8 + n > end:
        raise ValueError("chunk records run past the chunk")
    data = buf[pos + 8 : pos + 8 + n]
    if compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    elif compression == "lz4":
        data = lz4.frame.decompress(data)
    elif compression:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    if len(data) != size:
        raise ValueError(f"chunk decompressed to {len(data)} bytes, its header says {size}")
    return data


def _string_map(buf: bytes | memoryview, off: int) -> tuple[dict[str, str], int]:
    (n,) = _U32.unpack_from(buf, off)
    pos, end = off + 4, off + 4 + n
    out = {}
    while pos < end:
        key, pos = _string(buf, pos)
        out[key], pos = _string(buf, pos)
    return out, end


class _Builder:
    """Accumulates the records of the file as the scan walks it."""

    def __init__(self, progress: Callable[[int, int], object] | None = None) -> None:
        self.progress = progress  # called with (bytes walked, file size) after each chunk
        self.pieces: list[bytes] = []  # buffers holding message payloads
        self.base = 0  # total length of the pieces so far
        self.channel: list[int] = []
        self.log_time: list[int] = []
        self.start: list[int] = []
        self.length: list[int] = []
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, Channel] = {}
        self.metadata: dict[str, dict[str, str]] = {}

    def top_level(self, raw: bytes) -> int:
        """Walk the data section; return the offset where the walk stopped."""
        off, end = 8, len(raw)
        op: int  # struct's unpack_from yields tuple[Any, ...]
        n: int
        while off + 9 <= end:
            op, n = _RECORD_HEAD.unpack_from(raw, off)
            body = off + 9
            nxt = body + n
            if nxt > end:
                break
            if op == _OP_CHUNK:
                self._chunk(raw, body, nxt)
                if self.progress is not None:
                    self.progress(nxt, end)
            elif op == _OP_MESSAGE:  # a message outside any chunk (unchunked writers)
                piece = raw[off:nxt]
                self._walk(piece)
            elif op in (_OP_SCHEMA, _OP_CHANNEL):
                self._definition(op, raw, body)
            elif op == _OP_METADATA:
                name, pos = _string(raw, body)
                self.metadata[name], _ = _string_map(raw, pos)
            elif op == _OP_DATA_END:
                return nxt
            off = nxt
        return off

    def _definition(self, op: int, buf: bytes, body: int) -> None:
        if op == _OP_SCHEMA:
            (sid,) = _U16.unpack_from(buf, body)
            name, pos = _string(buf, body + 2)
            encoding, pos = _string(buf, pos)
            (n,) = _U32.unpack_from(buf, pos)
            if pos + 4 + n > len(buf):
                raise ValueError("schema data runs past its record")
            self.schemas[sid] = (name, encoding, bytes(buf[pos + 4 : pos + 4 + n]))
        else:
            cid, sid = struct.unpack_from("<HH", buf, body)
            topic, pos = _string(buf, body + 4)
            msg_enc, _ = _string(buf, pos)
            name, enc, data = self.schemas.get(sid, ("", "", b""))  # schema id 0: none
            self.channels[cid] = Channel(cid, topic, name, enc, msg_enc, data)

    def _walk(self, buf: bytes) -> None:
        """Walk the whole records of ``buf`` (a chunk's content); keep ``buf`` if it holds messages."""
        off, end, base = 0, len(buf), self.base
        unpack_head, unpack_msg = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
        channel, log_time, start, length = self.channel, self.log_time, self.start, self.length
        before = len(start)
        try:
            while off + 9 <= end:
                op, n = unpack_head(buf, off)
                body = off + 9
                nxt = body + n
                if nxt > end:
                    raise ValueError(f"a record runs past the end of its chunk (offset {off})")
                if op == _OP_MESSAGE:
                    if n < 22:
                        raise ValueError(f"message record of {n} bytes")
                    ch, _seq, log_t, _pub = unpack_msg(buf, body)
                    channel.append(ch)
                    log_time.append(log_t)
                    start.append(base + body + 22)
                    length.append(n - 22)
                elif op in (_OP_SCHEMA, _OP_CHANNEL):
                    self._definition(op, buf, body)
                off = nxt
        except (ValueError, struct.error):
            # none of the chunk's messages: their payloads are in no kept buffer (reading stops here)
            for column in (channel, log_time, start, length):
                del column[before:]
            raise
        if len(start) > before:
            self.pieces.append(buf)
            self.base += len(buf)

    def _chunk(self, raw: bytes, body: int, end: int) -> None:
        self._walk(_chunk_data(raw, body, end))


#: The footer record (opcode, length, summary start u64, summary offset start u64, CRC u32) and the
#: closing magic: the last bytes of a whole MCAP file.
_OP_FOOTER = 0x02
_FOOTER_BYTES = 9 + 20 + 8


def summary_channels(path: str | Path) -> dict[int, Channel] | None:
    """The channels of the MCAP file's summary section (its schema and channel records, read
    without the data section), by id; ``None`` when the file has none (a bag cut short: its
    channels are those :class:`McapWalk` has walked once exhausted)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size < len(MAGIC) + _FOOTER_BYTES:
            return None
        f.seek(size - _FOOTER_BYTES)
        tail = f.read(_FOOTER_BYTES)
        op, n = _RECORD_HEAD.unpack_from(tail, 0)
        if tail[-8:] != MAGIC or op != _OP_FOOTER or n != 20:
            return None
        start, offsets_start = struct.unpack_from("<QQ", tail, 9)
        end = offsets_start or size - _FOOTER_BYTES
        if start == 0 or not len(MAGIC) <= start <= end <= size - _FOOTER_BYTES:
            return None
        f.seek(start)
        summary = f.read(end - start)
    defs, off = _Builder(), 0
    while off + 9 <= len(summary):
        op, n = _RECORD_HEAD.unpack_from(summary, off)
        if off + 9 + n > len(summary):
            return None
        if op in (_OP_SCHEMA, _OP_CHANNEL):
            defs._definition(op, summary, off + 9)
        off += 9 + n
    return defs.channels or None


def scan_mcap(path: str | Path, *, progress: Callable[[int, int], object] | None = None) -> Scan:
    """Scan the MCAP file at ``path`` (see the module docstring); ``progress``, when given, is
    called with the bytes walked so far and the file's size once the file is read and after each
    chunk (a long bag's read-back shows how far it is: issue 46).

    Raises
    ------
    ValueError
        If the file does not start with the MCAP magic.
    """
    raw = Path(path).read_bytes()
    if raw[:8] != MAGIC:
        raise ValueError(f"{path}: not an MCAP file (no MCAP magic at the start)")
    b = _Builder(progress)
    if progress is not None:
        progress(0, len(raw))
    truncated: str | None = None
    try:
        end = b.top_level(raw)
        # a whole file ends with a footer record and the magic; anything else means it was cut
        if raw[-8:] != MAGIC and end < len(raw):
            truncated = f"the file ends inside a record at byte {end} of {len(raw)}"
        elif raw[-8:] != MAGIC:
            truncated = f"the file ends after {len(raw)} bytes without its footer"
    except (ValueError, struct.error, zstandard.ZstdError, RuntimeError) as exc:  # lz4 raises RuntimeError
        truncated = f"unreadable record ({type(exc).__name__}: {exc})"
    buffer = b"".join(b.pieces)
    return Scan(
        buffer=buffer,
        channel_id=np.asarray(b.channel, dtype=np.int64),
        log_time_ns=np.asarray(b.log_time, dtype=np.int64),
        start=np.asarray(b.start, dtype=np.int64),
        length=np.asarray(b.length, dtype=np.int64),
        channels=b.channels,
        metadata=b.metadata,
        truncated=truncated,
    )


# ---- the file a chunk at a time -----------------------------------------------------------------

_OP_MESSAGE_INDEX = 0x07
#: Message index record: channel id u16, then the byte length u32 of its (log time u64, offset u64) pairs.
_MESSAGE_INDEX_HEAD = struct.Struct("<HI")
#: Bytes of a message record before its payload: opcode u8, length u64, channel id u16, sequence
#: u32, log time u64, publish time u64.
_MESSAGE_PAYLOAD_AT = 9 + 22
#: The file's read buffer [bytes]: records are read in file order, a few at a time.
_READ_BUFFER_BYTES = 1 << 20


@dataclass
class Piece:
    """The messages of one chunk (or of one message outside any chunk), in file order."""

    data: bytes  # the chunk's uncompressed records
    channel_id: NDArray[np.int64]  # (m,)
    log_time_ns: NDArray[np.int64]  # (m,)
    start: NDArray[np.int64]  # (m,) offset of each payload in ``data``
    length: NDArray[np.int64]  # (m,) payload length [bytes]
    walked: int  # bytes of the file walked up to the end of this piece


class McapWalk:
    """The messages of an MCAP file a chunk at a time (:meth:`pieces`): the same messages, channels,
    metadata and end as :func:`scan_mcap`'s, in the same order, without reading the file whole or
    keeping what was walked (``sappc.bag.blocks``: a bag of 16.5 million messages, 756 MB).

    A chunk's messages are found from the message index records that follow it (where the writer
    wrote them: rosbag2 and the ``mcap`` package do): their records are read as columns, with no
    Python per message; the records between them (schemas and channels) are walked.  A chunk whose
    index does not account for each of its records exactly is walked record by record, as
    :func:`scan_mcap` walks every chunk.  :attr:`channels`, :attr:`metadata` and
    :attr:`truncated` are those of the records walked so far (all of them once :meth:`pieces` is
    exhausted)."""

    def __init__(self, path: str | Path, *, progress: Callable[[int, int], object] | None = None) -> None:
        self.path = Path(path)
        self.progress = progress
        self._defs = _Builder()  # its schemas, channels and metadata; its message lists stay empty
        self.truncated: str | None = None
        self.size = 0  # the file's bytes

    @property
    def channels(self) -> dict[int, Channel]:
        return self._defs.channels

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        return self._defs.metadata

    def pieces(self) -> Iterator[Piece]:
        """Every chunk's messages (chunks without messages skipped), then :attr:`truncated` set.

        Raises
        ------
        ValueError
            If the file does not start with the MCAP magic.
        """
        with open(self.path, "rb", buffering=_READ_BUFFER_BYTES) as f:
            size = self.size = os.fstat(f.fileno()).st_size
            if f.read(8) != MAGIC:
                raise ValueError(f"{self.path}: not an MCAP file (no MCAP magic at the start)")
            f.seek(max(size - 8, 0))
            tail = f.read(8)
            f.seek(8)
            if self.progress is not None:
                self.progress(0, size)
            off = 8
            pending: tuple[bytes, list[NDArray[np.int64]], int] | None = None  # a chunk's record, its index's offsets, its end
            try:
                while off + 9 <= size:
                    op, n = _RECORD_HEAD.unpack(f.read(9))
                    body = off + 9
                    nxt = body + n
                    if nxt > size:
                        break
                    if op == _OP_MESSAGE_INDEX and pending is not None:
                        pending[1].append(_index_offsets(f.read(n)))
                        off = nxt
                        continue
                    if pending is not None:
                        yield from self._chunk(*pending)
                        pending = None
                    if op == _OP_CHUNK:
                        pending = (f.read(n), [], nxt)
                    elif op == _OP_MESSAGE:  # a message outside any chunk (unchunked writers)
                        piece = _RECORD_HEAD.pack(op, n) + f.read(n)
                        yield from self._walked(piece, nxt)
                    elif op in (_OP_SCHEMA, _OP_CHANNEL):
                        self._defs._definition(op, f.read(n), 0)
                    elif op == _OP_METADATA:
                        record = f.read(n)
                        name, pos = _string(record, 0)
                        self._defs.metadata[name], _ = _string_map(record, pos)
                    elif op == _OP_DATA_END:
                        off = nxt
                        break
                    else:
                        f.seek(n, os.SEEK_CUR)
                    off = nxt
                if pending is not None:
                    yield from self._chunk(*pending)
                    pending = None
                # a whole file ends with a footer record and the magic; anything else means it was cut
                if tail != MAGIC and off < size:
                    self.truncated = f"the file ends inside a record at byte {off} of {size}"
                elif tail != MAGIC:
                    self.truncated = f"the file ends after {size} bytes without its footer"
            except (ValueError, struct.error, zstandard.ZstdError, RuntimeError) as exc:  # lz4 raises RuntimeError
                self.truncated = f"unreadable record ({type(exc).__name__}: {exc})"

    def _chunk(self, record: bytes, offsets: list[NDArray[np.int64]], end: int) -> Iterator[Piece]:
        """The messages of a chunk record (its content, decompressed as :func:`scan_mcap` does)."""
        data = _chunk_data(record, 0, len(record))
        indexed = self._indexed(data, offsets)
        if indexed is None:
            yield from self._walked(data, end)
        elif indexed[0].size:
            channel_id, log_time, start, length = indexed
            yield Piece(data, channel_id, log_time, start, length, walked=end)
        if self.progress is not None:
            self.progress(end, self.size)

    def _walked(self, data: bytes, end: int) -> Iterator[Piece]:
        """The messages of ``data`` walked record by record (:func:`scan_mcap`'s walk, errors included)."""
        b = self._defs
        b.channel, b.log_time, b.start, b.length, b.pieces, b.base = [], [], [], [], [], 0
        b._walk(data)
        if b.start:
            yield Piece(data, np.asarray(b.channel, np.int64), np.asarray(b.log_time, np.int64), np.asarray(b.start, np.int64),
                        np.asarray(b.length, np.int64), walked=end)
        b.channel, b.log_time, b.start, b.length, b.pieces = [], [], [], [], []

    def _indexed(self, data: bytes, offsets: list[NDArray[np.int64]]
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]] | None:
        """(channel id, log time, payload start, payload length) of every message of ``data`` from
        the chunk's message index (``offsets``: of each message record), when the index accounts for
        every message record exactly (each record at an offset is a whole message of the chunk; the
        records between them, walked, are none); ``None`` otherwise (the chunk is then walked)."""
        if not offsets:
            return None
        o = np.sort(np.concatenate(offsets))
        size = len(data)
        if o.size == 0 or o[0] < 0 or o[-1] + _MESSAGE_PAYLOAD_AT > size or np.any(o[1:] == o[:-1]):
            return None
        u8 = np.frombuffer(data, np.uint8)

        def column(at: int, width: int, dtype: str) -> NDArray[np.int64]:
            return np.ascontiguousarray(u8[(o + at)[:, None] + np.arange(width)]).view(dtype)[:, 0].astype(np.int64)

        if np.any(u8[o] != _OP_MESSAGE):
            return None
        n = np.ascontiguousarray(u8[(o + 1)[:, None] + np.arange(8)]).view("<u8")[:, 0]
        if np.any(n < 22) or np.any(n > size):
            return None
        ends = o + 9 + n.astype(np.int64)
        if ends[-1] > size or np.any(o[1:] < ends[:-1]):
            return None
        # the records between the messages (and before the first, after the last): walked
        gaps = np.flatnonzero(o[1:] != ends[:-1])
        regions = [(0, int(o[0]))] + [(int(ends[g]), int(o[g + 1])) for g in gaps] + [(int(ends[-1]), size)]
        for lo, hi in regions:
            if not self._between(data, lo, hi, last=hi == size):
                return None
        return column(9, 2, "<u2"), column(15, 8, "<u8"), o + _MESSAGE_PAYLOAD_AT, n.astype(np.int64) - 22

    def _between(self, data: bytes, lo: int, hi: int, *, last: bool) -> bool:
        """Walk the records of ``data[lo:hi]`` (definitions read): False when one is a message or
        they do not end at ``hi`` (``last``: the chunk's end, where the walk stops as :func:`scan_mcap`'s)."""
        off = lo
        while off + 9 <= hi:
            op, n = _RECORD_HEAD.unpack_from(data, off)
            nxt = off + 9 + n
            if nxt > hi or op == _OP_MESSAGE:
                return False
            if op in (_OP_SCHEMA, _OP_CHANNEL):
                self._defs._definition(op, data, off + 9)
            off = nxt
        return off == hi or last


def _index_offsets(record: bytes) -> NDArray[np.int64]:
    """The message record offsets of a message index record (none when it does not parse: the
    chunk is then walked)."""
    if len(record) < _MESSAGE_INDEX_HEAD.size:
        return np.zeros(0, np.int64)
    _channel, n = _MESSAGE_INDEX_HEAD.unpack_from(record, 0)
    if n % 16 or _MESSAGE_INDEX_HEAD.size + n > len(record):
        return np.full(1, -1, np.int64)  # an impossible offset: the index is not used
    pairs = np.frombuffer(record, "<u8", count=n // 8, offset=_MESSAGE_INDEX_HEAD.size)
    return pairs[1::2].astype(np.int64)

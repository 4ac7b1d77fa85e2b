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

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import lz4.frame
import numpy as np
import zstandard
from numpy.typing import NDArray

__all__ = ["MAGIC", "Channel", "Scan", "scan_mcap"]

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
    """A channel of the file: its topic and the name and encoding of its schema."""

    id: int
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str


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
        self.schemas: dict[int, tuple[str, str]] = {}
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
            encoding, _ = _string(buf, pos)
            self.schemas[sid] = (name, encoding)
        else:
            cid, sid = struct.unpack_from("<HH", buf, body)
            topic, pos = _string(buf, body + 4)
            msg_enc, _ = _string(buf, pos)
            name, enc = self.schemas.get(sid, ("", ""))
            self.channels[cid] = Channel(cid, topic, name, enc, msg_enc)

    def _walk(self, buf: bytes) -> None:
        """Walk the whole records of ``buf`` (a chunk's content); keep ``buf`` if it holds messages."""
        off, end, base = 0, len(buf), self.base
        unpack_head, unpack_msg = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
        channel, log_time, start, length = self.channel, self.log_time, self.start, self.length
        before = len(start)
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
        if len(start) > before:
            self.pieces.append(buf)
            self.base += len(buf)

    def _chunk(self, raw: bytes, body: int, end: int) -> None:
        _t0, _t1, size, _crc = _CHUNK_HEAD.unpack_from(raw, body)
        compression, pos = _string(raw, body + 28)
        (n,) = _U64.unpack_from(raw, pos)
        if pos + 8 + n > end:
            raise ValueError("chunk records run past the chunk")
        data = raw[pos + 8 : pos + 8 + n]
        if compression == "zstd":
            data = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            data = lz4.frame.decompress(data)
        elif compression:
            raise ValueError(f"unsupported chunk compression {compression!r}")
        if len(data) != size:
            raise ValueError(f"chunk decompressed to {len(data)} bytes, its header says {size}")
        self._walk(data)


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

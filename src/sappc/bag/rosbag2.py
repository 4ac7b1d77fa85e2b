"""The rosbag2 directory layout the project writes, and ``sappc repair``: a bag made whole again.

A bag is a rosbag2 version 9 directory: one MCAP file (profile ``ros2``) and ``metadata.yaml``
(:func:`bag_metadata`).  The recorder (:mod:`sappc.graph.recorder`) writes both; when it is killed
(SIGKILL, power loss) the MCAP file has no summary and no footer, and ``metadata.yaml`` still holds
the counts of its start.  Readers that need the footer (rosbags, mcap's indexed reader) then read
nothing, although every chunk the recorder flushed (every :data:`~sappc.graph.recorder.FLUSH_PERIOD_S`)
is intact.

:func:`repair` does what ``ros2 bag reindex`` does for rosbag2: it reads the file record by record
up to the first torn record, and writes the same schemas, channels, messages (with their log and
publish times and sequence numbers) and metadata records into a complete MCAP file (summary,
indexes, footer), then a ``metadata.yaml`` with the counts and times of what it holds.  The
original file is replaced only once the new one is complete (write, fsync, rename).
"""

from __future__ import annotations

import heapq
import os
import struct
import tempfile
from struct import error as StructError  # a record cut inside its fields
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from sappc.bag.errors import BagError
from sappc_msgs_py.contract import QOS_DEPTH
from sappc_msgs_py.schemas import type_hash

__all__ = ["BAG_METADATA", "MESSAGE_OVERHEAD_BYTES", "SORT_MEMORY_BYTES", "RepairResult", "bag_metadata", "offered_qos_v9", "repair", "sort_by_log_time", "write_bag_metadata"]

#: Name of the rosbag2 metadata file.
BAG_METADATA = "metadata.yaml"
#: Memory the closing sort holds in messages at once [bytes] (:func:`sort_by_log_time`): 32 MiB,
#: a sixth of the recorder's 200 MB budget (issue 25), about 5 min of experiment 1's 1,100
#: messages per simulated second; a 10-min run is sorted in a few runs.
SORT_MEMORY_BYTES = 32 * 1024 * 1024
#: What a message held for the sort costs beyond its data [bytes]: on CPython 3.11 (sys.getsizeof)
#: the 5-field record tuple 80, two 64-bit times 32 each, the sequence 28, the bytes object's
#: header 33 and the list's pointer 8, 213 in all, rounded up.
MESSAGE_OVERHEAD_BYTES = 256
#: A run file's record header: log time, channel id, sequence, publish time, data length (the MCAP
#: message record's field widths).
_RUN_HEADER = struct.Struct("<QHIQI")
#: Read buffer of each run file during the merge [bytes]: the merge holds one per run.
_RUN_READ_BUFFER_BYTES = 64 * 1024


class _Record(NamedTuple):
    """A message of the sort: the MCAP message record's fields."""

    log_time: int
    channel_id: int
    sequence: int
    publish_time: int
    data: bytes


def offered_qos_v9() -> list[dict[str, Any]]:
    """The offered QoS of every project publisher, in rosbag2's version 9 layout."""
    zero = {"sec": 0, "nsec": 0}
    return [
        {
            "history": "keep_last",
            "depth": QOS_DEPTH,
            "reliability": "reliable",
            "durability": "volatile",
            "deadline": zero,
            "lifespan": zero,
            "liveliness": "automatic",
            "liveliness_lease_duration": zero,
            "avoid_ros_namespace_conventions": False,
        }
    ]


def bag_metadata(mcap_name: str, topics: list[tuple[str, str]], counts: dict[str, int], start_ns: int, end_ns: int, custom: dict[str, str]) -> dict[str, Any]:
    """The rosbag2 version 9 ``metadata.yaml`` content for one MCAP file.

    Parameters
    ----------
    mcap_name : the MCAP file's name in the bag directory.
    topics : (resolved topic name, ROS type name) of every channel.
    counts : messages per topic.
    start_ns, end_ns : log times of the first and last message [ns since the epoch].
    custom : rosbag2 ``custom_data`` (the project: metadata record name -> copied file name).
    """
    total = sum(counts.values())
    duration = max(0, end_ns - start_ns)
    return {
        "rosbag2_bagfile_information": {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [mcap_name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start_ns},
            "message_count": total,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": name,
                        "type": type_name,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": offered_qos_v9(),
                        "type_description_hash": type_hash(type_name),
                    },
                    "message_count": counts.get(name, 0),
                }
                for name, type_name in topics
            ],
            "compression_format": "",
            "compression_mode": "",
            "files": [
                {"path": mcap_name, "starting_time": {"nanoseconds_since_epoch": start_ns}, "duration": {"nanoseconds": duration}, "message_count": total}
            ],
            "custom_data": custom or None,
            "ros_distro": "jazzy",
        }
    }


def write_bag_metadata(bag_dir: Path, meta: dict[str, Any]) -> None:
    """Write ``metadata.yaml`` atomically (a reader never sees half a file)."""
    tmp = bag_dir / (BAG_METADATA + ".tmp")
    tmp.write_text(yaml.safe_dump(meta, sort_keys=False))
    tmp.replace(bag_dir / BAG_METADATA)


@dataclass(frozen=True)
class RepairResult:
    """What :func:`repair` found and wrote.

    Attributes
    ----------
    path : the repaired MCAP file.
    was_complete : the file already had its footer (nothing was rewritten but ``metadata.yaml``).
    messages : messages in the repaired file.
    counts : messages per topic.
    stopped_at : why reading stopped (a torn record at the end of a killed recording), or ``None``.
    first_ns, last_ns : log times of the first and last message kept [ns since the epoch].
    """

    path: Path
    was_complete: bool
    messages: int
    counts: dict[str, int]
    stopped_at: str | None
    first_ns: int
    last_ns: int


def _has_footer(path: Path) -> bool:
    from sappc.bag.mcap_scan import MAGIC

    size = path.stat().st_size
    if size < 2 * len(MAGIC):
        return False
    with path.open("rb") as f:
        f.seek(size - len(MAGIC))
        return f.read(len(MAGIC)) == MAGIC


def _read_records(path: Path) -> tuple[dict[int, Any], dict[int, Any], list[Any], list[Any], str | None]:
    """Every schema, channel, metadata and message record of an MCAP file that can be read, and
    where reading stopped (``None``: the whole file)."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[Metadata] = []
    messages: list[Message] = []
    stopped_at: str | None = None
    try:
        with path.open("rb") as f:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Message):
                    messages.append(record)
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    metadata.append(record)
    except (McapError, EOFError, ValueError, OSError, StructError) as exc:  # the torn tail of a killed recording
        stopped_at = f"{type(exc).__name__}: {exc}"
    return schemas, channels, metadata, messages, stopped_at


def _write_records(path: Path, schemas: dict[int, Any], channels: dict[int, Any], metadata: list[tuple[str, dict[str, str]]],
                   messages: Iterable[Any], library: str, chunk_size: int | None = None) -> None:
    """Write the records as a new MCAP file (zstd chunks), in the order given, then replace ``path`` with it."""
    from mcap.writer import CompressionType, Writer

    tmp = path.with_name(path.name + ".rewrite.tmp")
    with tmp.open("wb") as out:
        writer = Writer(out, compression=CompressionType.ZSTD) if chunk_size is None else Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library=library)
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in schemas.items()}
        channel_ids = {cid: writer.register_channel(ch.topic, ch.message_encoding, schema_ids.get(ch.schema_id, 0), ch.metadata)
                       for cid, ch in channels.items()}
        for name, data in metadata:
            writer.add_metadata(name, data)
        for m in messages:
            writer.add_message(channel_ids[m.channel_id], log_time=m.log_time, data=m.data, publish_time=m.publish_time, sequence=m.sequence)
        writer.finish()
        out.flush()
        os.fsync(out.fileno())
    tmp.replace(path)


def _order(m: _Record) -> tuple[int, int, int]:
    """The sort key of a message: (log time, channel id, sequence)."""
    return m.log_time, m.channel_id, m.sequence


def _spill(run: list[_Record], directory: Path, index: int) -> Path:
    """Sort ``run`` and write it to a run file in ``directory``; the file's path."""
    run.sort(key=_order)  # stable: equal keys keep the file's order
    path = directory / f"run{index:05d}"
    with path.open("wb") as f:
        for m in run:
            f.write(_RUN_HEADER.pack(m.log_time, m.channel_id, m.sequence, m.publish_time, len(m.data)))
            f.write(m.data)
    return path


def _read_run(path: Path) -> Iterator[_Record]:
    """The messages of a run file, in its (sorted) order."""
    with path.open("rb", buffering=_RUN_READ_BUFFER_BYTES) as f:
        while header := f.read(_RUN_HEADER.size):
            log_time, channel_id, sequence, publish_time, size = _RUN_HEADER.unpack(header)
            yield _Record(log_time, channel_id, sequence, publish_time, f.read(size))


def sort_by_log_time(path: str | Path, *, chunk_size: int | None = None, library: str = "sappc (mcap-python)",
                     memory_bytes: int = SORT_MEMORY_BYTES) -> int:
    """Rewrite a complete MCAP file with its messages in (log time, channel, sequence) order.

    What the lockstep recorder does when it closes a bag on simulated time: the file then depends
    only on what was recorded, not on the order the topics' messages arrived in.  Schemas,
    channels and metadata keep their ids and order.  Returns the number of messages.

    Memory is bounded, whatever the bag's length: an external merge sort.  The file is read once,
    its messages cut into runs of about ``memory_bytes`` (data plus
    :data:`MESSAGE_OVERHEAD_BYTES` each), each run sorted and written to a temporary file beside
    the bag, then the runs are merged (:func:`heapq.merge`, stable) straight into the new file.
    The result is the same file, byte for byte, as sorting every message in memory (equal keys
    keep the order they had in the file in both).

    Raises
    ------
    BagError
        If the file cannot be read whole (a killed recording: ``sappc repair`` it first).
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    if memory_bytes <= 0:
        raise ValueError(f"memory_bytes must be > 0, got {memory_bytes!r}")
    file = Path(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[tuple[str, dict[str, str]]] = []
    count = 0
    with tempfile.TemporaryDirectory(dir=file.parent, prefix=f".{file.name}.sort-") as tmp:
        runs: list[Path] = []
        run: list[_Record] = []
        held = 0
        try:
            with file.open("rb") as f:
                for record in StreamReader(f, validate_crcs=True).records:
                    if isinstance(record, Message):
                        run.append(_Record(record.log_time, record.channel_id, record.sequence, record.publish_time, record.data))
                        held += len(record.data) + MESSAGE_OVERHEAD_BYTES
                        count += 1
                        if held >= memory_bytes:
                            runs.append(_spill(run, Path(tmp), len(runs)))
                            run, held = [], 0
                    elif isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Metadata):
                        metadata.append((record.name, record.metadata))
        except (McapError, EOFError, ValueError, OSError, StructError) as exc:
            raise BagError(f"{file}: cannot sort an incomplete file ({type(exc).__name__}: {exc})") from None
        if run:
            runs.append(_spill(run, Path(tmp), len(runs)))
        del run
        _write_records(file, schemas, channels, metadata, heapq.merge(*(_read_run(r) for r in runs), key=_order), library, chunk_size)
    return count


def repair(bag: str | Path) -> RepairResult:
    """Make the bag at ``bag`` (a rosbag2 directory or an ``.mcap`` file) readable by every MCAP
    and rosbag2 reader again; see the module docstring.

    Raises
    ------
    BagError
        If ``bag`` is not a bag, or not even its first records can be read.
    """
    from sappc.bag.read import mcap_file  # the readers, only here: the recorder imports this module

    path = mcap_file(Path(bag))
    bag_dir = path.parent if Path(bag).is_dir() else None
    complete = _has_footer(path)
    schemas, channels, metadata, messages, stopped_at = _read_records(path)
    if not channels:
        raise BagError(f"{path}: no channel could be read (is it an MCAP file?{' ' + stopped_at if stopped_at else ''})")
    messages = [m for m in messages if m.channel_id in channels]
    counts = {ch.topic: 0 for ch in channels.values()}
    for m in messages:
        counts[channels[m.channel_id].topic] += 1
    first_ns = min((m.log_time for m in messages), default=0)
    last_ns = max((m.log_time for m in messages), default=0)

    topics = [(ch.topic, schemas[ch.schema_id].name) for ch in channels.values() if ch.schema_id in schemas]
    custom = {md.name: md.name.split("/", 1)[1] for md in metadata if md.name.startswith("sappc/")}
    meta = bag_metadata(path.name, topics, counts, first_ns, last_ns, custom)
    if not complete:
        extra = [] if any(md.name == "rosbag2" for md in metadata) else [  # what the recorder writes when it closes the bag
            ("rosbag2", {"serialized_metadata": yaml.safe_dump(meta["rosbag2_bagfile_information"], sort_keys=False)})]
        _write_records(path, schemas, channels, [*[(md.name, md.metadata) for md in metadata], *extra], messages, "sappc repair (mcap-python)")
    if bag_dir is not None:
        write_bag_metadata(bag_dir, meta)
    return RepairResult(path=path, was_complete=complete, messages=len(messages), counts=counts, stopped_at=stopped_at,
                        first_ns=first_ns, last_ns=last_ns)

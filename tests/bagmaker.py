"""Synthetic MCAP bags for tests, written with the ``mcap`` package's own writer and rclpy's
serializer (independent of the project's recorder and reader)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, IndexType, Writer
from rclpy.serialization import serialize_message

from sappc_msgs_py.schemas import schema_text


def write_bag(path: Path, messages: list[tuple[str, str, Any, int]], *, compression: str = "zstd", chunk_size: int = 4096,
              use_chunking: bool = True, metadata: dict[str, dict[str, str]] | None = None, indexed: bool = True) -> Path:
    """Write ``messages`` = [(topic, type name, message, log time ns)] to the MCAP file ``path``
    (``indexed`` false: no message indexes and no summary offsets, each chunk to be walked)."""
    kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=kinds[compression], use_chunking=use_chunking,
                   index_types=IndexType.ALL if indexed else IndexType.NONE, use_summary_offsets=indexed)
        w.start(profile="ros2", library="tests/bagmaker")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, type_name, msg, log_ns in messages:
            if type_name not in schemas:
                schemas[type_name] = w.register_schema(type_name, "ros2msg", schema_text(type_name).encode())
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "cdr", schemas[type_name])
            w.add_message(channels[topic], log_time=log_ns, data=serialize_message(msg), publish_time=log_ns)
        for name, data in (metadata or {}).items():
            w.add_metadata(name, data)
        w.finish()
    return path

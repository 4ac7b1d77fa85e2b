"""The lockstep recorder's closing sort (:func:`sappc.bag.rosbag2.sort_by_log_time`) in bounded
memory (issue 25, defect 7): an external merge sort that writes the same file, byte for byte, as
sorting every message in memory, while holding a fraction of the bag's messages."""

from __future__ import annotations

import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from sappc.bag import rosbag2
from sappc.bag.read import BagError
from sappc.bag.rosbag2 import _read_records, _write_records, sort_by_log_time

#: The synthetic bag: messages, their data size [bytes] and channels (about 10 MB of data).
_N_MESSAGES, _DATA_BYTES, _N_CHANNELS = 40_000, 250, 6
#: The sort's memory budget in the test [bytes]: a tenth of the bag's data, so it sorts in many runs.
_BUDGET_BYTES = 1024 * 1024
#: Chunk size of the bags written here [bytes] (the recorder's).
_CHUNK_BYTES = 256 * 1024


def _shuffled_bag(path: Path, seed: int) -> Path:
    """An MCAP file whose messages are in no order of log time: each channel's stamps run ahead and
    behind the others' (as the recorder receives them under load), with ties on the log time
    across channels and, on one channel, equal (log time, sequence) pairs (kept in file order)."""
    rng = np.random.default_rng(seed)
    log_ns = rng.integers(0, 2_000, _N_MESSAGES) * 10_000_000  # many messages share a stamp
    channel = rng.integers(0, _N_CHANNELS, _N_MESSAGES)
    with path.open("wb") as f:
        w = Writer(f, chunk_size=_CHUNK_BYTES, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="tests/test_sort")
        sid = w.register_schema("std_msgs/msg/Float64MultiArray", "ros2msg", b"float64[] data")
        cids = [w.register_channel(f"/topic{k}", "cdr", sid) for k in range(_N_CHANNELS)]
        w.add_metadata("sappc/scenario.yaml", {"text": "duration_s: 1"})
        sequence = [0] * _N_CHANNELS
        for i in range(_N_MESSAGES):
            c = int(channel[i])
            sequence[c] += c != 0  # channel 0: every message has sequence 0 (ties, stable order)
            w.add_message(cids[c], log_time=int(log_ns[i]), publish_time=int(log_ns[i]), sequence=sequence[c],
                          data=rng.bytes(_DATA_BYTES))
        w.add_metadata("rosbag2", {"serialized_metadata": "closing"})
        w.finish()
    return path


def _sorted_in_memory(path: Path) -> None:
    """The sort as it was before issue 25: every message read, sorted and written at once."""
    schemas, channels, metadata, messages, stopped_at = _read_records(path)
    assert stopped_at is None
    messages.sort(key=lambda m: (m.log_time, m.channel_id, m.sequence))
    _write_records(path, schemas, channels, [(md.name, md.metadata) for md in metadata], messages, "tests/test_sort", _CHUNK_BYTES)


def _peak_bytes(call) -> int:  # type: ignore[no-untyped-def]
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_the_bounded_sort_writes_the_in_memory_sorts_file_in_a_fraction_of_its_memory(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    bag = _shuffled_bag(tmp_path / "bag.mcap", seed=2511)
    in_memory, bounded = tmp_path / "in_memory.mcap", tmp_path / "bounded.mcap"
    shutil.copyfile(bag, in_memory)
    shutil.copyfile(bag, bounded)
    runs: list[int] = []
    spill = rosbag2._spill
    monkeypatch.setattr(rosbag2, "_spill", lambda run, directory, index: (runs.append(len(run)), spill(run, directory, index))[1])

    peak_in_memory = _peak_bytes(lambda: _sorted_in_memory(in_memory))
    peak_bounded = _peak_bytes(lambda: sort_by_log_time(bounded, chunk_size=_CHUNK_BYTES, library="tests/test_sort", memory_bytes=_BUDGET_BYTES))

    assert bounded.read_bytes() == in_memory.read_bytes()
    assert bounded.read_bytes() != bag.read_bytes()  # it was not in order
    data_bytes = _N_MESSAGES * _DATA_BYTES
    assert len(runs) >= data_bytes // _BUDGET_BYTES and sum(runs) == _N_MESSAGES
    assert peak_in_memory > data_bytes  # what the bounded sort avoids: the whole bag's data at once
    # the budget, one read buffer per run, the source's and the new file's chunks (compressed and
    # not, twice each), and 1 MiB for the interpreter's own allocations
    bound = _BUDGET_BYTES + len(runs) * rosbag2._RUN_READ_BUFFER_BYTES + 4 * _CHUNK_BYTES + 1024 * 1024
    assert peak_bounded < bound < data_bytes / 2, (peak_bounded, bound)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # the run files are gone


def test_the_sort_refuses_an_incomplete_file_and_a_budget_of_nothing(tmp_path) -> None:  # type: ignore[no-untyped-def]
    bag = _shuffled_bag(tmp_path / "bag.mcap", seed=1)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(BagError, match="cannot sort an incomplete file"):
        sort_by_log_time(torn)
    assert torn.read_bytes() == bag.read_bytes()[: bag.stat().st_size // 2]  # left as it was
    with pytest.raises(ValueError, match="memory_bytes must be > 0, got 0"):
        sort_by_log_time(bag, memory_bytes=0)


#: What a held message costs beyond its data, as docs/recorder.md states it [bytes].
_OVERHEAD_BYTES = 256


def _bag_of_sizes(path: Path, sizes: list[int]) -> Path:
    """An MCAP file of one channel whose messages hold ``sizes`` bytes of data, in reverse stamp order."""
    with path.open("wb") as f:
        w = Writer(f, chunk_size=_CHUNK_BYTES, compression=CompressionType.NONE)
        w.start(profile="ros2", library="tests/test_sort")
        cid = w.register_channel("/t", "cdr", w.register_schema("std_msgs/msg/UInt8MultiArray", "ros2msg", b"uint8[] data"))
        for k, size in enumerate(sizes):
            stamp = (len(sizes) - k) * 1_000_000
            w.add_message(cid, log_time=stamp, publish_time=stamp, sequence=k, data=bytes([k % 251]) * size)
        w.finish()
    return path


def _runs_of_sort(path: Path, monkeypatch: pytest.MonkeyPatch, **kwargs: int) -> list[int]:
    """Sort ``path``; the number of messages of each run the sort cut, in order."""
    runs: list[int] = []
    spill = rosbag2._spill
    monkeypatch.setattr(rosbag2, "_spill", lambda run, directory, index: (runs.append(len(run)), spill(run, directory, index))[1])
    assert sort_by_log_time(path, chunk_size=_CHUNK_BYTES, library="tests/test_sort", **kwargs) == sum(runs)
    return runs


def test_a_run_is_cut_as_soon_as_the_messages_held_reach_the_budget(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The memory rule (docs/recorder.md): each held message counts its data plus 256 bytes, and a
    run is cut when the count reaches the budget, not before (one byte short holds one message more)
    and not after; every run starts from nothing."""
    budget = 10_000
    short = budget - 1 - 2 * _OVERHEAD_BYTES  # two messages one byte short of the budget
    exact = budget - 2 * _OVERHEAD_BYTES  # two messages that reach it exactly
    sizes = [short // 2, short - short // 2, 100, exact // 2, exact - exact // 2, short // 2, short - short // 2, 100]
    bag = _bag_of_sizes(tmp_path / "bag.mcap", sizes)
    reference = shutil.copyfile(bag, tmp_path / "in_memory.mcap")
    _sorted_in_memory(reference)
    assert _runs_of_sort(bag, monkeypatch, memory_bytes=budget) == [3, 2, 3]
    assert bag.read_bytes() == reference.read_bytes()


def test_the_default_budget_is_32_mib(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The recorder's closing sort holds 32 MiB of messages (docs/recorder.md): two messages that
    reach it exactly make a run of their own."""
    half = 16 * 1024 * 1024 - _OVERHEAD_BYTES
    assert _runs_of_sort(_bag_of_sizes(tmp_path / "bag.mcap", [half, half, 10]), monkeypatch) == [2, 1]

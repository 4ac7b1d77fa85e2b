"""Read a recorded bag back into arrays, and compute a run's metrics from it.

Works on any bag that follows the topic contract (``sappc run``'s, or a user plant's): a rosbag2
directory with ``metadata.yaml`` and an MCAP file, or a bare ``.mcap`` file.  The file is read
sequentially, so a bag cut short by a crash (no summary, a torn last chunk) yields every message
before the tear and says where it ends.

Samples are aligned on the plant's state stamps (``state/attitude`` and ``state/rate``, the
truth even when a fault relay feeds the controller): the reference is interpolated at each stamp
(exact when the stamps coincide, as in lockstep), torques, disturbances and diagnostics are the
latest at or before it (zero-order hold, as the plant applies them).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from sappc_controller.core.base import ControlOutput
from sappc_msgs_py.contract import (
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    DISTURBANCE_TORQUE,
    REFERENCE_ATTITUDE,
    STATE_ATTITUDE,
    STATE_RATE,
    faulty,
)
from spacecraft_sim.core.attitude import error_quaternion, quat_normalize
from spacecraft_sim.core.validation import ConfigError

from .metrics import MetricsAccumulator

__all__ = ["Bag", "BagError", "read_bag", "bag_metrics"]

Array = NDArray[np.float64]


class BagError(ConfigError):
    """The path is not a readable bag, or lacks what is asked of it."""


@dataclass
class Series:
    """One topic: header stamps [ns] and values, in recording order."""

    stamps_ns: NDArray[np.int64]
    values: Array


@dataclass
class Bag:
    """The messages of a bag as arrays (see :func:`read_bag`)."""

    path: Path
    series: dict[str, Series]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: str | None = None  # why reading stopped early, None when the file is whole
    diagnostics_labels: tuple[str, ...] = ()

    @property
    def counts(self) -> dict[str, int]:
        """Messages read per topic."""
        return {t: s.stamps_ns.size for t, s in self.series.items()}


def _mcap_file(path: Path) -> Path:
    if path.is_file():
        return path
    if not path.is_dir():
        raise BagError(f"{path}: no such bag (a rosbag2 directory or an .mcap file)")
    meta = path / "metadata.yaml"
    if meta.exists():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            files = [path / f for f in info["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise BagError(f"{meta}: not a rosbag2 metadata file ({exc})") from None
        if len(files) == 1 and files[0].exists():
            return files[0]
    found = sorted(path.glob("*.mcap"))
    if not found:
        raise BagError(f"{path}: no .mcap file in the bag directory")
    return found[0]


def _decoders() -> dict[str, Any]:
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped, WrenchStamped
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64MultiArray

    def stamp(m: Any) -> int:
        return int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)

    def quat(data: bytes) -> tuple[int, list[float]]:
        m = deserialize_message(data, QuaternionStamped)
        q = m.quaternion
        return stamp(m), [q.x, q.y, q.z, q.w]

    def vec(data: bytes) -> tuple[int, list[float]]:
        m = deserialize_message(data, Vector3Stamped)
        return stamp(m), [m.vector.x, m.vector.y, m.vector.z]

    def wrench(data: bytes) -> tuple[int, list[float]]:
        m = deserialize_message(data, WrenchStamped)
        tq = m.wrench.torque
        return stamp(m), [tq.x, tq.y, tq.z]

    def clock(data: bytes) -> tuple[int, list[float]]:
        m = deserialize_message(data, Clock)
        ns = int(m.clock.sec) * 1_000_000_000 + int(m.clock.nanosec)
        return ns, [ns / 1e9]

    def multiarray(data: bytes) -> tuple[int, list[float], str]:
        m = deserialize_message(data, Float64MultiArray)
        values = list(m.data)
        return int(round(values[0] * 1e9)) if values else 0, values, m.layout.dim[0].label if m.layout.dim else ""

    return {
        "geometry_msgs/msg/QuaternionStamped": quat,
        "geometry_msgs/msg/Vector3Stamped": vec,
        "geometry_msgs/msg/WrenchStamped": wrench,
        "rosgraph_msgs/msg/Clock": clock,
        "std_msgs/msg/Float64MultiArray": multiarray,
    }


def read_bag(path: str | Path) -> Bag:
    """Every message of the contract's types in the bag at ``path``, as arrays.

    Raises
    ------
    BagError
        If ``path`` is not a bag (no MCAP file, not MCAP, no messages at all).
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    p = Path(path)
    mcap_path = _mcap_file(p)
    decoders = _decoders()
    stamps: dict[str, list[int]] = {}
    values: dict[str, list[list[float]]] = {}
    metadata: dict[str, dict[str, str]] = {}
    labels = ""
    truncated: str | None = None
    with open(mcap_path, "rb") as f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            raise BagError(f"{mcap_path}: not an MCAP file")
        f.seek(0)
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, Any]] = {}
        n = 0
        try:  # one sequential pass: survives a missing summary and a torn last chunk
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    topic, decode = channels.get(record.channel_id, ("", None))
                    if decode is None:
                        continue
                    out = decode(record.data)
                    stamps.setdefault(topic, []).append(out[0])
                    values.setdefault(topic, []).append(out[1])
                    if len(out) == 3 and not labels:
                        labels = out[2]
                    n += 1
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, decoders.get(schemas.get(record.schema_id, "")))
                elif isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
        except (McapError, EOFError, ValueError, struct.error) as exc:
            truncated = f"{type(exc).__name__}: {exc}"
    if n == 0:
        raise BagError(f"{p}: the bag holds no messages of the topic contract" + (f" (reading stopped: {truncated})" if truncated else ""))
    series = {}
    for topic, st in stamps.items():
        vals = values[topic]
        width = max(len(v) for v in vals)
        arr = np.full((len(vals), width), np.nan)
        for i, v in enumerate(vals):
            arr[i, : len(v)] = v
        series[topic] = Series(np.asarray(st, dtype=np.int64), arr)
    return Bag(
        path=p,
        series=series,
        metadata=metadata,
        truncated=truncated,
        diagnostics_labels=tuple(labels.split(",")) if labels else (),
    )


def _topic(bag: Bag, name: str) -> str | None:
    """The recorded topic whose name is ``name`` or ends with ``/name`` (namespaced runs)."""
    for t in bag.series:
        if t.lstrip("/") == name or t.endswith("/" + name):
            return t
    return None


def _latest_index(stamps: NDArray[np.int64], at: NDArray[np.int64]) -> NDArray[np.int64]:
    """Index of the latest sample at or before each of ``at`` (-1 if none)."""
    order = np.argsort(stamps, kind="stable")
    idx = np.searchsorted(stamps[order], at, side="right") - 1
    return np.where(idx >= 0, order[np.maximum(idx, 0)], -1)


@dataclass
class BagRun:
    """A run recovered from a bag, aligned on the state stamps."""

    t: Array  # seconds since the first state
    t0_ns: int
    x: Array  # (T, 1, 7)
    outputs: list[ControlOutput]
    disturbance_B: Array  # (T, 1, 3)


def bag_run(bag: Bag) -> BagRun:
    """Align the bag's topics on the state stamps (see the module docstring)."""
    names = {
        "att": STATE_ATTITUDE.name,
        "rate": STATE_RATE.name,
        "ref": REFERENCE_ATTITUDE.name,
    }
    found = {k: _topic(bag, v) for k, v in names.items()}
    missing = [names[k] for k, v in found.items() if v is None]
    if missing:
        raise BagError(f"{bag.path}: the bag lacks {', '.join(missing)}; metrics need the state and the reference")
    att, rate, ref = (bag.series[found[k]] for k in ("att", "rate", "ref"))  # type: ignore[index]
    common = np.intersect1d(att.stamps_ns, rate.stamps_ns)
    common = common[common >= ref.stamps_ns.min()]
    if common.size == 0:
        raise BagError(f"{bag.path}: no state sample has both attitude and rate after the first reference")
    ia = _latest_index(att.stamps_ns, common)
    ir = _latest_index(rate.stamps_ns, common)
    x = np.concatenate((att.values[ia, :4], rate.values[ir, :3]), axis=1)[:, None, :]
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
    q_BR = error_quaternion(q_RN, x[:, 0, :4])

    torque_topic = _topic(bag, faulty(CONTROL_TORQUE).name) or _topic(bag, CONTROL_TORQUE.name)
    T = common.size

    def held(topic: str | None, width: int) -> Array:
        if topic is None:
            return np.zeros((T, width))
        s = bag.series[topic]
        i = _latest_index(s.stamps_ns, common)
        return np.where((i >= 0)[:, None], s.values[np.maximum(i, 0), :width], 0.0)

    torque = held(torque_topic, 3)
    dist = held(_topic(bag, DISTURBANCE_TORQUE.name), 3)
    diag_topic = _topic(bag, CONTROLLER_DIAGNOSTICS.name)
    labels = bag.diagnostics_labels
    rows: dict[str, Array] = {}
    if diag_topic is not None and labels:
        d = bag.series[diag_topic]
        i = _latest_index(d.stamps_ns, common)
        data = d.values[np.maximum(i, 0)].reshape(T, len(labels), 3)
        data[i < 0] = np.nan
        rows = {label: data[:, n] for n, label in enumerate(labels)}
    nan3 = np.full((T, 3), np.nan)
    outputs = [
        ControlOutput(
            torque_B=torque[k : k + 1],
            torque_cmd_B=rows.get("torque_cmd_Nm", nan3)[k : k + 1],
            saturated=(rows.get("saturated", np.zeros((T, 3)))[k : k + 1] > 0.5),
            q_BR=q_BR[k : k + 1],
            rho=rows.get("rho", nan3)[k : k + 1],
            band_lower=rows.get("band_lower", nan3)[k : k + 1],
            band_upper=rows.get("band_upper", nan3)[k : k + 1],
            eps=rows.get("eps", nan3)[k : k + 1],
            z=rows.get("z", nan3)[k : k + 1],
            V=rows.get("lyapunov_V", nan3)[k : k + 1],
        )
        for k in range(T)
    ]
    t0 = int(common[0])
    return BagRun(t=(common - t0) / 1e9, t0_ns=t0, x=x, outputs=outputs, disturbance_B=dist[:, None, :])


def bag_metrics(bag: Bag, *, steady_from_s: float, settle_threshold: float, t2_s: float, fault_windows: list[tuple[float, float]]) -> dict[str, Any]:
    """The metrics of :mod:`sappc.metrics` for the run in ``bag``."""
    run = bag_run(bag)
    acc = MetricsAccumulator(run.t, 1, steady_from_s=steady_from_s, settle_threshold=settle_threshold, t2_s=t2_s, fault_windows=fault_windows)
    for k, t in enumerate(run.t):
        acc(k, float(t), run.x[k], run.outputs[k], run.disturbance_B[k])
    return acc.run_metrics(0)

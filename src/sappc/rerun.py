"""``sappc rerun``: feed a bag's recorded inputs into the controller core again.

The controller node computes ``controller.step(t, dt, q, w, q_d, w_d, wdot_d)`` with
``t = stamp_ns / 1e9`` from the five inputs of one stamp (the state it subscribes to, which is
the fault relay's output when the run had sensor faults, and the reference).  The re-run makes
the same calls, in the same order, on a fresh controller built from a ROS parameters file (the
one embedded in the bag by ``sappc run``, or ``--params``), and compares each torque with the
one the node published on ``control/torque``.  With the recorded parameters and a lockstep bag
the two are bit-for-bit equal: a determinism check of the whole chain (CDR, the node, the core).

Which samples are re-run: every ``control/torque`` message whose diagnostics do not flag stale
inputs (a stale sample is the node's zero torque, not a control step).  Lockstep bags (with
``/clock``) pair inputs by exact stamp, as the node does.  Real-time bags pair each torque with
the latest input the recorder had received before it: the node's own view may differ by a
message in flight, so expect small differences there, which are reported, not hidden.
Runtime parameter changes made during the run are not in the bag and are not replayed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
from sappc_msgs_py.contract import (
    CLOCK,
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    REFERENCE_ACCELERATION,
    REFERENCE_ATTITUDE,
    REFERENCE_RATE,
    STATE_ATTITUDE,
    STATE_RATE,
    faulty,
)
from spacecraft_sim.core.validation import ConfigError, InputError

from .bag import Bag, BagError, Series, _latest_index, _topic
from .report import PARAMS_RECORD

__all__ = ["RerunResult", "rerun_bag"]

Array = NDArray[np.float64]

_NS = 1_000_000_000


@dataclass
class RerunResult:
    """Recorded and recomputed torques at the re-run samples."""

    controller: str
    params_source: str
    mode: str  # "lockstep" (pairs by stamp) or "realtime" (pairs by arrival)
    stamps_ns: NDArray[np.int64]  # (K,) the re-run samples
    recorded: Array  # (K, 3) control/torque as published [N m]
    recomputed: Array  # (K, 3) [N m]
    skipped: dict[str, int] = field(default_factory=dict)  # why some torque samples were not re-run
    failed_steps: int = 0  # steps the core refused (the node would command zero; recomputed = 0)

    @property
    def identical(self) -> int:
        """Samples whose three recomputed components equal the recorded ones bit for bit."""
        return int(np.all(self.recomputed == self.recorded, axis=1).sum())

    @property
    def max_abs_diff_Nm(self) -> float:
        return float(np.max(np.abs(self.recomputed - self.recorded))) if self.stamps_ns.size else 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready."""
        k = int(self.stamps_ns.size)
        return {
            "controller": self.controller,
            "parameters": self.params_source,
            "mode": self.mode,
            "samples": k,
            "identical": self.identical,
            "all_identical": k > 0 and self.identical == k,
            "max_abs_diff_Nm": self.max_abs_diff_Nm,
            "skipped": self.skipped,
            "failed_steps": self.failed_steps,
        }


def _series(bag: Bag, *names: str) -> Series:
    for name in names:
        topic = _topic(bag, name)
        if topic is not None and bag.series[topic].stamps_ns.size:
            return bag.series[topic]
    raise BagError(f"{bag.path}: the bag lacks {names[-1]}; a re-run needs the state, the reference and control/torque")


def rerun_bag(bag: Bag, params: str | Path | None = None) -> RerunResult:
    """Re-run the controller of ``bag`` (see the module docstring).

    ``params``: a ROS parameters file for the controller node (default: the bag's own).

    Raises
    ------
    BagError
        If the bag lacks an input or ``control/torque``, or carries no parameters and none are given.
    ConfigError
        If the parameters are invalid.
    """
    if params is not None:
        source = str(params)
        try:
            text = Path(params).read_text()
        except OSError as exc:
            raise ConfigError(f"cannot read parameters {params}: {exc.strerror}") from None
    else:
        record = bag.metadata.get(PARAMS_RECORD)
        if not record or "text" not in record:
            raise BagError(f"{bag.path}: the bag carries no controller parameters ({PARAMS_RECORD}); give --params FILE")
        source, text = f"the bag's {PARAMS_RECORD}", record["text"]
    kind, config, dt = controller_from_parameters_file(text, source=source)
    controller = CONTROLLER_CLASSES[kind](config)

    # the state the controller subscribed to: the relay's when the run relayed it
    inputs = [
        _series(bag, faulty(STATE_ATTITUDE).name, STATE_ATTITUDE.name),
        _series(bag, faulty(STATE_RATE).name, STATE_RATE.name),
        _series(bag, REFERENCE_ATTITUDE.name),
        _series(bag, REFERENCE_RATE.name),
        _series(bag, REFERENCE_ACCELERATION.name),
    ]
    torque = _series(bag, CONTROL_TORQUE.name)
    skipped: dict[str, int] = {}
    keep = np.ones(torque.stamps_ns.size, dtype=bool)
    diag_topic = _topic(bag, CONTROLLER_DIAGNOSTICS.name)
    if diag_topic is not None and "status" in bag.diagnostics_labels:
        d = bag.series[diag_topic]
        col = 3 * bag.diagnostics_labels.index("status") + 1  # status[1]: the stale flag
        # the node publishes the torque and its diagnostics together, with the same time
        i = _latest_index(d.stamps_ns, torque.stamps_ns)
        stale = (i >= 0) & (d.stamps_ns[np.maximum(i, 0)] == torque.stamps_ns) & (d.values[np.maximum(i, 0), col] > 0.5)
        keep &= ~stale
        if stale.any():
            skipped["stale (zero torque, no control step)"] = int(stale.sum())

    lockstep = _topic(bag, CLOCK.name) is not None
    if lockstep:  # pair by exact stamp, as the node does
        pos = []
        for s in inputs:
            order = np.argsort(s.stamps_ns, kind="stable")
            j = np.clip(np.searchsorted(s.stamps_ns[order], torque.stamps_ns), 0, s.stamps_ns.size - 1)
            hit = s.stamps_ns[order][j] == torque.stamps_ns
            pos.append(np.where(hit, order[j], -1))
    else:  # pair by arrival at the recorder
        pos = [_latest_index(s.log_time_ns, torque.log_time_ns) for s in inputs]
    found = np.all(np.stack(pos) >= 0, axis=0)
    if (keep & ~found).any():
        skipped["an input of the sample is not in the bag"] = int((keep & ~found).sum())
    keep &= found

    rows = np.flatnonzero(keep)
    recomputed = np.full((rows.size, 3), np.nan)
    failed = 0
    for n, r in enumerate(rows):
        q, w, q_d, w_d, wdot_d = (s.values[p[r], : (4 if c in (0, 2) else 3)] for c, (s, p) in enumerate(zip(inputs, pos)))
        try:
            recomputed[n] = controller.step(int(torque.stamps_ns[r]) / _NS, dt, q, w, q_d, w_d, wdot_d).torque_B
        except (InputError, FloatingPointError, ConfigError):
            failed += 1  # the node then publishes zero torque
            recomputed[n] = 0.0
    return RerunResult(
        controller=kind,
        params_source=source,
        mode="lockstep" if lockstep else "realtime",
        stamps_ns=torque.stamps_ns[rows],
        recorded=torque.values[rows, :3],
        recomputed=recomputed,
        skipped=skipped,
        failed_steps=failed,
    )

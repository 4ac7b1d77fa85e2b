"""``sappc rerun``: feed a bag's recorded inputs into the controller core again.

The controller node computes ``controller.step(t, dt, q, w, q_d, w_d, wdot_d)`` with
``t = stamp_ns / 1e9`` (real time: counted from the first step's stamp) from the five inputs of one stamp (the state it subscribes to, which is
the fault relay's output when the run had sensor faults, and the reference).  The re-run makes
the same calls, in the same order, on a fresh controller built from a ROS parameters file (the
one embedded in the bag by ``sappc run``, or ``--params``), and compares each torque with the
one the node published on ``control/torque``.  With the recorded parameters and a lockstep bag
the two are bit-for-bit equal: a determinism check of the whole chain (CDR, the node, the core).

Which samples are re-run: every ``control/torque`` message whose diagnostics do not flag it as
no control step (``status[1]``: a held torque or the watchdog's zero, see the node's answers).  Which inputs: those
whose stamps the controller reported in its diagnostics (``input_stamps_state_s``,
``input_stamps_reference_s``), so the re-run is exact in real time too.  For a bag without them
(another controller node), the recorded inputs are fed, in the order the recorder received
them, through the node's own input pairing (:mod:`sappc_controller.inputs`): lockstep bags
(with ``/clock``) pair the inputs of equal stamps, and real-time bags step each fresh state at
its stamp with the reference of that stamp, or the newest earlier one the recorder had received
by then, which may differ from the node's view by a message in flight: expect small differences
there, which are reported, not hidden.  Each step is the
node's step (:func:`~sappc_controller.inputs.step_sample`).  Runtime parameter changes made
during the run are not in the bag and are not replayed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_controller.inputs import INPUT_TOPICS, STEP_ERRORS, ControlSample, LockstepPairing, RealtimePairing, step_sample
from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
from sappc_msgs_py.contract import CLOCK, CONTROL_TORQUE, CONTROLLER_DIAGNOSTICS, consumed_names
from gnc_common.validation import MAX_YAML_BYTES, read_text_file

from sappc.bag.read import PARAMS_RECORD, STAMP_TOL_NS, Bag, BagError, Series, find_topic, nearest_index

__all__ = ["RerunResult", "rerun_bag"]

Array = NDArray[np.float64]

def _arrival_order(inputs: list[Series]) -> list[tuple[int, int]]:
    """``(input, row)`` of every recorded input message in the order the recorder received them."""
    logs = [s.log_time_ns for s in inputs]
    which = np.concatenate([np.full(t.size, c, dtype=np.int64) for c, t in enumerate(logs)])
    rows = np.concatenate([np.arange(t.size, dtype=np.int64) for t in logs])
    order = np.lexsort((which, np.concatenate(logs)))  # by time received, then input order
    return list(zip(which[order].tolist(), rows[order].tolist()))


def _replay(inputs: list[Series], widths: list[int], pairing: LockstepPairing | RealtimePairing) -> dict[int, ControlSample]:
    """The samples the node's ``pairing`` completes from the recorded inputs fed in the order the
    recorder received them, by stamp [ns]."""
    samples: dict[int, ControlSample] = {}
    for c, r in _arrival_order(inputs):
        s = inputs[c]
        stamp_ns = int(s.stamps_ns[r])
        if isinstance(pairing, RealtimePairing) and c < RealtimePairing.N_STATE \
                and pairing.waiting_ns is not None and pairing.waiting_ns < stamp_ns:
            # a newer state: the one still waiting for its reference had passed its deadline (the node held the reference)
            held = pairing.take_held()
            if held is not None:
                samples.setdefault(held.t_ns, held)
        sample = pairing.add(INPUT_TOPICS[c].name, stamp_ns, s.values[r, : widths[c]])
        if sample is not None:
            samples.setdefault(sample.t_ns, sample)  # the node rejects a stamp it has computed
    return samples


@dataclass
class RerunResult:
    """Recorded and recomputed torques at the re-run samples."""

    controller: str
    params_source: str
    mode: str  # "lockstep" (the bag has /clock) or "realtime"
    pairing: str  # how each torque was matched with its inputs
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
            "pairing": self.pairing,
            "samples": k,
            "identical": self.identical,
            "all_identical": k > 0 and self.identical == k,
            "max_abs_diff_Nm": self.max_abs_diff_Nm,
            "skipped": self.skipped,
            "failed_steps": self.failed_steps,
        }


def _series(bag: Bag, *names: str) -> Series:
    for name in names:
        topic = find_topic(bag, name)
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
        text = read_text_file(params, "parameters", max_bytes=MAX_YAML_BYTES)
    else:
        record = bag.metadata.get(PARAMS_RECORD)
        if not record or "text" not in record:
            raise BagError(f"{bag.path}: the bag carries no controller parameters ({PARAMS_RECORD}); give --params FILE")
        source, text = f"the bag's {PARAMS_RECORD}", record["text"]
    kind, config, dt = controller_from_parameters_file(text, source=source)
    controller = CONTROLLER_CLASSES[kind](config)

    # the inputs the controller subscribed to: the relay's when the run relayed them
    inputs = [_series(bag, *consumed_names(t)) for t in INPUT_TOPICS]
    widths = [4 if t.type_name.endswith("QuaternionStamped") else 3 for t in INPUT_TOPICS]
    torque = _series(bag, CONTROL_TORQUE.name)
    skipped: dict[str, int] = {}
    keep = np.ones(torque.stamps_ns.size, dtype=bool)
    labels = bag.diagnostics_labels
    diag_topic = find_topic(bag, CONTROLLER_DIAGNOSTICS.name)
    diag = None
    if diag_topic is not None and "status" in labels:
        # the node publishes each torque with its diagnostics, stamped with the same time
        d = bag.series[diag_topic]
        j = nearest_index(d.stamps_ns, torque.stamps_ns, STAMP_TOL_NS)
        diag = np.where((j >= 0)[:, None], d.values[np.maximum(j, 0)], np.nan)
        stale = diag[:, 3 * labels.index("status") + 1] > 0.5  # status[1]: not a control step (held or zero torque)
        keep &= ~stale
        if stale.any():
            skipped["not a control step (the last torque held, or zero torque)"] = int(stale.sum())

    lockstep = find_topic(bag, CLOCK.name) is not None
    if diag is not None and "input_stamps_state_s" in labels and "input_stamps_reference_s" in labels:
        # the stamps of the messages the step used, as the controller reported them
        a, b = 3 * labels.index("input_stamps_state_s"), 3 * labels.index("input_stamps_reference_s")
        used = np.concatenate((diag[:, a : a + 2], diag[:, b : b + 3]), axis=1)
        used_ns = np.where(np.isfinite(used), np.round(np.nan_to_num(used) * 1e9), -1).astype(np.int64)
        pos = np.stack([nearest_index(s.stamps_ns, used_ns[:, c], STAMP_TOL_NS) for c, s in enumerate(inputs)], axis=1)
        samples: list[ControlSample | None] = [
            ControlSample(int(t_ns), tuple(int(s.stamps_ns[p]) for s, p in zip(inputs, row)),
                          tuple(s.values[p, :width] for s, p, width in zip(inputs, row, widths)))
            if np.all(row >= 0) else None
            for t_ns, row in zip(torque.stamps_ns, pos)
        ]
        pairing = "the input stamps the controller reported"
    else:  # the node's pairing, on the inputs in the order the recorder received them
        by_stamp = _replay(inputs, widths, LockstepPairing(INPUT_TOPICS) if lockstep else RealtimePairing(INPUT_TOPICS))
        samples = [by_stamp.get(int(t_ns)) for t_ns in torque.stamps_ns]
        pairing = "equal stamps" if lockstep else "the state's stamp, the reference received by then (approximate)"
    found = np.array([s is not None for s in samples], dtype=bool)
    if (keep & ~found).any():
        skipped["an input of the sample is not in the bag"] = int((keep & ~found).sum())
    keep &= found

    rows = np.flatnonzero(keep)
    recomputed = np.full((rows.size, 3), np.nan)
    failed = 0
    # the law's time origin, as the node's: the stamps in lockstep, the first step's stamp in real time
    origin_ns = 0 if lockstep or rows.size == 0 else int(torque.stamps_ns[rows[0]])
    for n, r in enumerate(rows):
        sample = samples[r]
        assert sample is not None  # kept rows have their inputs
        try:
            recomputed[n] = step_sample(controller, dt, sample, origin_ns).torque_B
        except STEP_ERRORS:
            failed += 1  # the node then publishes zero torque
            recomputed[n] = 0.0
    return RerunResult(
        controller=kind,
        params_source=source,
        mode="lockstep" if lockstep else "realtime",
        pairing=pairing,
        stamps_ns=torque.stamps_ns[rows],
        recorded=torque.values[rows, :3],
        recomputed=recomputed,
        skipped=skipped,
        failed_steps=failed,
    )

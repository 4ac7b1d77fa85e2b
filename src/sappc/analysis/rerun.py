"""``sappc rerun``: feed a bag's recorded inputs into the controller core again.

The controller node computes ``controller.step(t, dt, q, w, q_d, w_d, wdot_d)`` with
``t = stamp_ns / 1e9`` (real time: counted from the first step's stamp) from the five inputs of one stamp (the state it subscribes to, which is
the estimator's estimate when the run had one, the fault relay's output when the run had sensor
faults and no estimator, and the reference).  The re-run makes
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
from sappc_msgs_py.contract import CLOCK, CONTROL_TORQUE, CONTROLLER_DIAGNOSTICS, consumed_names, controller_state_sources
from gnc_common.validation import MAX_YAML_BYTES, ConfigError, read_text_file, safe_load_yaml

from sappc.bag.blocks import BLOCK_BYTES, EDGE_NS, BagBlocks, NotInBlocks
from sappc.bag.read import PARAMS_RECORD, STAMP_TOL_NS, Bag, BagError, Series, find_topic, nearest_index, read_bag

__all__ = ["RerunResult", "rerun_bag", "rerun_blocks"]

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


def _series_topic(bag: Bag, *names: str) -> str:
    """The first of ``names`` the bag has a message of (the relay's output before the topic itself)."""
    for name in names:
        topic = find_topic(bag, name)
        if topic is not None and bag.series[topic].stamps_ns.size:
            return topic
    raise BagError(f"{bag.path}: the bag lacks {names[-1]}; a re-run needs the state, the reference and control/torque")


def _series(bag: Bag, *names: str) -> Series:
    return bag.series[_series_topic(bag, *names)]


def _controller(path: Path, metadata: dict[str, dict[str, str]], params: str | Path | None) -> tuple[str, Any, Any, float]:
    """(parameters' source, controller kind, a fresh controller, its period [s]) from ``params``
    or, without, the bag's own :data:`~sappc.bag.read.PARAMS_RECORD`."""
    if params is not None:
        source = str(params)
        text = read_text_file(params, "parameters", max_bytes=MAX_YAML_BYTES)
    else:
        record = metadata.get(PARAMS_RECORD)
        if not record or "text" not in record:
            raise BagError(f"{path}: the bag carries no controller parameters ({PARAMS_RECORD}); give --params FILE")
        source, text = f"the bag's {PARAMS_RECORD}", record["text"]
    kind, config, dt = controller_from_parameters_file(text, source=source)
    return source, kind, CONTROLLER_CLASSES[kind](config), dt


def _input_names(metadata: dict[str, dict[str, str]]) -> list[tuple[str, ...]]:
    """The names under which the run's controller received each of its five inputs, the one to
    prefer first: its attitude and rate from the estimator's estimate when the run had one
    (:func:`~sappc_msgs_py.contract.controller_state_sources`; the bag's
    :data:`~sappc.bag.read.PARAMS_RECORD` configures an ``estimator`` node), the relay's output
    for a relayed input, else the topic itself."""
    record = metadata.get(PARAMS_RECORD) or {}
    try:
        nodes = safe_load_yaml(record.get("text", ""), source=f"the bag's {PARAMS_RECORD}") or {}
    except ConfigError:  # unreadable parameters name no estimator (without --params the re-run has refused them already)
        nodes = {}
    estimating = isinstance(nodes, dict) and any(str(name).strip("/") == "estimator" for name in nodes)
    return [consumed_names(t) for t in (*controller_state_sources(estimating), *INPUT_TOPICS[2:])]


#: Each input's width: a quaternion's 4, a vector's 3.
_WIDTHS = [4 if t.type_name.endswith("QuaternionStamped") else 3 for t in INPUT_TOPICS]
_NOT_A_STEP = "not a control step (the last torque held, or zero torque)"
_NO_INPUT = "an input of the sample is not in the bag"
#: The pairing of a re-run from the stamps the controller reported.
_REPORTED = "the input stamps the controller reported"


def _diagnostics_at(d: Series, stamps_ns: NDArray[np.int64]) -> Array:
    """The diagnostics row of each torque's stamp (the node publishes each torque with its
    diagnostics, stamped with the same time); NaN where there is none."""
    j = nearest_index(d.stamps_ns, stamps_ns, STAMP_TOL_NS)
    return np.where((j >= 0)[:, None], d.values[np.maximum(j, 0)], np.nan)


def _stale(diag: Array, labels: tuple[str, ...]) -> NDArray[np.bool_]:
    """status[1] of each torque's diagnostics: not a control step (held or zero torque)."""
    stale: NDArray[np.bool_] = diag[:, 3 * labels.index("status") + 1] > 0.5
    return stale


def _used_stamps(diag: Array, labels: tuple[str, ...]) -> NDArray[np.int64]:
    """(K, 5) the stamps of the input messages each step used, as the controller reported them
    (its diagnostics' ``input_stamps_*``) [ns]; -1 where none is reported."""
    a, b = 3 * labels.index("input_stamps_state_s"), 3 * labels.index("input_stamps_reference_s")
    used = np.concatenate((diag[:, a : a + 2], diag[:, b : b + 3]), axis=1)
    used_ns: NDArray[np.int64] = np.where(np.isfinite(used), np.round(np.nan_to_num(used) * 1e9), -1).astype(np.int64)
    return used_ns


def _reported_samples(inputs: list[Series], torque_ns: NDArray[np.int64], diag: Array, labels: tuple[str, ...]
                      ) -> list[ControlSample | None]:
    """Each torque's sample from the input stamps its diagnostics report (``None``: an input not in
    ``inputs``)."""
    used_ns = _used_stamps(diag, labels)
    pos = np.stack([nearest_index(s.stamps_ns, used_ns[:, c], STAMP_TOL_NS) for c, s in enumerate(inputs)], axis=1)
    return [
        ControlSample(int(t_ns), tuple(int(s.stamps_ns[p]) for s, p in zip(inputs, row)),
                      tuple(s.values[p, :width] for s, p, width in zip(inputs, row, _WIDTHS)))
        if np.all(row >= 0) else None
        for t_ns, row in zip(torque_ns, pos)
    ]


class _Stepper:
    """The re-run's steps in order, a block of torques at a time (its controller carries its state)."""

    def __init__(self, controller: Any, dt: float, lockstep: bool) -> None:
        self.controller, self.dt, self.lockstep = controller, dt, lockstep
        self.origin_ns: int | None = 0 if lockstep else None  # the law's time origin: the first step's stamp in real time
        self.skipped: dict[str, int] = {}
        self.failed = 0
        self.stamps: list[NDArray[np.int64]] = []
        self.recorded: list[Array] = []
        self.recomputed: list[Array] = []

    def skip(self, why: str, n: int) -> None:
        if n:
            self.skipped[why] = self.skipped.get(why, 0) + n

    def run(self, torque: Series, keep: NDArray[np.bool_], samples: list[ControlSample | None]) -> None:
        """Step the kept torques of ``torque`` (rows of ``samples``: None, an input missing)."""
        found = np.array([s is not None for s in samples], dtype=bool)
        self.skip(_NO_INPUT, int((keep & ~found).sum()))
        rows = np.flatnonzero(keep & found)
        recomputed = np.full((rows.size, 3), np.nan)
        if rows.size and self.origin_ns is None:
            self.origin_ns = int(torque.stamps_ns[rows[0]])
        for n, r in enumerate(rows):
            sample = samples[r]
            assert sample is not None  # kept rows have their inputs
            try:
                recomputed[n] = step_sample(self.controller, self.dt, sample, self.origin_ns or 0).torque_B
            except STEP_ERRORS:
                self.failed += 1  # the node then publishes zero torque
                recomputed[n] = 0.0
        self.stamps.append(torque.stamps_ns[rows])
        self.recorded.append(torque.values[rows, :3])
        self.recomputed.append(recomputed)

    def result(self, kind: str, source: str, pairing: str) -> RerunResult:
        empty = np.zeros((0, 3))
        skipped = {why: self.skipped[why] for why in (_NOT_A_STEP, _NO_INPUT) if why in self.skipped}
        return RerunResult(controller=kind, params_source=source, mode="lockstep" if self.lockstep else "realtime", pairing=pairing,
                           stamps_ns=np.concatenate(self.stamps) if self.stamps else np.zeros(0, np.int64),
                           recorded=np.concatenate(self.recorded) if self.recorded else empty,
                           recomputed=np.concatenate(self.recomputed) if self.recomputed else empty,
                           skipped=skipped, failed_steps=self.failed)


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
    source, kind, controller, dt = _controller(bag.path, bag.metadata, params)
    # the inputs the controller subscribed to: the estimate when the run estimated, the relay's when it relayed them
    inputs = [_series(bag, *names) for names in _input_names(bag.metadata)]
    torque = _series(bag, CONTROL_TORQUE.name)
    lockstep = find_topic(bag, CLOCK.name) is not None
    stepper = _Stepper(controller, dt, lockstep)
    keep = np.ones(torque.stamps_ns.size, dtype=bool)
    labels = bag.diagnostics_labels
    diag_topic = find_topic(bag, CONTROLLER_DIAGNOSTICS.name)
    diag = None
    if diag_topic is not None and "status" in labels:
        diag = _diagnostics_at(bag.series[diag_topic], torque.stamps_ns)
        stale = _stale(diag, labels)
        keep &= ~stale
        stepper.skip(_NOT_A_STEP, int(stale.sum()))
    if diag is not None and "input_stamps_state_s" in labels and "input_stamps_reference_s" in labels:
        samples = _reported_samples(inputs, torque.stamps_ns, diag, labels)
        pairing = _REPORTED
    else:  # the node's pairing, on the inputs in the order the recorder received them
        by_stamp = _replay(inputs, _WIDTHS, LockstepPairing(INPUT_TOPICS) if lockstep else RealtimePairing(INPUT_TOPICS))
        samples = [by_stamp.get(int(t_ns)) for t_ns in torque.stamps_ns]
        pairing = "equal stamps" if lockstep else "the state's stamp, the reference received by then (approximate)"
    stepper.run(torque, keep, samples)
    return stepper.result(kind, source, pairing)


#: How far before a torque's stamp the inputs it used may be stamped, for a re-run in blocks [ns]:
#: the windows keep the inputs of the last second before the next torque (a real-time step holds
#: a reference a frame or two old: 10 to 20 ms at 100 Hz).  An input older than that is read from
#: the bag read whole (the re-run starts again that way: the same result).
_INPUT_AGE_NS = 1_000_000_000


def rerun_blocks(path: str | Path, params: str | Path | None = None, *, block_bytes: int = BLOCK_BYTES,
                 block_messages: int | None = None) -> RerunResult:
    """:func:`rerun_bag` of the bag at ``path`` read in blocks (:class:`~sappc.bag.blocks.BagBlocks`:
    memory set by the block, not by the bag): the same result, bit for bit.  The torques are
    stepped in order as their diagnostics and inputs are read: each torque once every topic it reads
    has a message stamped more than :data:`~sappc.bag.blocks.EDGE_NS` after it (or none left).  A
    bag without the input stamps its controller reported (another controller node: the node's own
    pairing over the arrival order), or that cannot be read in blocks exactly, is read whole.

    Raises
    ------
    BagError, ConfigError
        As :func:`~sappc.bag.read.read_bag` and :func:`rerun_bag`.
    """
    bb = BagBlocks(path, block_bytes=block_bytes, block_messages=block_messages)
    try:
        return _rerun_in_blocks(bb, params)
    except NotInBlocks:
        return rerun_bag(read_bag(path), params)
    except BagError:  # read_bag's error first, as the bag read whole gives it
        if not bb.has_contract_messages():
            raise bb.no_messages() from None
        raise


def _rerun_in_blocks(bb: BagBlocks, params: str | Path | None) -> RerunResult:
    source, kind, controller, dt = _controller(bb.path, bb.bag.metadata, params)
    if bb.not_in_blocks is not None:
        raise NotInBlocks(bb.not_in_blocks)
    view = bb.view()  # the topics in the whole bag's order, each "with messages" as the index counted them (decoded: checked at the end)
    for name, t in view.series.items():
        view.series[name] = Series(np.zeros(bb.topic(name).messages, np.int64), t.values, t.log_time_ns)
    input_topics = [_series_topic(view, *names) for names in _input_names(bb.bag.metadata)]
    torque_topic = _series_topic(view, CONTROL_TORQUE.name)
    diag_topic = find_topic(view, CONTROLLER_DIAGNOSTICS.name)
    if diag_topic is None:
        raise NotInBlocks("no controller diagnostics: the node's pairing over the arrival order")
    reads = [*input_topics, diag_topic]  # what a torque reads: its diagnostics, the inputs they name
    need = {*reads, torque_topic}
    stepper = _Stepper(controller, dt, find_topic(view, CLOCK.name) is not None)

    def step(bound_ns: int | None) -> None:
        """Step the torques read that no message left can change: stamped more than EDGE_NS before
        ``bound_ns``, the least last stamp of a topic they read with messages left (None: every torque)."""
        w = bb.topic(torque_topic).window
        if w is None or w.stamps_ns.size == 0:
            return
        hi = w.stamps_ns.size if bound_ns is None else int(np.searchsorted(w.stamps_ns, bound_ns - EDGE_NS, side="left"))
        if hi == 0:
            return
        labels = bb.diagnostics_labels()
        if "status" not in labels or "input_stamps_state_s" not in labels or "input_stamps_reference_s" not in labels:
            raise NotInBlocks("no input stamps reported: the node's pairing over the arrival order")
        windows = [bb.topic(name).lookup_window() for name in reads]
        if any(x is None for x in windows):
            raise NotInBlocks("a topic without messages")
        *inputs, d = [x for x in windows if x is not None]
        torque = Series(w.stamps_ns[:hi], w.values[:hi], w.log_time_ns[:hi])
        diag = _diagnostics_at(d, torque.stamps_ns)
        used_ns = _used_stamps(diag, labels)
        # every lookup reads from the windows what it would from the whole bag: no message near it cut, none to come
        lookups = [(name, used_ns[:, c]) for c, name in enumerate(input_topics)] + [(diag_topic, torque.stamps_ns)]
        if not all(bb.topic(name).readable(at).all() for name, at in lookups):
            raise NotInBlocks("an input stamped before the windows")
        if bound_ns is not None and max(int(at.max()) for _, at in lookups) + STAMP_TOL_NS >= bound_ns:
            raise NotInBlocks("an input stamped after the torque")
        stale = _stale(diag, labels)
        stepper.skip(_NOT_A_STEP, int(stale.sum()))
        stepper.run(torque, ~stale, _reported_samples(inputs, torque.stamps_ns, diag, labels))
        bb.topic(torque_topic).window = Series(w.stamps_ns[hi:], w.values[hi:], w.log_time_ns[hi:])
        if hi < w.stamps_ns.size:  # the windows from the next torque on: the inputs of _INPUT_AGE_NS before it
            bb.cut_windows(reads, int(w.stamps_ns[hi]) - _INPUT_AGE_NS)

    for _ in bb.passes(lambda topic: topic.channel.topic in need or not bb.float_arrays_known(), lambda name: name in need):
        if not bb.float_arrays_known():
            continue  # the diagnostics' labels are not known yet
        bound: int | None = None
        for read in map(bb.topic, reads):
            if read.complete:
                continue
            if read.last_ns is None:
                break
            bound = read.last_ns if bound is None else min(bound, read.last_ns)
        else:
            step(bound)
    step(None)
    if any(bb.topic(name).decoded == 0 for name in need):
        raise NotInBlocks("a topic none of whose messages decode (the bag read whole takes the next name)")
    return stepper.result(kind, source, _REPORTED)

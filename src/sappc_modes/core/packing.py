"""The flight modes as the compiled closed loop takes them (:mod:`sappc.offline.compiled_loop`):
one ``NamedTuple`` of arrays, a row per run, packed by :func:`pack_modes`.

The mode manager's laws outside TRACK are the project's own: B-dot on the rods in DETUMBLE
(:mod:`.bdot`), and MRP feedback (``sappc_controller``'s ``mrp_feedback`` kernel, its parameter
rows packed by the caller: this room never imports the controller) in HOLD, on the estimate
towards the attitude held at HOLD's entry, and in SAFE, on the gyro's rate alone (its attitude
gain zero).  Plain arrays: no ROS, no clock.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from sappc_modes.core.bdot import N_BDOT_PARAMS, pack_bdot
from sappc_modes.core.modes import DETUMBLE, HOLD, MODE_NAMES, N_PARAMS, SAFE, TRACK, ModeConfig

__all__ = ["ModeArrays", "N_MODE_RUN", "MR_ENTRY", "MR_SAMPLES", "MR_TRANSITIONS", "pack_modes"]

Array = NDArray[np.float64]

#: Columns of a run's mode summary (the loop's ``LoopRecord.mode_run``): the time each mode was
#: first entered [s] (NaN: never; ``MR_ENTRY + mode``), the samples flown in each mode
#: (``MR_SAMPLES + mode``), the transitions taken.
MR_ENTRY, MR_SAMPLES, MR_TRANSITIONS = 0, 4, 8
N_MODE_RUN = 9


#: The restarts of the controller a run may take (flight modes: each entry into TRACK after the
#: first starts it again, with constants of its own): a flight that leaves TRACK more often than
#: this (a health cycling through SAFE) continues its last start at each further entry.  The
#: offline loop's and the controller node's.
MAX_RESTARTS = 8


class ModeArrays(NamedTuple):
    """The modes of a batch: ``prm`` (N, :data:`~sappc_modes.core.modes.N_PARAMS`) the guards
    (:meth:`~sappc_modes.core.modes.ModeConfig.packed`), ``initial`` (N,) each run's first mode,
    ``bdot`` (N, :data:`~sappc_modes.core.bdot.N_BDOT_PARAMS`) the B-dot law's, ``hold_prm`` and
    ``safe_prm`` (N, P) the MRP feedback law's parameter rows in HOLD and in SAFE (the
    controller's packing), ``hold_reference`` (N,) 1.0 where HOLD points at the scenario's
    reference (an acquisition), 0.0 where it holds the attitude of its entry; ``restart_coef`` (N,
    R, ...) the controller's start constants of each run's restarts (its 2nd to (R+1)th start in
    TRACK, filled by the loop as they come) and ``starts_known`` (N,) how many of a run's starts
    have their constants (its first's in the controller's arrays); ``requests`` (N, K, 2) the
    ground's requests, each a time [s] and a mode (one sample's request: the first sample at or
    after that time).  Without modes every array but ``starts_known`` has no columns (and ``initial`` and ``hold_reference`` no meaning): the loop
    flies TRACK alone, as before modes existed."""

    prm: Array
    initial: Array
    bdot: Array
    hold_prm: Array
    safe_prm: Array
    hold_reference: Array
    restart_coef: Array
    starts_known: Array
    requests: Array

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"prm": 0, "initial": 0, "bdot": 0, "hold_prm": 0, "safe_prm": 0, "hold_reference": 0, "restart_coef": 0, "starts_known": 0, "requests": 0}

    @property
    def active(self) -> bool:
        """Whether the batch flies modes."""
        return bool(self.prm.shape[1] > 0)


def pack_modes(config: ModeConfig | None, n_runs: int, dt_s: float, *, initial_mode: int = DETUMBLE, bdot_gain_N_m_s: float = 0.0,
               hold_prm: Array | None = None, safe_prm: Array | None = None, hold_on_reference: bool = False,
               coef_shape: tuple[int, int] = (0, 0), max_restarts: int = 0,
               requests: tuple[tuple[float, int], ...] = ()) -> ModeArrays:
    """The modes of ``n_runs`` runs sampled every ``dt_s``: the guards of ``config``, the first
    mode, the B-dot gain [N m s], the MRP feedback rows of HOLD and SAFE ((P,) or (N, P)),
    whether HOLD points at the reference, room for ``max_restarts`` restarts' start constants of
    shape ``coef_shape`` (the controller's), and the ground's ``requests`` ((time [s], mode) each);
    ``config`` ``None``: no modes (every array empty)."""
    if config is None:
        empty = np.zeros((n_runs, 0))
        return ModeArrays(empty, np.zeros(n_runs), empty.copy(), empty.copy(), empty.copy(), np.zeros(n_runs),
                          np.zeros((n_runs, 0) + tuple(coef_shape)), np.zeros(n_runs), np.zeros((n_runs, 0, 2)))
    if isinstance(initial_mode, bool) or initial_mode not in (DETUMBLE, HOLD, TRACK, SAFE):
        raise ValueError(f"initial_mode must be one of {dict(enumerate(MODE_NAMES))}, got {initial_mode!r}")
    if hold_prm is None or safe_prm is None:
        raise ValueError("modes need the MRP feedback parameter rows of HOLD and SAFE (hold_prm, safe_prm)")

    def rows(a: Array, width: int | None = None) -> Array:
        arr = np.asarray(a, dtype=np.float64)
        out = np.array(np.broadcast_to(arr, (n_runs, arr.shape[-1])), dtype=np.float64, order="C")
        if width is not None and out.shape[1] != width:
            raise ValueError(f"expected {width} columns, got {out.shape[1]}")
        return out

    for at_s, mode in requests:
        if isinstance(at_s, bool) or not isinstance(at_s, (int, float)) or not math.isfinite(at_s) or at_s < 0.0:
            raise ValueError(f"a request's time must be a finite number >= 0 [s], got {at_s!r}")
        if isinstance(mode, bool) or mode not in (DETUMBLE, HOLD, TRACK, SAFE):
            raise ValueError(f"a request's mode must be one of {dict(enumerate(MODE_NAMES))}, got {mode!r}")
    table = np.array([[float(a), float(m)] for a, m in requests], dtype=np.float64).reshape(-1, 2)
    prm = rows(config.packed(dt_s), N_PARAMS)
    bdot = rows(pack_bdot(bdot_gain_N_m_s), N_BDOT_PARAMS)
    return ModeArrays(prm, np.full(n_runs, float(initial_mode)), bdot, rows(hold_prm), rows(safe_prm),
                      np.full(n_runs, 1.0 if hold_on_reference else 0.0), np.zeros((n_runs, int(max_restarts)) + tuple(coef_shape)),
                      np.zeros(n_runs), np.ascontiguousarray(np.broadcast_to(table, (n_runs,) + table.shape)))


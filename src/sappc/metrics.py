"""Run metrics, computed from time histories (offline runs now, recorded bags later).

All metrics are per run (batch axis N); :func:`run_metrics` returns a dict for
run 0 (or the only run).  Definitions:

``settling_time_s``
    The first sample time after which ``max_i |q_ev,i|`` stays below
    ``settle_threshold`` until the end; ``0`` if it always was, ``None`` if it
    never settles.
``steady_max_abs_qev``, ``steady_mean_abs_qev``
    Over ``t >= steady_from_s``: the largest ``|q_ev,i|``, and the largest over
    ``i`` of the time-mean of ``|q_ev,i|`` (the paper's Monte Carlo criterion).
``rpf_error_at_t2``
    ``max_i |q_ev,i - rho_i|`` at the sample nearest ``t2_s``, with ``rho`` the
    controller's own performance function (the RPF for SAPPC).
``overshoot``
    The largest excursion of any component to the sign opposite its initial
    error, ``max_{i,t} max(0, -sign(q_ev,i(0)) q_ev,i(t))`` (``sign(0) = +1``).
``max_abs_torque_Nm``
    Largest produced per-axis torque magnitude.
``saturation_fraction``
    Fraction of control samples at which at least one axis was saturated.
``time_outside_constraint_s``
    Number of samples with any component outside its constraint band, times ``dt``.
``returned_to_constraint``
    Only with faults: ``True`` when every component is inside its band at the
    end of the run, i.e. from the sample after the last one outside the band
    to the end.  ``left_constraint_after_fault`` says whether the error left
    the band at or after the first fault's start, ``returned_at_s`` when it
    re-entered for good (``None`` if it never left or never returned).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .closed_loop import History

__all__ = ["run_metrics"]

Array = NDArray[np.float64]


def _settling_time(t: Array, max_abs: Array, threshold: float) -> float | None:
    above = np.flatnonzero(max_abs >= threshold)
    if above.size == 0:
        return 0.0
    if above[-1] + 1 >= t.size:
        return None
    return float(t[above[-1] + 1])


def run_metrics(
    h: History,
    *,
    steady_from_s: float,
    settle_threshold: float,
    t2_s: float,
    fault_windows: list[tuple[float, float]],
    run: int = 0,
) -> dict[str, Any]:
    """Metrics of run ``run`` of a history (see the module docstring for definitions)."""
    t = h.t
    dt = float(t[1] - t[0]) if t.size > 1 else 0.0
    q_ev = h.q_ev[:, run]
    abs_q = np.abs(q_ev)
    steady = t >= steady_from_s - 1e-9
    sign0 = np.where(q_ev[0] >= 0.0, 1.0, -1.0)
    outside = ((q_ev < h.band_lower[:, run]) | (q_ev > h.band_upper[:, run])).any(axis=1)
    k2 = int(np.argmin(np.abs(t - t2_s)))
    m: dict[str, Any] = {
        "settling_time_s": _settling_time(t, abs_q.max(axis=1), settle_threshold),
        "steady_max_abs_qev": float(abs_q[steady].max()) if steady.any() else None,
        "steady_mean_abs_qev": float(abs_q[steady].mean(axis=0).max()) if steady.any() else None,
        "rpf_error_at_t2": float(np.abs(q_ev[k2] - h.rho[k2, run]).max()),
        "overshoot": float(max(0.0, (-sign0 * q_ev).max())),
        "max_abs_torque_Nm": float(np.abs(h.torque_B[:, run]).max()),
        "saturation_fraction": float(h.saturated[:, run].any(axis=1).mean()),
        "time_outside_constraint_s": float(outside.sum() * dt),
        "returned_to_constraint": None,
        "left_constraint_after_fault": None,
        "returned_at_s": None,
    }
    if fault_windows:
        first_start = min(start for start, _ in fault_windows)
        left = outside & (t >= first_start - 1e-9)
        m["left_constraint_after_fault"] = bool(left.any())
        m["returned_to_constraint"] = bool(not outside[-1])
        if left.any() and not outside[-1]:
            m["returned_at_s"] = float(t[np.flatnonzero(outside)[-1] + 1])
    return m

"""A run's verdict: the loss-of-control rule, and the bounds a scenario puts on its metrics
(the ``metrics.requirements`` mapping).

Every run is judged, whether or not its scenario states requirements:

**Loss of control** (always a failure, bound or not), either of:

- the run ends with its attitude lost: ``max_i |q_ev,i|`` stays above
  :data:`~sappc.evaluation.metrics.LOSS_OF_CONTROL_FACTOR` times the scenario's
  ``metrics.settle_threshold`` from some time in the steady window (``t >= steady_from_s``) to its
  last sample (the metric ``control_lost_at_s``); a fault's transient that comes back within the
  bound is not a loss;
- the controller computed the torque of fewer than :data:`MIN_COMMANDED_FRACTION` of the run's
  samples it was active for (it held, zeroed or refused the rest: lost inputs, a withheld
  estimate, a starved real-time loop): the spacecraft flew open loop more than closed.  With
  flight modes, the samples outside TRACK (``inactive``: the mode's own law flew them) are not
  the controller's.

**Never tracked**: with flight modes, a run that never reached TRACK (its ``mode_sequence`` says
where it stayed).

**Non-finite**: a run whose state or torque became non-finite.

**Requirements**: ``requirements`` maps ``<metric>_max`` to an upper bound, for the numeric metrics
of :mod:`sappc.evaluation.metrics` listed in :data:`sappc.scenario.BOUNDED_METRICS` (validated by
:func:`sappc.scenario.check_requirements` when the scenario loads), e.g.::

    metrics:
      steady_from_s: 40.0
      requirements: {steady_max_abs_qev_max: 1.0e-4, settling_time_s_max: 20.0}

A bounded metric fails when it exceeds its bound or is unknown (``None``: a run that never settles
has no settling time; a bag without diagnostics has no band metrics).  The same check serves
``sappc simulate``, ``sappc run``, the per-run table of a campaign (:func:`lost_control`, on its
arrays) and ``sappc compare-controllers``, so that every path agrees on what failed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sappc.evaluation.metrics import LOSS_OF_CONTROL_FACTOR

__all__ = ["MIN_COMMANDED_FRACTION", "failed_requirements", "loss_of_control", "lost_control"]

#: The smallest share of a run's samples whose torque the controller must have computed: below it
#: the spacecraft flew open loop (zero or held torques) for most of the run.  Measured: every run of
#: the bundled scenarios computes at least 0.967 of its samples (the 90 deg prior withholds the
#: first 2 s); the 800 km orbit with the cross-product law that loses its attitude computes 0.41.
MIN_COMMANDED_FRACTION = 0.5


def lost_control(control_lost_at_s: ArrayLike, commanded: ArrayLike, samples: ArrayLike) -> NDArray[np.bool_]:
    """Which runs lost control (module docstring), on per-run arrays: ``control_lost_at_s`` (NaN:
    not lost), the samples the controller ``commanded`` and all its ``samples``."""
    lost_at = np.asarray(control_lost_at_s, dtype=np.float64)
    cmd, n = np.asarray(commanded, dtype=np.float64), np.asarray(samples, dtype=np.float64)
    starved = (n > 0) & (cmd < MIN_COMMANDED_FRACTION * n)
    return np.asarray(np.isfinite(lost_at) | starved, dtype=np.bool_)


def loss_of_control(metrics: Mapping[str, Any], controller: Mapping[str, Any] | None = None, *,
                    settle_threshold: float | None = None) -> list[str]:
    """The loss-of-control lines of a run (empty: none): its ``metrics`` (``control_lost_at_s``,
    ``steady_max_abs_qev``) and its ``controller`` summary (``commanded`` and ``samples``; ``None``
    or ``commanded`` ``None``: unknown, e.g. a bag without the controller's diagnostics)."""
    out = []
    lost_at = metrics.get("control_lost_at_s")
    if lost_at is not None:
        bound = "" if settle_threshold is None else f" {LOSS_OF_CONTROL_FACTOR * settle_threshold:g}"
        peak = metrics.get("steady_max_abs_qev")
        out.append(f"control lost: max |q_ev,i| above{bound} ({LOSS_OF_CONTROL_FACTOR:g} x the settling band) from {lost_at:g} s "
                   f"to the end" + ("" if peak is None else f" (up to {peak:.5g})"))
    cmd = None if controller is None else controller.get("commanded")
    n = None if controller is None else controller.get("samples")
    inactive = 0 if controller is None else int(controller.get("inactive") or 0)  # flight modes: the samples another mode's law flew
    if n is not None:
        n -= inactive
    if cmd is not None and n and bool(lost_control(np.nan, cmd, n)):
        of = f"of the {n} samples it was active for" if inactive else f"of {n} samples"
        out.append(f"control lost: the controller computed the torque of {cmd} {of} ({cmd / n:.0%}, fewer than {MIN_COMMANDED_FRACTION:.0%})")
    return out


def failed_requirements(metrics: Mapping[str, Any], requirements: Mapping[str, float], controller: Mapping[str, Any] | None = None,
                        *, settle_threshold: float | None = None) -> list[str]:
    """The ways a run fails, each as one line (empty: the run passes): non-finite, the
    loss-of-control rule (:func:`loss_of_control`, always applied) and the ``requirements`` its
    ``metrics`` break."""
    failed = [] if metrics.get("finite", True) else ["the run became non-finite"]
    failed += loss_of_control(metrics, controller, settle_threshold=settle_threshold)
    if "mode_sequence" in metrics and metrics.get("time_to_track_s") is None:
        failed.append("the flight never reached TRACK (modes flown: " + ", ".join(metrics["mode_sequence"]) + ")")
    for key, bound in requirements.items():
        name = key[: -len("_max")]
        value = metrics.get(name)
        if value is None:
            failed.append(f"{name} is unknown (required <= {bound:g})")
        elif value > bound:
            failed.append(f"{name} = {value:.6g} > {bound:g}")
    return failed

"""What a scenario calls a failed run: bounds on its metrics (the ``metrics.requirements`` mapping).

``requirements`` maps ``<metric>_max`` to an upper bound, for the numeric metrics of
:mod:`sappc.evaluation.metrics` listed in :data:`sappc.scenario.BOUNDED_METRICS` (validated by
:func:`sappc.scenario.check_requirements` when the scenario loads), e.g.::

    metrics:
      steady_from_s: 40.0
      requirements: {steady_max_abs_qev_max: 1.0e-4, settling_time_s_max: 20.0}

A run fails when a bounded metric exceeds its bound, is unknown (``None``: a run that never
settles has no settling time; a bag without diagnostics has no band metrics), or when the run is
not finite (always a failure, bound or not).  The same check serves ``sappc simulate``,
``sappc run`` and the per-run table of a campaign, so that the three paths agree on what failed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["failed_requirements"]

def failed_requirements(metrics: Mapping[str, Any], requirements: Mapping[str, float]) -> list[str]:
    """The requirements a run's ``metrics`` break, each as one line (empty: the run passes)."""
    failed = [] if metrics.get("finite", True) else ["the run became non-finite"]
    for key, bound in requirements.items():
        name = key[: -len("_max")]
        value = metrics.get(name)
        if value is None:
            failed.append(f"{name} is unknown (required <= {bound:g})")
        elif value > bound:
            failed.append(f"{name} = {value:.6g} > {bound:g}")
    return failed

"""Checks that a drawn figure shows what it drew (issue 25, 2.5: the Monte Carlo steady-state figure
was three empty log axes, and the suite passed because it only looked at the file's size).

:func:`capture_figures` records every figure saved while a test runs (``Figure.savefig``,
whoever calls it: the report, the campaign, the tuning study); :func:`assert_every_axes_shows_data`
then requires, in every axes of every figure, data points of its lines and line collections (in
data coordinates: reference lines such as ``axhline`` do not count) that are finite, positive on a
log axis, and inside the axes' view limits.  :data:`NO_EMPTY_LOG_AXES` turns matplotlib's
"Data has no positive values" warning into an error, for the test modules that draw figures.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

__all__ = ["NO_EMPTY_LOG_AXES", "assert_every_axes_shows_data", "capture_figures", "points_in_view"]

#: ``pytestmark`` of a module that draws figures: the warning of an empty log axis is an error.
NO_EMPTY_LOG_AXES = pytest.mark.filterwarnings("error:Data has no positive values:UserWarning")


def capture_figures(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """A list that receives every matplotlib figure saved from now on (``Figure.savefig``)."""
    from matplotlib.figure import Figure

    saved: list[Any] = []
    original = Figure.savefig

    def savefig(self: Any, *args: Any, **kwargs: Any) -> Any:
        saved.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return saved


def points_in_view(ax: Any) -> int:
    """Data points of ``ax``'s lines and line collections that are finite (positive on a log axis)
    and inside its view limits."""
    from matplotlib.collections import LineCollection

    blocks = [line.get_xydata() for line in ax.get_lines() if line.get_transform() == ax.transData]
    for c in ax.collections:
        if isinstance(c, LineCollection) and c.get_transform() == ax.transData:
            blocks += [np.asarray(seg, dtype=np.float64) for seg in c.get_segments()]
    if not blocks:
        return 0
    xy = np.concatenate([np.asarray(b, dtype=np.float64).reshape(-1, 2) for b in blocks])
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    ok = np.isfinite(xy).all(axis=1) & (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
    if ax.get_yscale() == "log":
        ok &= xy[:, 1] > 0.0
    if ax.get_xscale() == "log":
        ok &= xy[:, 0] > 0.0
    return int(np.count_nonzero(ok))


def assert_every_axes_shows_data(figures: list[Any], *, at_least: int = 1, empty_ok: Callable[[str, Any], bool] | None = None) -> None:
    """Every axes of every figure shows at least ``at_least`` data points (:func:`points_in_view`),
    except those for which ``empty_ok(figure title, axes)`` is true (a test that expects nothing
    there), which must then say so ("nothing to draw", :func:`sappc.analysis.plots._finish`)."""
    assert figures, "no figure was saved"
    for fig in figures:
        title = fig._suptitle.get_text() if fig._suptitle is not None else "(untitled)"
        for ax in fig.axes:
            n = points_in_view(ax)
            if empty_ok is not None and empty_ok(title, ax):
                assert n == 0 and any("nothing to draw" in t.get_text() for t in ax.texts), (title, ax.get_ylabel(), n)
                continue
            assert n >= at_least, f"{title}: the axes {ax.get_ylabel()!r} ({ax.get_title()!r}) shows {n} data points"

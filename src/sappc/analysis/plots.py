"""Paper-style figures: of a run (each q_ev component with its performance function and
constraint band, whole run and steady-state zoom; the actuator torques; the transformed error
and Lyapunov values; the reaction wheels' speeds and motor torques against their limits), of
several runs overlaid, of a torque re-run, of a Monte Carlo campaign."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from numpy.typing import NDArray

from sappc.evaluation.history import History

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn, not with this module
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from spacecraft_sim.core.wheels import ReactionWheels

__all__ = ["CAMPAIGN_FIGURE_SHAPES", "RUN_FIGURE_SHAPES", "FigureWorker", "campaign_figures", "draw_jobs", "house_style", "plot_campaign", "plot_compare",
           "plot_estimator", "plot_run", "plot_torque_rerun", "plot_wheels"]

Array = NDArray[np.float64]
_F = TypeVar("_F", bound=Callable[..., Any])


def house_style(draw: _F) -> _F:
    """Draw with matplotlib's own defaults (its ``default`` style), whatever the process's global
    settings are: another library may change them on import (Basilisk's ``simHelpers`` sets
    ``figure.autolayout``, the tick and label sizes, a figure size), and the project's figures
    must not depend on what else was imported (or on a user's ``matplotlibrc``).  A decorator of
    every function that makes figures; matplotlib is imported when it is called (the Agg backend)."""

    @functools.wraps(draw)
    def drawn(*args: Any, **kwargs: Any) -> Any:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        with plt.style.context("default"):
            return draw(*args, **kwargs)

    return drawn  # type: ignore[return-value]


#: Subscripts 1 to 3 for axis labels.  Labels are plain Unicode, never mathtext: matplotlib's
#: mathtext parser costs ~0.3 s at first use, a sixth of a report's time budget.
_SUB = ("₁", "₂", "₃")


def _y_data(ax: Axes) -> list[Array]:
    """The y values of ``ax``'s lines and line collections in data coordinates (not the reference
    lines such as ``axhline``, whose x is in axes coordinates)."""
    from matplotlib.collections import LineCollection

    blocks = [np.asarray(line.get_ydata(), dtype=np.float64) for line in ax.get_lines() if line.get_transform() == ax.transData]
    # the paths' vertex arrays as they are (get_segments() rebuilds every segment point by point in
    # Python: half a second for a campaign's overlay of 200 runs)
    blocks += [np.asarray(path.vertices, dtype=np.float64)[:, 1] for c in ax.collections if isinstance(c, LineCollection)
               for path in c.get_paths()]
    return blocks


def _positive_data(ax: Axes) -> bool:
    """Whether ``ax``'s data (:func:`_y_data`) hold a finite value > 0."""
    return any(bool(np.any(np.isfinite(b) & (b > 0.0))) for b in _y_data(ax))


def _finite_data(ax: Axes) -> bool:
    """Whether ``ax``'s data (:func:`_y_data`) hold a finite value."""
    return any(bool(np.any(np.isfinite(b))) for b in _y_data(ax))


def _log_axis(ax: Axes) -> bool:
    """Log scale on y with decade labels written 10⁻⁵ in Unicode (the default formatter uses mathtext),
    once the axes' data are drawn; return whether it is log.  Data without a positive value (an
    error that is exactly zero, a performance function the controller never had) stay on a linear
    axis with a note: a log axis would be empty ("Data has no positive values")."""
    from matplotlib.ticker import FuncFormatter, NullLocator

    if not _positive_data(ax):
        if _finite_data(ax):
            ax.text(0.01, 0.04, "no positive value to draw on a log scale: linear scale", transform=ax.transAxes, fontsize=7,
                    color="tab:red")
        return False
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(_decade_label))
    # no minor ticks: over the 6 to 10 decades of an error's log plot, matplotlib makes 8 unlabelled
    # ticks a decade, each an object with its own line and text; creating them was a third of a report
    ax.yaxis.set_minor_locator(NullLocator())
    return True


def _decade_label(value: float, _pos: int) -> str:
    if value <= 0 or not np.isfinite(value):
        return ""
    exponent = np.log10(value)
    if abs(exponent - round(exponent)) > 1e-9:
        return ""
    return "10" + str(int(round(exponent))).translate(_SUPERSCRIPT)


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")

#: zlib level of the PNG files: 1 encodes ~3x faster than matplotlib's default 6 for files ~1.4x
#: larger (about 100 kB a figure), which matters for a report made in under 2 s.
PNG_COMPRESS_LEVEL = 1

#: The figures' resolution in their PNG files [dots per inch].
PNG_DPI = 110


def _save_png(fig: Figure, path: Path) -> None:
    """``fig.savefig(path, dpi=PNG_DPI)``, the PNG encoded here rather than by Pillow: the pixels
    matplotlib renders for ``savefig`` (its ``rgba`` output) and the chunks its PNG files have (the
    ``Software`` text, the resolution), each row stored as its difference from the row above (PNG
    filter 2) and deflated at :data:`PNG_COMPRESS_LEVEL`.  Pillow tries the five filters on every
    row (14 ms a figure at 880 x 825 pixels, against 7 ms here) for files ~10 % smaller."""
    import io
    import struct
    import zlib

    import matplotlib

    raw = io.BytesIO()
    fig.savefig(raw, format="rgba", dpi=PNG_DPI)
    pixels = raw.getbuffer()
    # the canvas's size in pixels as matplotlib's renderer takes it (int() of the size in inches times the dpi)
    width, height = (int(v * PNG_DPI) for v in fig.get_size_inches())
    if width * height * 4 != pixels.nbytes:  # (never seen): leave it to matplotlib
        del pixels
        fig.savefig(path, dpi=PNG_DPI, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
        return
    rows = np.frombuffer(pixels, np.uint8).reshape(height, width * 4)
    filtered = np.empty((height, width * 4 + 1), np.uint8)
    filtered[:, 0] = 2  # "Up"
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # modulo 256
    del rows, pixels

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    per_metre = int(PNG_DPI / 0.0254 + 0.5)
    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0))  # 8-bit RGBA
                     + chunk(b"tEXt", f"Software\0Matplotlib version{matplotlib.__version__}, https://matplotlib.org/".encode("latin-1"))
                     + chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1))
                     + chunk(b"IDAT", zlib.compress(filtered.data, PNG_COMPRESS_LEVEL))
                     + chunk(b"IEND", b""))


def _finish(fig: Figure, path: Path, title: str, paths: list[Path], *, margins: dict[str, float] | None = None) -> None:
    """Title, lay out (``tight_layout`` unless fixed ``margins`` are given: it costs ~1 s on log
    axes with many lines), save as PNG at :data:`PNG_DPI` (:func:`_save_png`), close, and record the path."""
    import matplotlib.pyplot as plt

    fig.suptitle(title)
    for ax in fig.axes:
        if not _finite_data(ax):  # e.g. a bag without the controller's diagnostics: say so, not an empty frame
            ax.text(0.5, 0.5, "nothing to draw: no finite value", transform=ax.transAxes, ha="center", va="center", fontsize=8,
                    color="tab:red")
    if margins is None:
        fig.tight_layout()
    else:
        fig.subplots_adjust(**margins)
    _save_png(fig, path)
    plt.close(fig)
    paths.append(path)


def _mark_faults(ax: Axes, fault_windows: Sequence[tuple[float, float]], t_end: float) -> None:
    for start, end in fault_windows:
        ax.axvspan(start, min(end, t_end), color="tab:red", alpha=0.15, lw=0)


#: Fixed margins of the 3-row figures: ``tight_layout`` would cost ~0.25 s per figure (it draws
#: the figure once more to measure it), most of a report's time budget.
_ROWS_MARGINS = dict(left=0.12, right=0.97, bottom=0.07, top=0.93, hspace=0.12)

#: Line colours of the runs of a comparison, in order.
_RUN_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray")


def _rows(n: int = 3, height: float = 7.5) -> tuple[Figure, NDArray[np.object_]]:
    """A figure of ``n`` (at least 2) rows sharing the time axis, and its array of Axes: one that
    :func:`_prepare_rows` made in advance when there is one of that shape, else a new one."""
    return _figure(n, height, 1)


def _columns(cols: int, height: float) -> tuple[Figure, NDArray[np.object_]]:
    """A figure of one row of ``cols`` (at least 2) axes sharing the y axis, 4 in wide each, and
    its array of Axes: one made in advance (:func:`_prepare_rows` of ``(1, height, cols)``) when
    there is one, else a new one."""
    return _figure(1, height, cols)


def _figure(n: int, height: float, cols: int) -> tuple[Figure, NDArray[np.object_]]:
    """:func:`_rows` (``cols`` 1) or :func:`_columns` (``n`` 1)."""
    pool = _PREPARED.get((n, height, cols))
    if pool:
        return pool.pop(0)
    return _new_figure(n, height, cols)


def _new_figure(n: int, height: float, cols: int) -> tuple[Figure, NDArray[np.object_]]:
    """A new figure of :func:`_figure`'s shape: ``n`` rows sharing x, 8 in wide (``cols`` 1), or
    one row of ``cols`` axes sharing y, 4 in wide each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if cols == 1:
        return plt.subplots(n, 1, figsize=(8, height), sharex=True)
    return plt.subplots(1, cols, figsize=(4.0 * cols, height), sharey=True)


#: The shape of a figure made in advance (:func:`_prepare_rows`'s arguments): (rows, height) of
#: :func:`_rows`, or (1, height, columns) of :func:`_columns`.
FigureShape = tuple[int, float] | tuple[int, float, int]

#: Figures of :func:`_rows` and :func:`_columns` made in advance (:func:`_prepare_rows`), by
#: (rows, height, columns).
_PREPARED: dict[tuple[int, float, int], list[tuple[Figure, NDArray[np.object_]]]] = {}

#: The figures a :class:`FigureWorker` prepares for :func:`plot_run`'s figures of every run while
#: it waits, in this order (``qev``, ``qev_zoom`` and ``qev_log`` are (3, 7.5), ``torque``
#: (3, 6.5), ``eps_lyapunov`` (2, 6.0)).  The two processes that then draw each have a copy of
#: what was prepared, and in :data:`_RUN_JOBS_ORDER` one of them normally draws ``qev`` and
#: ``qev_zoom``, the other ``qev_log``, ``torque`` and ``eps_lyapunov``: these three serve the
#: second process's figures and the first's first one.  The first's second is made when drawn,
#: which evens the two processes out (about 0.16 s each on machine B); a fourth prepared here
#: would only delay both when the bag's data come while it is being made.
RUN_FIGURE_SHAPES: tuple[FigureShape, ...] = ((3, 7.5), (3, 6.5), (2, 6.0))

#: The figures a :class:`FigureWorker` prepares for :func:`plot_campaign` while the runs go: one
#: (3, 8.0), the trajectory figures' shape, then one (1, 3.8, 3), the error figures' (a row of
#: three).  The worker's two processes each take one trajectory figure first, then one error
#: figure (:data:`_CAMPAIGN_JOBS_ORDER`), each on its own copy of the prepared ones (both forked
#: after they were made): 0.03 s of each trajectory figure's 0.2 s, 0.035 s of each error figure's
#: 0.115 s (machine A, medians of 12), on the critical path at the campaign's end.  They are made
#: while the command starts, on the core its own start leaves idle.
CAMPAIGN_FIGURE_SHAPES: tuple[FigureShape, ...] = ((3, 8.0), (1, 3.8, 3))

#: Ticks made in advance on each axis of a prepared figure (:func:`_prepare_rows`): the time axis of
#: a 60 s run has 9 major tick positions (-10 to 70 s), a y axis 6 to 10.
_PREPARED_TICKS = (9, 8)


def _prepare_rows(n: int, height: float, cols: int = 1) -> None:
    """Make a figure of :func:`_rows` now (or, ``cols`` > 1, of :func:`_columns`, ``n`` 1), with
    its axes' first ticks (each a group of lines and texts: creating them is a third of drawing a
    figure), for a later :func:`_rows` (:func:`_columns`) of that shape to take.  The figure drawn
    on it is the one a new figure gives: matplotlib creates the ticks of an axis from its tick
    settings whenever they are first needed, and applies a change of these settings to the ticks
    already made (``tests/tools/bag/test_report_processes.py`` and
    ``tests/tools/montecarlo/test_campaign_figures.py`` check every pixel).  Call it with the style
    the figures are drawn with (:func:`house_style`)."""
    fig, axes = _new_figure(n, height, cols)
    for ax in axes:
        for axis, ticks in zip((ax.xaxis, ax.yaxis), _PREPARED_TICKS):
            axis.get_major_ticks(ticks)
            axis.get_minor_ticks(1)
    _PREPARED.setdefault((n, height, cols), []).append((fig, axes))


def plot_run(
    h: History,
    out_dir: Path,
    *,
    title: str,
    fault_windows: Sequence[tuple[float, float]] = (),
    zoom_from_s: float = 15.0,
    run: int = 0,
    wheels: ReactionWheels | None = None,
    parallel: bool | None = None,
    worker: FigureWorker | None = None,
) -> list[Path]:
    """Write ``qev.png``, ``qev_zoom.png``, ``qev_log.png``, ``torque.png`` and
    ``eps_lyapunov.png`` to ``out_dir``, and ``wheels.png`` when the history has wheel records
    (:func:`plot_wheels`; the limits drawn are ``wheels``', when given); return their paths.
    Injected faults are shaded red.

    ``worker``: a :class:`FigureWorker` started earlier draws them (this process does not import
    matplotlib); else ``parallel``: draw them in two processes (:func:`draw_jobs`; ``None``: when
    that is safe).  The files are the same either way."""
    kwargs = dict(h=h, out_dir=out_dir, title=title, fault_windows=list(fault_windows), zoom_from_s=zoom_from_s, run=run, wheels=wheels)
    if worker is not None and worker.alive:
        return worker.draw(_run_jobs, kwargs, theirs=_RUN_JOBS_ORDER)
    return draw_jobs(_run_jobs(**kwargs), parallel=parallel)  # type: ignore[arg-type]


#: The order in which a :class:`FigureWorker`'s two processes take :func:`_run_jobs`' jobs (each
#: the next one left when done with its last): ``qev`` in one while the other draws ``qev_log``
#: and ``torque``, then ``qev_zoom`` and ``eps_lyapunov``.  The five figures take 0.29 to 0.30
#: CPU-s (machine B, 2026-12-06; the first one a process draws 15 to 20 ms more than the others);
#: in this order the busier process draws for 0.16 to 0.17 s, in the jobs' own order for 0.17 to
#: 0.18 s.  The figures that only some runs have come last.
_RUN_JOBS_ORDER = (0, 2, 3, 1, 4, 5, 6, 7)


def _run_jobs(
    h: History,
    out_dir: Path,
    *,
    title: str,
    fault_windows: Sequence[tuple[float, float]],
    zoom_from_s: float,
    run: int,
    wheels: ReactionWheels | None,
) -> list[Any]:
    """:func:`plot_run`'s figures, one job (a callable returning the paths it wrote) each, in order."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t = h.t
    t_end = float(t[-1])
    faults = list(fault_windows)
    q_ev = h.q_ev[:, run]

    def qev(name: str, mask: NDArray[np.bool_], zoom: bool) -> list[Path]:
        paths: list[Path] = []
        if not mask.any():
            return paths
        fig, axes = _rows()
        for i, ax in enumerate(axes):
            lower, upper = h.band_lower[mask, run, i], h.band_upper[mask, run, i]
            view = None
            if zoom:  # y range of q_ev and rho; the band is drawn only where it shows inside it
                both = np.concatenate((q_ev[mask, i], h.rho[mask, run, i]))
                both = both[np.isfinite(both)]
                lo, hi = (both.min(), both.max()) if both.size else (-1.0, 1.0)
                pad = 0.25 * max(hi - lo, 1e-6)
                view = (lo - pad, hi + pad)
            banded = bool(np.isfinite(lower).any() and np.isfinite(upper).any())  # no band where the law never ran
            if view is not None and banded and np.nanmax(lower) <= view[0] and np.nanmin(upper) >= view[1]:
                # the band holds the whole view (e.g. +-0.016 around a 1e-4 error): shading it
                # would colour the whole panel, so say where it is instead
                ax.text(0.01, 0.04, f"constraint band [{np.nanmin(lower):.3g}, {np.nanmax(upper):.3g}]: beyond this view",
                        transform=ax.transAxes, fontsize=7, color="tab:blue")
            else:
                ax.fill_between(t[mask], lower, upper, color="tab:blue", alpha=0.18, lw=0, label="constraint band")
            ax.plot(t[mask], h.rho[mask, run, i], "k--", lw=1.0, label=f"ρ{_SUB[i]}")
            ax.plot(t[mask], q_ev[mask, i], color="tab:blue", lw=1.3, label=f"q_ev{_SUB[i]}")
            _mark_faults(ax, faults, t_end)
            ax.set_ylabel(f"q_ev{_SUB[i]}")
            ax.grid(True, alpha=0.3)
            if view is not None:
                ax.set_ylim(*view)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / name, f"{title}: attitude error" + (" (zoom)" if zoom else ""), paths, margins=_ROWS_MARGINS)
        return paths

    def qev_log() -> list[Path]:
        # |q_ev| on a log scale: the steady state (1e-5) is invisible on the linear plots
        paths: list[Path] = []
        fig, axes = _rows()
        for i, ax in enumerate(axes):
            ax.plot(t, np.abs(h.rho[:, run, i]), "k--", lw=1.0, label=f"|ρ{_SUB[i]}|")
            ax.plot(t, np.abs(q_ev[:, i]), color="tab:blue", lw=1.2, label=f"|q_ev{_SUB[i]}|")
            _log_axis(ax)
            _mark_faults(ax, faults, t_end)
            ax.set_ylabel(f"|q_ev{_SUB[i]}|")
            ax.grid(True, alpha=0.3)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / "qev_log.png", f"{title}: attitude error magnitude", paths, margins=_ROWS_MARGINS)
        return paths

    def torque() -> list[Path]:
        paths: list[Path] = []
        fig, axes = _rows(height=6.5)
        for i, ax in enumerate(axes):
            ax.plot(t, h.torque_B[:, run, i], lw=1.0, color="tab:green", label=f"u{_SUB[i]}")
            _mark_faults(ax, faults, t_end)
            ax.set_ylabel(f"u{_SUB[i]} [N m]")
            ax.grid(True, alpha=0.3)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / "torque.png", f"{title}: actuator torque", paths, margins=_ROWS_MARGINS)
        return paths

    def eps_lyapunov() -> list[Path]:
        # the transformed error and the backstepping Lyapunov values
        paths: list[Path] = []
        fig, axes = _rows(2, height=6.0)
        for i in range(3):
            axes[0].plot(t, h.eps[:, run, i], lw=1.0, label=f"ε{_SUB[i]}")
            axes[1].plot(t, np.abs(h.V[:, run, i]), lw=1.0, label=f"V{_SUB[i]}")
        _log_axis(axes[1])
        for ax in axes:
            _mark_faults(ax, faults, t_end)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right", fontsize=8)
        axes[0].set_ylabel("ε (transformed error)")
        axes[1].set_ylabel("Lyapunov values")
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / "eps_lyapunov.png", f"{title}: transformed error and Lyapunov values", paths, margins=_ROWS_MARGINS)
        return paths

    def wheel_figures() -> list[Path]:
        if h.wheel_speed_rad_s is None or h.wheel_torque_Nm is None:
            return []
        limits = None  # the wheel set's, unless it is not the one recorded (another number of wheels)
        undelivered = None
        if wheels is not None and wheels.n == h.wheel_speed_rad_s.shape[2]:
            limits = (wheels.per_wheel("max_speed_rad_s"), wheels.per_wheel("max_torque_Nm"))
            # what the wheels' motors did not make of the command: tau + G u (friction aside)
            undelivered = h.torque_B[:, run] + h.wheel_torque_Nm[:, run] @ wheels.G.T
        return plot_wheels(h.t, h.wheel_speed_rad_s[:, run], h.wheel_torque_Nm[:, run], out_dir, title=title, limits=limits,
                           fault_windows=faults, undelivered_Nm=undelivered)

    def estimator_figures() -> list[Path]:
        return plot_estimator(h, out_dir, title=title, run=run, fault_windows=faults) if h.estimate is not None else []

    def mode_figures() -> list[Path]:
        return plot_modes(h, out_dir, title=title, run=run, fault_windows=faults) if h.mode is not None else []

    jobs = [lambda: qev("qev.png", np.ones_like(t, dtype=bool), False), lambda: qev("qev_zoom.png", t >= zoom_from_s, True),
            qev_log, torque, eps_lyapunov, wheel_figures, estimator_figures, mode_figures]
    return jobs


#: Each flight mode's colour in ``modes.png`` (:data:`sappc_modes.core.modes.MODE_NAMES`' order).
_MODE_COLORS = ("tab:purple", "tab:olive", "tab:green", "tab:red")


def mode_segments(t: Array, mode: NDArray[Any]) -> list[tuple[float, float, int]]:
    """The contiguous spans of one run's mode record (``t`` (T,), ``mode`` (T,)): ``(start, end,
    mode)`` each, a span ending where the next starts (the last at the last sample)."""
    m = np.asarray(mode, dtype=np.int64)
    if m.size == 0:
        return []
    starts = np.concatenate(([0], np.flatnonzero(m[1:] != m[:-1]) + 1))
    ends = np.append(starts[1:], m.size - 1)
    return [(float(t[a]), float(t[b]), int(m[a])) for a, b in zip(starts, ends)]


def plot_modes(h: History, out_dir: Path, *, title: str, run: int = 0, fault_windows: Sequence[tuple[float, float]] = ()) -> list[Path]:
    """``modes.png`` of a run with flight modes (docs/design/modes.md): the body rate's magnitude
    [deg/s] and the largest attitude-error component, on log axes, over a band per mode (the
    mode's name in the legend, once)."""
    from sappc_modes.core.modes import MODE_NAMES

    if h.mode is None:
        return []
    paths: list[Path] = []
    t = h.t
    rate = np.degrees(np.linalg.norm(h.omega_BN_B[:, run], axis=-1))
    err = np.max(np.abs(h.q_ev[:, run]), axis=-1)
    fig, axes = _rows(2, height=5.5)
    spans = mode_segments(t, h.mode[:, run])
    for ax, y, label in ((axes[0], rate, "|ω| [deg/s]"), (axes[1], err, "max |q_ev,i|")):
        named: set[int] = set()
        for start, end, m in spans:
            ax.axvspan(start, end, color=_MODE_COLORS[m % len(_MODE_COLORS)], alpha=0.15, lw=0,
                       label=MODE_NAMES[m] if m not in named and 0 <= m < len(MODE_NAMES) else None)
            named.add(m)
        ax.plot(t, np.where(y > 0, y, np.nan), color="tab:blue", lw=0.8, label=label)
        _log_axis(ax)
        _mark_faults(ax, fault_windows, float(t[-1]))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8, ncol=2)
        ax.set_ylabel(label)
    axes[-1].set_xlabel("time [s]")
    _finish(fig, out_dir / "modes.png", f"{title}: flight modes", paths, margins=dict(left=0.12, right=0.97, bottom=0.1, top=0.9, hspace=0.12))
    return paths


def _fork_is_safe() -> bool:
    """Whether this process may fork a child that draws figures: POSIX, two CPUs or more, one
    thread, and neither numba (its thread pool) nor rclpy (its executor's threads) loaded."""
    import os
    import sys
    import threading

    return (hasattr(os, "fork") and (os.cpu_count() or 1) > 1 and threading.active_count() == 1
            and not any(m in sys.modules for m in ("numba", "rclpy")))


@house_style
def draw_jobs(jobs: Sequence[Any], *, parallel: bool | None = None) -> list[Path]:
    """Run figure jobs (callables that draw and save figures and return their paths); return every
    path in the jobs' order.

    With ``parallel`` (``None``: when :func:`_fork_is_safe`), a forked child and this process take
    the jobs one at a time, in order, each the next one left when it is done with its last (two
    CPUs: about half the time; a child forked before matplotlib is imported imports it on its
    own); the files are the same as one process's.  The jobs that a child which failed did not
    send back are drawn again here."""
    return [p for paths in _draw_each(jobs, parallel=parallel) for p in paths]


def _draw_each(jobs: Sequence[Any], *, parallel: bool | None = None, unreaped: list[int] | None = None) -> list[list[Path]]:
    """:func:`draw_jobs`, the paths of each job apart (matplotlib imported and its style set by the
    caller).  ``unreaped``: where a child that sent every path it drew is put, to be waited for by
    the caller (its exit takes a few ms), instead of being waited for here."""
    import os

    jobs = list(jobs)
    if parallel is None:
        parallel = _fork_is_safe()
    if not parallel or len(jobs) < 2 or len(jobs) > 256:
        return [list(job()) for job in jobs]
    import json
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    queue_r, queue_w = os.pipe()  # the jobs' numbers, a byte each: a read of one byte takes one job, in one process
    os.write(queue_w, bytes(range(len(jobs))))
    os.close(queue_w)
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: draw, send the paths, leave without the parent's exit handlers
        code = 1
        try:
            os.close(read_end)
            done = {i: [str(p) for p in paths] for i, paths in _take_jobs(queue_r, jobs).items()}
            with os.fdopen(write_end, "w") as f:
                json.dump(done, f)
            code = 0
        finally:
            os._exit(code)
    os.close(write_end)
    try:
        drawn = _take_jobs(queue_r, jobs)
    finally:
        os.close(queue_r)
        with os.fdopen(read_end) as f:
            text = f.read()
    try:  # written once the queue is empty: the jobs it took, each done
        theirs = {int(i): [Path(p) for p in paths] for i, paths in json.loads(text).items()}
    except ValueError:
        theirs = {}
    if unreaped is not None and theirs.keys() | drawn.keys() == set(range(len(jobs))):
        unreaped.append(pid)
    else:
        os.waitpid(pid, 0)
    drawn.update(theirs)
    for i, job in enumerate(jobs):  # a child that failed: the jobs it took and did not send back
        if i not in drawn:
            drawn[i] = list(job())
    return [drawn[i] for i in range(len(jobs))]


def _take_jobs(queue: int, jobs: Sequence[Any]) -> dict[int, list[Path]]:
    """Draw the jobs whose numbers this process reads from the pipe ``queue``, one at a time, until
    it is empty; return their paths by number."""
    import os

    drawn: dict[int, list[Path]] = {}
    while number := os.read(queue, 1):
        drawn[number[0]] = list(jobs[number[0]]())
    return drawn


def _import_matplotlib() -> None:
    """Import matplotlib (the Agg backend, pyplot) without writing the docstrings of its artists'
    ``set`` methods: on import, matplotlib lists every property of each artist class into them
    (:func:`matplotlib.artist.kwdoc`), a quarter of its import time (0.06 of 0.26 s on machine B);
    only ``help()`` reads them, and a figure process never calls it.  Their signatures and every
    behaviour are matplotlib's own."""
    import matplotlib.artist as martist

    kwdoc = martist.kwdoc
    martist.kwdoc = lambda artist: ""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot  # noqa: F401
    finally:
        martist.kwdoc = kwdoc


def _prepare_until_readable(shapes: Sequence[FigureShape], fd: int) -> None:
    """:func:`_prepare_rows` of each of ``shapes`` in turn until the file descriptor ``fd`` has
    something to read (a task: its figures are drawn then, in two processes)."""
    import select

    for shape in shapes:
        if select.select([fd], [], [], 0)[0]:
            return
        _prepare_rows(*shape)


class FigureWorker:
    """A child process forked now, which imports matplotlib while this process goes on (``sappc
    report`` reads the bag meanwhile), makes figures of the shapes ``prepare`` in advance
    (:func:`_prepare_rows`, until a task comes), then draws the figures it is sent
    (:meth:`draw`) in two processes (:func:`draw_jobs`: it forks once more, with matplotlib
    imported and the prepared figures made).

    Started only where forking is safe (:func:`_fork_is_safe`; else :attr:`alive` is false and
    the figures are drawn here).  Use it as a context manager: leaving it ends the child; a child
    whose parent ended without a word reads the end of its pipe and leaves."""

    def __init__(self, prepare: Sequence[FigureShape] = ()) -> None:
        import os
        import sys

        self.pid = 0
        self._send = self._receive = -1
        if not _fork_is_safe():
            return
        sys.stdout.flush()
        sys.stderr.flush()
        task_r, task_w = os.pipe()
        done_r, done_w = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(task_w)
            os.close(done_r)
            self._serve(task_r, done_w, tuple(prepare))  # never returns
        os.close(task_r)
        os.close(done_w)
        self.pid, self._send, self._receive = pid, task_w, done_r

    @staticmethod
    def _serve(task_r: int, done_w: int, prepare: tuple[FigureShape, ...]) -> None:
        import json
        import os
        import pickle
        import signal
        import traceback

        # Ctrl-C is the parent's to handle (sappc.__main__: one line, exit 130): it then closes
        # the pipe, and this process leaves (without a traceback of its own on the terminal)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        code = 1
        try:
            _import_matplotlib()  # the point: it overlaps the parent's work
            house_style(_prepare_until_readable)(prepare, task_r)
            with os.fdopen(task_r, "rb") as f:
                try:
                    task = pickle.load(f)
                except EOFError:  # the parent closed without a task
                    task = None
            if task is not None:
                make_jobs, kwargs, theirs = task
                jobs = make_jobs(**kwargs)
                helper: list[int] = []
                done = house_style(_draw_each)([jobs[i] for i in theirs], unreaped=helper)
                with os.fdopen(done_w, "w") as f:
                    json.dump([[str(p) for p in paths] for paths in done], f)
                for pid in helper:  # (after the paths are sent)
                    os.waitpid(pid, 0)
            code = 0
        except BaseException:  # noqa: BLE001  (the parent draws the figures itself)
            traceback.print_exc()
        finally:
            os._exit(code)

    @property
    def alive(self) -> bool:
        """Whether the child was started and has not been used or closed."""
        return self.pid > 0 and self._send >= 0

    def draw(self, make_jobs: Any, kwargs: dict[str, Any], theirs: Sequence[int] | None = None) -> list[Path]:
        """Have the child draw jobs ``theirs`` (``None``: every one) of ``make_jobs(**kwargs)`` (a
        module-level function: it is sent by name), draw the others here, and return every path in
        the jobs' order.  A child that failed has its jobs drawn again here.  This process imports
        matplotlib only to draw."""
        return self.send(make_jobs, kwargs, theirs)()

    def send(self, make_jobs: Any, kwargs: dict[str, Any], theirs: Sequence[int] | None = None) -> Callable[[], list[Path]]:
        """:meth:`draw` in two steps: send the child its jobs now and return the function that
        draws the others here, waits for the child's and returns what :meth:`draw` returns (this
        process goes on meanwhile: ``sappc montecarlo`` writes its table while its figures are
        drawn).  A function never called leaves the child to :meth:`close`, which waits for it."""
        import os
        import pickle

        jobs = make_jobs(**kwargs)
        theirs = list(range(len(jobs))) if theirs is None else [i for i in theirs if i < len(jobs)]
        import threading

        def send(fd: int) -> None:  # in a thread: the pipe holds 64 kB, the child reads once matplotlib is imported
            try:
                with os.fdopen(fd, "wb") as f:
                    pickle.dump((make_jobs, kwargs, theirs), f, protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:  # noqa: BLE001  (the child is gone, or a value would not pickle: its jobs are drawn here below)
                pass

        sender = threading.Thread(target=send, args=(self._send,), daemon=True)
        self._send = -1
        sender.start()
        return functools.partial(self._collect, jobs, theirs, sender)

    def _collect(self, jobs: Sequence[Any], theirs: list[int], sender: Any) -> list[Path]:
        """The second step of :meth:`send`."""
        import json
        import os

        mine_jobs = [i for i in range(len(jobs)) if i not in theirs]
        mine = house_style(lambda: {i: jobs[i]() for i in mine_jobs})() if mine_jobs else {}
        sender.join()
        with os.fdopen(self._receive, "r") as f:
            self._receive = -1
            text = f.read()
        try:  # the child writes its paths once every job is done; it is waited for in close()
            got = json.loads(text)
        except ValueError:
            got = None
        if not isinstance(got, list) or len(got) != len(theirs):  # it failed: its jobs are drawn here
            self._wait()
            got = None
        drawn = ({i: [Path(p) for p in paths] for i, paths in zip(theirs, got)} if got is not None
                 else house_style(lambda: {i: jobs[i]() for i in theirs})())
        return [p for i in range(len(jobs)) for p in (mine[i] if i in mine else drawn[i])]

    def _wait(self) -> int:
        import os

        if self.pid <= 0:
            return -1
        _, status = os.waitpid(self.pid, 0)
        self.pid = 0
        return status

    def close(self) -> None:
        """End the child (if it was not used: it reads the end of its pipe and leaves)."""
        import os

        for fd in (self._send, self._receive):
            if fd >= 0:
                os.close(fd)
        self._send = self._receive = -1
        self._wait()

    def __enter__(self) -> FigureWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@house_style
def plot_estimator(h: History, out_dir: Path, *, title: str, run: int = 0, fault_windows: Sequence[tuple[float, float]] = ()) -> list[Path]:
    """``estimator.png``: the estimate against the truth with the filter's own 3-sigma bounds: per
    axis, the attitude error (:func:`sappc.evaluation.estimation.attitude_errors`, the true
    attitude relative to the estimate) [rad] and, when the truth of the gyro bias was recorded, the
    bias error [rad/s], each inside +-3 sqrt(P_ii) shaded; ``estimator_nis.png``: the normalised
    innovation squared of each tracker update against its 99 % chi-square line (3 dof)."""
    import matplotlib

    matplotlib.use("Agg")
    from sappc.evaluation.estimation import attitude_errors

    est = h.estimate
    assert est is not None
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    t, t_end = h.t, float(h.t[-1])
    a = attitude_errors(est.q_BN[:, run], h.q_BN[:, run])
    sigma = np.sqrt(np.abs(np.diagonal(est.covariance[:, run], axis1=1, axis2=2)))
    rows = [("attitude error [rad]", a, sigma[:, :3])]
    if est.gyro_bias_true is not None:
        rows.append(("bias error [rad/s]", est.gyro_bias_true[:, run] - est.gyro_bias[:, run], sigma[:, 3:]))
    fig, axes = _rows(3 * len(rows), height=3.0 * 3 * len(rows) / 2)
    for r, (label, err, sig) in enumerate(rows):
        for i in range(3):
            ax = axes[3 * r + i]
            ax.fill_between(t, -3.0 * sig[:, i], 3.0 * sig[:, i], color="tab:green", alpha=0.25, lw=0, label="±3σ (the filter's)")
            ax.plot(t, err[:, i], lw=0.8, color="tab:blue", label="true − estimated" if r == 0 else None)
            _mark_faults(ax, fault_windows, t_end)
            ax.set_ylabel(f"{label.split(' [')[0]} {'xyz'[i]}\n[{label.split('[')[1]}")
            ax.grid(True, alpha=0.3)
            finite = np.isfinite(err[:, i]) & np.isfinite(sig[:, i])
            if finite.any():  # the error and its bound after the start, not the prior's first sample
                late = finite & (t >= t[finite][0] + 1.0) if np.any(finite & (t >= t[finite][0] + 1.0)) else finite
                top = float(np.max(np.maximum(np.abs(err[late, i]), 3.0 * sig[late, i])))
                if top > 0.0:
                    ax.set_ylim(-1.2 * top, 1.2 * top)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    _finish(fig, out_dir / "estimator.png", f"{title}: estimation errors and the filter's 3σ", paths, margins=_ROWS_MARGINS)
    nis = est.nis[:, run]
    updates = np.isfinite(nis) & np.concatenate(([True], np.diff(nis) != 0.0))  # a new value: a tracker sample compared
    if updates.any():
        from scipy.special import chdtri  # (not scipy.stats: half a second to import)

        fig, ax = plt_subplots()
        ax.plot(t[updates], nis[updates], ".", ms=2, color="tab:blue", label="NIS of each tracker sample")
        ax.axhline(3.0, color="tab:green", lw=0.8, ls="--", label="3 (its mean when consistent)")
        ax.axhline(float(chdtri(3, 0.01)), color="tab:red", lw=0.8, ls="--", label="99 % (chi-square, 3 dof)")
        _log_axis(ax)
        _mark_faults(ax, fault_windows, t_end)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("NIS")
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(loc="upper right", fontsize=8)
        _finish(fig, out_dir / "estimator_nis.png", f"{title}: normalised innovation squared", paths)
    return paths


def plt_subplots() -> tuple[Figure, Axes]:
    """One axes, the size of the single-panel figures."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.6))
    return fig, ax


@house_style
def plot_wheels(t: Array, speed_rad_s: Array, torque_Nm: Array, out_dir: Path, *, title: str,
                limits: tuple[Array, Array] | None = None, fault_windows: Sequence[tuple[float, float]] = (),
                undelivered_Nm: Array | None = None) -> list[Path]:
    """``wheels.png``: each reaction wheel's speed relative to the body (``speed_rad_s`` (T, W))
    and its motor torque (``torque_Nm`` (T, W)), one colour per wheel, with ``limits`` = (speed
    limits (W,), motor torque limits (W,)) dashed at plus and minus (one pair of black lines when
    every wheel has the same limit, else each wheel's in its colour); no limit lines without them.
    ``undelivered_Nm`` (T, 3): the commanded body torque the motors did not make (``tau + G u``),
    in a third panel, when given."""
    import matplotlib

    matplotlib.use("Agg")

    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    t_end = float(t[-1])
    fig, axes = _rows(2 if undelivered_Nm is None else 3, height=6.0 if undelivered_Nm is None else 8.0)
    colors = [f"C{i % 10}" for i in range(speed_rad_s.shape[1])]
    if undelivered_Nm is not None:
        for i in range(3):
            axes[2].plot(t, undelivered_Nm[:, i], lw=1.0, label="xyz"[i])
        _mark_faults(axes[2], fault_windows, float(t[-1]))
        axes[2].set_ylabel("not delivered [N m]")
        axes[2].grid(True, alpha=0.3)
        axes[2].legend(loc="upper right", fontsize=8, ncol=3)
    for ax, values, lim, label in ((axes[0], speed_rad_s, None if limits is None else limits[0], "speed [rad/s]"),
                                   (axes[1], torque_Nm, None if limits is None else limits[1], "motor torque [N m]")):
        for i in range(values.shape[1]):
            ax.plot(t, values[:, i], color=colors[i], lw=1.0, label=f"wheel {i + 1}")
        if lim is not None and np.all(lim == lim[0]):
            for sign in (1.0, -1.0):
                ax.axhline(sign * float(lim[0]), color="k", ls="--", lw=0.9, label="limit" if sign > 0 else None)
        elif lim is not None:
            for i, value in enumerate(lim):
                for sign in (1.0, -1.0):
                    ax.axhline(sign * float(value), color=colors[i], ls="--", lw=0.8)
        _mark_faults(ax, fault_windows, t_end)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[-1].set_xlabel("time [s]")
    what = "dashed: their limits" if limits is not None else "limits unknown: no scenario"
    _finish(fig, out_dir / "wheels.png", f"{title}: reaction wheels ({what})", paths, margins=_ROWS_MARGINS)
    return paths


@house_style
def plot_compare(runs: list[tuple[str, History]], out_dir: Path, *, title: str,
                 fault_windows: Sequence[tuple[float, float]] = ()) -> list[Path]:
    """Overlay several runs, as the paper's comparison figures: ``compare_qev.png`` (each q_ev
    component with its run's performance function dashed), ``compare_qev_log.png`` and
    ``compare_torque.png``.  Each run is one colour, labelled."""
    import matplotlib

    matplotlib.use("Agg")

    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    t_end = max(float(h.t[-1]) for _, h in runs)
    faults = list(fault_windows)
    for name, log in (("compare_qev.png", False), ("compare_qev_log.png", True)):
        fig, axes = _rows()
        for i, ax in enumerate(axes):
            for n, (label, h) in enumerate(runs):
                c = _RUN_COLORS[n % len(_RUN_COLORS)]
                q, rho = h.q_ev[:, 0, i], h.rho[:, 0, i]
                if log:
                    q, rho = np.abs(q), np.abs(rho)
                ax.plot(h.t, rho, "--", color=c, lw=0.9)
                ax.plot(h.t, q, color=c, lw=1.2, label=label)
            if log:
                _log_axis(ax)
            _mark_faults(ax, faults, t_end)
            ax.set_ylabel(f"|q_ev{_SUB[i]}|" if log else f"q_ev{_SUB[i]}")
            ax.grid(True, alpha=0.3, which="both" if log else "major")
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / name, f"{title}: attitude error (dashed: each run's performance function)", paths, margins=_ROWS_MARGINS)
    fig, axes = _rows(height=6.5)
    for i, ax in enumerate(axes):
        for n, (label, h) in enumerate(runs):
            ax.plot(h.t, h.torque_B[:, 0, i], color=_RUN_COLORS[n % len(_RUN_COLORS)], lw=1.0, label=label)
        _mark_faults(ax, faults, t_end)
        ax.set_ylabel(f"u{_SUB[i]} [N m]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    _finish(fig, out_dir / "compare_torque.png", f"{title}: actuator torque", paths, margins=_ROWS_MARGINS)
    estimating = [(label, h) for label, h in runs if h.estimate is not None]
    if estimating:  # the attitude estimation error of each run with an estimator, its 3 sigma dashed
        from sappc.evaluation.estimation import attitude_errors

        fig, axes = _rows()
        for i, ax in enumerate(axes):
            for n, (label, h) in enumerate(runs):
                if h.estimate is None:
                    continue
                c = _RUN_COLORS[n % len(_RUN_COLORS)]
                err = attitude_errors(h.estimate.q_BN[:, 0], h.q_BN[:, 0])[:, i]
                three_sigma = 3.0 * np.sqrt(np.abs(h.estimate.covariance[:, 0, i, i]))
                ax.plot(h.t, three_sigma, "--", color=c, lw=0.8)
                ax.plot(h.t, -three_sigma, "--", color=c, lw=0.8)
                ax.plot(h.t, err, color=c, lw=0.9, label=label)
            _mark_faults(ax, faults, t_end)
            ax.set_ylabel(f"attitude error {'xyz'[i]} [rad]")
            ax.grid(True, alpha=0.3)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / "compare_estimator.png", f"{title}: attitude estimation error (dashed: each run's ±3σ)", paths,
                margins=_ROWS_MARGINS)
    return paths


@house_style
def plot_torque_rerun(t: Array, recorded: Array, recomputed: Array, out_dir: Path, *, title: str) -> list[Path]:
    """``rerun_torque.png``: recorded and recomputed torque per axis, and their difference."""
    import matplotlib

    matplotlib.use("Agg")

    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    fig, axes = _rows(4, height=8.0)
    for i in range(3):
        axes[i].plot(t, recorded[:, i], color="tab:green", lw=1.2, label="recorded")
        axes[i].plot(t, recomputed[:, i], color="tab:purple", lw=1.0, ls="--", label="recomputed")
        axes[i].set_ylabel(f"u{_SUB[i]} [N m]")
        axes[i].grid(True, alpha=0.3)
        axes[3].plot(t, recomputed[:, i] - recorded[:, i], lw=1.0, label=f"Δu{_SUB[i]}")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[3].legend(loc="upper right", fontsize=8)
    axes[3].set_ylabel("recomputed - recorded")
    axes[3].grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    _finish(fig, out_dir / "rerun_torque.png", f"{title}: torque re-run through the controller core", paths, margins=_ROWS_MARGINS)
    return paths


#: Margin of a log axis's view around its data, as a factor (a tenth of a decade each side).
_LOG_MARGIN = 10.0**0.1
#: Margin of a linear axis's view around its data, as a fraction of the data's span.
_LINEAR_MARGIN = 0.05


def _view_of(ax: Axes, x: Array, ys: Sequence[NDArray[Any]], *, log: bool) -> None:
    """Set ``ax``'s view to the data of its collections: ``x`` (T,) and the finite values of ``ys``
    (positive ones on a log axis).  ``autoscale_view`` cannot be used: a collection added to a log
    axis leaves its data limits unset, and matplotlib then draws an empty panel with "Data has no
    positive values" (issue 25, 2.5).  No such value: the view is left as it is."""
    values = np.concatenate([np.asarray(y, dtype=np.float64).ravel() for y in ys])
    values = values[np.isfinite(values) & (values > 0.0 if log else True)]
    if x.size:
        ax.set_xlim(float(x.min()), float(x.max()) if x.max() > x.min() else float(x.min()) + 1.0)
    if not values.size:
        return
    lo, hi = float(values.min()), float(values.max())
    if log:
        ax.set_ylim(lo / _LOG_MARGIN, hi * _LOG_MARGIN)
    else:
        pad = _LINEAR_MARGIN * (hi - lo) if hi > lo else max(abs(hi), 1.0) * _LINEAR_MARGIN
        ax.set_ylim(lo - pad, hi + pad)


#: The columns of a campaign's table that :func:`plot_campaign`'s figures read (what a
#: :class:`FigureWorker` is sent: 1.4 MB pickled for 3000 runs and 200 trajectories of 251 samples).
_CAMPAIGN_COLUMNS = ("run", "rpf_error_at_t2_per_axis", "steady_mean_abs_qev_per_axis", "traj_t", "traj_q_ev", "traj_rho")


def plot_campaign(tab: dict[str, NDArray[Any]], out_dir: Path, *, criteria: tuple[float, float], title: str,
                  nees: dict[str, Any] | None = None, parallel: bool | None = None,
                  worker: FigureWorker | None = None) -> list[Path]:
    """The paper's Monte Carlo figures: t2 tracking error and steady-state error per component
    (one point per run, criterion dashed), and the kept trajectories overlaid with their RPFs; with
    an estimator (``nees``: :func:`sappc.montecarlo.results.nees_consistency`), its consistency:
    the NEES averaged over the runs against its 95 % band (``montecarlo_nees.png``).

    ``worker``: a :class:`FigureWorker` started earlier draws them (this process does not import
    matplotlib); else ``parallel``: draw them in two processes (:func:`draw_jobs`; ``None``: when
    that is safe).  The files are the same either way."""
    return campaign_figures(tab, out_dir, criteria=criteria, title=title, nees=nees, parallel=parallel, worker=worker)()


def campaign_figures(tab: dict[str, NDArray[Any]], out_dir: Path, *, criteria: tuple[float, float], title: str,
                     nees: dict[str, Any] | None = None, parallel: bool | None = None,
                     worker: FigureWorker | None = None) -> Callable[[], list[Path]]:
    """:func:`plot_campaign` in two steps: the figures are sent to ``worker`` now, when it is
    alive (:meth:`FigureWorker.send`), and the function returned waits for them and returns their
    paths; without a worker, that function draws them (:func:`draw_jobs`).  ``tab`` is read now."""
    kwargs = dict(tab={k: tab[k] for k in _CAMPAIGN_COLUMNS}, out_dir=out_dir, criteria=criteria, title=title, nees=nees)
    if worker is not None and worker.alive:
        return worker.send(_campaign_jobs, kwargs, theirs=_CAMPAIGN_JOBS_ORDER)
    return lambda: draw_jobs(_campaign_jobs(**kwargs), parallel=parallel)  # type: ignore[arg-type]


#: The order in which a :class:`FigureWorker`'s two processes take :func:`_campaign_jobs`' jobs
#: (each the next one left when done with its last): the two trajectory figures first, one in
#: each process (0.18 to 0.20 s each for 200 trajectories, machine B), then the two error figures
#: (0.09 to 0.12 s each for 3000 runs; 0.08 s on a prepared figure, machine A), the NEES last.
_CAMPAIGN_JOBS_ORDER = (2, 3, 0, 1, 4)


def _campaign_jobs(tab: dict[str, NDArray[Any]], out_dir: Path, *, criteria: tuple[float, float], title: str,
                   nees: dict[str, Any] | None) -> list[Any]:
    """:func:`plot_campaign`'s figures, one job (a callable returning the paths it wrote) each, in
    order: the two error figures, the two trajectory figures (when trajectories were kept), the
    NEES (with ``nees``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = tab["run"]

    def errors(name: str, key: str, limit: float, label: str) -> list[Path]:
        paths: list[Path] = []
        fig, axes = _columns(3, 3.8)  # (one made in advance by the figure worker: CAMPAIGN_FIGURE_SHAPES)
        for i, ax in enumerate(axes):
            ax.plot(runs, tab[key][:, i], ".", ms=2, color="tab:blue")
            ax.axhline(limit, color="tab:red", ls="--", lw=1, label="criterion")
            _log_axis(ax)
            ax.set_xlabel("run")
            ax.set_title(f"component {i + 1}")
            ax.grid(True, alpha=0.3)
        axes[0].set_ylabel(label)
        axes[0].legend(fontsize=8)
        _finish(fig, out_dir / name, f"{title}: {len(runs)} runs", paths,
                margins=dict(left=0.07, right=0.98, bottom=0.14, top=0.86, wspace=0.08))
        return paths

    t, q, rho = tab["traj_t"], tab["traj_q_ev"], tab["traj_rho"]

    def trajectories(name: str, mask: NDArray[np.bool_], logy: bool) -> list[Path]:
        from matplotlib.collections import LineCollection

        paths: list[Path] = []
        fig, axes = _rows(3, 8.0)  # (one made in advance by the figure worker: CAMPAIGN_FIGURE_SHAPES)
        for i, ax in enumerate(axes):
            y, r = q[mask, :, i], rho[mask, :, i]
            if logy:
                y, r = np.abs(y), np.abs(r)
            # one collection per family: hundreds of Line2D objects take seconds to draw
            tm = np.broadcast_to(t[mask][:, None], y.shape)
            ax.add_collection(LineCollection(np.stack((tm, y), axis=-1).transpose(1, 0, 2), colors="tab:blue", linewidths=0.4, alpha=0.25))
            ax.add_collection(LineCollection(np.stack((tm, r), axis=-1).transpose(1, 0, 2), colors="k", linewidths=0.4, alpha=0.25, linestyles="--"))
            _view_of(ax, t[mask], (y, r), log=logy and _log_axis(ax))
            ax.set_ylabel(f"|q_ev{_SUB[i]}|" if logy else f"q_ev{_SUB[i]}")
            ax.grid(True, alpha=0.3)
        axes[-1].set_xlabel("time [s]")
        _finish(fig, out_dir / name, f"{title}: {q.shape[1]} trajectories (solid) and their RPFs (dashed)" + (", steady state" if logy else ""),
                paths, margins=dict(left=0.11, right=0.97, bottom=0.07, top=0.94, hspace=0.12))
        return paths

    def consistency(nees: dict[str, Any]) -> list[Path]:
        import matplotlib.pyplot as plt

        paths: list[Path] = []
        t_s, mean = np.asarray(nees["t_s"]), np.asarray(nees["mean"])
        lo, hi = nees["band_95"]
        fig, ax = plt.subplots(figsize=(9, 3.6))
        ax.plot(t_s, mean, lw=0.8, color="tab:blue", label=f"NEES averaged over {nees['runs']} runs")
        ax.axhspan(lo, hi, color="tab:green", alpha=0.2, label="95 % chi-square band")
        ax.axhline(6.0, color="tab:green", lw=0.8, ls="--", label="6 (consistent)")
        inside = nees.get("fraction_inside")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("NEES (6 error states)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
        _finish(fig, out_dir / "montecarlo_nees.png",
                f"{title}: estimator consistency" + (f" ({inside:.1%} of samples inside the band)" if inside is not None else ""), paths)
        return paths

    jobs: list[Any] = [
        lambda: errors("montecarlo_t2_error.png", "rpf_error_at_t2_per_axis", criteria[0], "|q_ev,i − ρᵢ| at t₂"),
        lambda: errors("montecarlo_steady_error.png", "steady_mean_abs_qev_per_axis", criteria[1], "mean |q_ev,i| over the steady window"),
    ]
    if q.size:
        jobs += [lambda: trajectories("montecarlo_trajectories.png", np.ones_like(t, dtype=bool), False),
                 lambda: trajectories("montecarlo_trajectories_steady.png", t >= 15.0, True)]
    if nees is not None and nees.get("mean") is not None:
        jobs.append(lambda: consistency(nees))
    return jobs

"""``sappc report`` in its own process: it loads neither numba nor scipy (the metrics kernel's
source runs in the interpreter for one bag; ``tests/tools/evaluation/test_metrics.py`` checks the
bits) nor matplotlib (its forked :class:`~sappc.analysis.plots.FigureWorker` draws every figure, in
two processes, on figures it made in advance), and the figures that worker draws are the
figures that one process draws: the same pixels, every one, also when a library changed
matplotlib's global settings in that process (Basilisk does on import when matplotlib is loaded:
CI on 2026-11-28 saw the report's figures of the suite's process, after the Basilisk tests, laid
out differently; :func:`sappc.analysis.plots.house_style` draws with matplotlib's defaults).  A
difference says which pixels."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from test_wheels_report import _bag

from sappc.analysis import plots
from sappc.analysis.plots import RUN_FIGURE_SHAPES, FigureWorker, _prepare_rows, _run_jobs, draw_jobs, house_style
from sappc.evaluation.history import History
from sappc.analysis.report import analyse_bag, write_report

from conftest import SCENARIOS

ROOT = Path(__file__).resolve().parents[3]

_RUN_REPORT = """
import sys
from sappc.cli import main
code = main(["report", sys.argv[1], "--out", sys.argv[2]])
print(sorted(m for m in ("numba", "scipy", "rclpy", "matplotlib") if m in sys.modules))
sys.exit(code)
"""


def test_the_report_command_loads_no_compiler_and_its_two_processes_draw_the_same_files(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "bag", (SCENARIOS / "paper_tracking.yaml").read_text(), None, None)
    out = subprocess.run([sys.executable, "-c", _RUN_REPORT, str(bag), str(tmp_path / "two")], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout
    import matplotlib

    with matplotlib.rc_context():  # (restored after)
        # a library that changes matplotlib's globals on import, as Basilisk does when matplotlib is
        # loaded (figure.autolayout, tick and label sizes): the report's figures must not change
        import Basilisk.utilities.simHelpers as bsk_helpers

        bsk_helpers._applyMatplotlibDefaults(matplotlib)  # (once a process: the suite may have done it already)
        matplotlib.rc("figure", autolayout=True)
        matplotlib.rc("axes", labelsize=10)
        one = write_report(analyse_bag(bag), tmp_path / "one")  # this process has rclpy loaded: no fork, one process
    for path in one:
        if path.suffix != ".png":
            assert (tmp_path / "two" / path.name).read_bytes() == path.read_bytes(), path.name
            continue
        mine, theirs = _pixels(path), _pixels(tmp_path / "two" / path.name)
        assert mine.shape == theirs.shape, (path.name, mine.shape, theirs.shape)
        rows, cols = np.nonzero((mine != theirs).any(axis=-1))
        assert rows.size == 0, (f"{path.name}: {rows.size} pixels differ, rows {rows.min()}-{rows.max()}, "
                                f"columns {cols.min()}-{cols.max()} of {mine.shape[:2]}")


def _pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGBA"))


def test_a_worker_that_was_not_used_or_could_not_start_leaves_the_figures_to_this_process(tmp_path: Path) -> None:
    with FigureWorker() as unused:  # rclpy is loaded here: forking is not safe, no child
        assert not unused.alive
    a = analyse_bag(_bag(tmp_path / "bag", (SCENARIOS / "paper_tracking.yaml").read_text(), None, None))
    assert a.run is not None
    kwargs = dict(h=a.run.history, out_dir=tmp_path / "figs", title="t", fault_windows=[], zoom_from_s=0.5, run=0, wheels=None)
    paths = draw_jobs(_run_jobs(**kwargs), parallel=False)  # type: ignore[arg-type]
    assert [p.name for p in paths] == ["qev.png", "qev_zoom.png", "qev_log.png", "torque.png", "eps_lyapunov.png"]


def _settling_run(seconds: float = 20.0) -> History:
    """A run's History at 100 Hz whose attitude error decays inside a shrinking band (each
    figure has lines, a band, log axes of several decades)."""
    t = np.arange(0.0, seconds + 1e-9, 0.01)
    decay = np.exp(-t / 3.0)[:, None, None] * np.array([0.3, -0.2, 0.1])
    wobble = 1e-5 * np.sin(t)[:, None, None]
    q_ev = decay + wobble
    q_BR = np.concatenate((q_ev, np.sqrt(1.0 - (q_ev**2).sum(axis=-1, keepdims=True))), axis=-1)
    rho = 0.4 * np.exp(-t / 2.5)[:, None, None] + 3e-5 * np.ones((1, 1, 3))
    torque = 0.1 * np.cos(t)[:, None, None] * np.ones((1, 1, 3))
    zeros = np.zeros_like(rho)
    return History(t=t, q_BN=q_BR.copy(), omega_BN_B=zeros, q_BR=q_BR, torque_B=torque, torque_cmd_B=torque,
                   saturated=np.zeros(rho.shape, bool), disturbance_B=zeros, rho=rho, band_lower=-rho, band_upper=rho,
                   eps=q_ev / rho, z=zeros, V=0.5 * (q_ev / rho) ** 2 + 1e-9)


def test_figures_made_in_advance_are_the_figures_made_when_drawn(tmp_path: Path) -> None:
    """The figure worker makes the run's figures and their first ticks while it waits
    (``_prepare_rows``); a figure drawn on one is the figure made when drawn, every pixel."""
    kwargs = dict(h=_settling_run(), title="t", fault_windows=[(4.0, 6.0)], zoom_from_s=5.0, run=0, wheels=None)
    fresh = draw_jobs(_run_jobs(out_dir=tmp_path / "fresh", **kwargs), parallel=False)  # type: ignore[arg-type]
    assert set(RUN_FIGURE_SHAPES) == {(3, 7.5), (3, 6.5), (2, 6.0)}
    house_style(lambda: [_prepare_rows(*shape) for shape in ((3, 7.5),) * 3 + ((3, 6.5), (2, 6.0))])()
    prepared = draw_jobs(_run_jobs(out_dir=tmp_path / "prepared", **kwargs), parallel=False)  # type: ignore[arg-type]
    assert not any(plots._PREPARED.values())  # each of the five figures was drawn on a prepared one
    assert [p.name for p in prepared] == [p.name for p in fresh] == ["qev.png", "qev_zoom.png", "qev_log.png", "torque.png", "eps_lyapunov.png"]
    for mine, theirs in zip(fresh, prepared):
        a, b = _pixels(mine), _pixels(theirs)
        assert a.shape == b.shape and (a == b).all(), f"{mine.name}: {int((a != b).any(axis=-1).sum())} pixels differ"


def test_the_figures_png_files_are_matplotlibs_pixels_and_chunks(tmp_path: Path) -> None:
    """The figures' PNG files are encoded by ``plots._save_png`` (a faster filter than Pillow's):
    the pixels and the PNG information (``Software``, dpi) of ``savefig``'s own PNG, at every
    figure size the project draws (a size in pixels that is not a whole number of inches)."""
    import zlib

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    t = np.linspace(0.0, 10.0, 1001)
    # matplotlib's defaults: a library imported earlier in this process may have changed its globals (Basilisk
    # sets figure.autolayout, with which each savefig lays the figure out again: two saves, two layouts)
    with matplotlib.rc_context():  # (restored after)
        matplotlib.rcdefaults()
        for size in ((8.0, 7.5), (8.0, 6.5), (12.0, 3.8), (9.0, 3.6), (8.0, 5.5)):
            fig, ax = plt.subplots(figsize=size)
            ax.fill_between(t, -np.exp(-t), np.exp(-t), color="tab:blue", alpha=0.18, lw=0)
            ax.plot(t, np.sin(3 * t) * np.exp(-t), label="ρ₁")
            ax.legend()
            ax.set_title("10⁻⁵")
            plots._save_png(fig, tmp_path / "mine.png")
            fig.savefig(tmp_path / "theirs.png", dpi=plots.PNG_DPI)
            plt.close(fig)
            data = (tmp_path / "mine.png").read_bytes()
            at = data.index(b"IDAT")
            length = int.from_bytes(data[at - 4 : at], "big")
            assert zlib.decompress(data[at + 4 : at + 4 + length])[0] == 2  # written here, filter "Up" (not matplotlib's fallback)
            with Image.open(tmp_path / "mine.png") as mine, Image.open(tmp_path / "theirs.png") as theirs:
                assert (mine.mode, mine.size, mine.info) == (theirs.mode, theirs.size, theirs.info), size
                assert (np.asarray(mine) == np.asarray(theirs)).all(), size

"""A campaign's figures drawn by ``sappc montecarlo``'s :class:`~sappc.analysis.plots.FigureWorker`
(forked at the command's start, before numba is imported; it draws the figures in two processes
while the command writes its table) are the figures one process draws: the same pixels, every one;
the command's own process never imports matplotlib.  A difference says which pixels."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from conftest import ROOT, SCENARIOS
from sappc.analysis.plots import plot_campaign

_RUN_CAMPAIGN = """
import sys
from sappc.cli import main
code = main(["montecarlo", sys.argv[1], "--runs", "6", "--workers", "2", "--out", sys.argv[2], "--no-progress"])
print(sorted(m for m in ("matplotlib",) if m in sys.modules))
sys.exit(code)
"""

#: A campaign's table and NEES for :func:`plot_campaign` (every figure, the NEES's too), drawn by a
#: figure worker in a process without numba, then by that process alone.
_DRAW_BOTH = """
import pickle, sys
from pathlib import Path
from sappc.analysis.plots import FigureWorker, plot_campaign
with FigureWorker() as worker:
    assert worker.alive
    tab, nees = pickle.loads(Path(sys.argv[1]).read_bytes())
    kw = dict(criteria=(1e-4, 5e-5), title="t", nees=nees)
    two = plot_campaign(tab, Path(sys.argv[2]), worker=worker, **kw)
    assert not worker.alive
one = plot_campaign(tab, Path(sys.argv[3]), parallel=False, **kw)
print([p.name for p in two] == [p.name for p in one], [p.name for p in one])
"""


def _pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGBA"))


def _same_pixels(mine: Path, theirs: Path) -> None:
    a, b = _pixels(mine), _pixels(theirs)
    assert a.shape == b.shape, (mine.name, a.shape, b.shape)
    rows, cols = np.nonzero((a != b).any(axis=-1))
    assert rows.size == 0, (f"{mine.name}: {rows.size} pixels differ, rows {rows.min()}-{rows.max()}, "
                            f"columns {cols.min()}-{cols.max()} of {a.shape[:2]}")


def test_the_campaign_command_draws_its_figures_in_its_figure_worker(tmp_path: Path) -> None:
    from sappc.montecarlo.config import campaign_config
    from sappc.montecarlo.results import _load_chunks
    from sappc.scenario import scenario_from_mapping

    raw = copy.deepcopy(yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text()))
    raw["duration_s"] = 21.0
    raw["metrics"]["steady_from_s"] = 20.5
    raw["montecarlo"]["chunk_runs"] = 3
    raw["montecarlo"]["trajectory_runs"] = 4
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = subprocess.run([sys.executable, "-c", _RUN_CAMPAIGN, str(path), str(tmp_path / "two")],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout  # no matplotlib in the command's process
    scenario = scenario_from_mapping(raw)
    crit = campaign_config(scenario).criteria
    tab = _load_chunks(tmp_path / "two", 2)
    assert "tsum_nees" not in tab
    one = plot_campaign(tab, tmp_path / "one", criteria=(crit.rpf_error_at_t2_max, crit.steady_mean_abs_qev_max),
                        title=scenario.name, parallel=False)
    assert [p.name for p in one] == ["montecarlo_t2_error.png", "montecarlo_steady_error.png", "montecarlo_trajectories.png",
                                     "montecarlo_trajectories_steady.png"]
    assert sorted(p.name for p in (tmp_path / "two").glob("*.png")) == sorted(p.name for p in one)
    for p in one:
        _same_pixels(p, tmp_path / "two" / p.name)


def _campaign_table(rng: np.random.Generator, runs: int, kept: int, samples: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A campaign's table for :func:`plot_campaign` (``runs`` runs, ``kept`` trajectories of
    ``samples`` samples over 50 s, decaying errors under their RPFs) and its trajectories' times."""
    t = np.linspace(0.0, 50.0, samples)
    q = (0.3 * np.exp(-t / 4.0)[:, None, None] * rng.uniform(-1.0, 1.0, (1, kept, 3)) + 1e-5).astype(np.float32)
    return t, {"run": np.arange(runs), "rpf_error_at_t2_per_axis": rng.uniform(1e-6, 2e-5, (runs, 3)),
               "steady_mean_abs_qev_per_axis": rng.uniform(1e-6, 4e-5, (runs, 3)), "traj_t": t, "traj_q_ev": q,
               "traj_rho": (1.2 * np.abs(q) + 3e-5).astype(np.float32)}


def test_a_figure_worker_draws_the_campaign_figures_one_process_draws(tmp_path: Path) -> None:
    """Every figure of :func:`plot_campaign` (the NEES's too) through a figure worker: the jobs'
    order and pixels of one process's drawing."""
    import pickle

    rng = np.random.default_rng(0)
    runs, samples = 40, 101
    t, tab = _campaign_table(rng, runs, 5, samples)
    nees = {"t_s": t, "mean": 6.0 + rng.normal(0.0, 0.5, samples), "band_95": [5.1, 7.0], "runs": runs, "fraction_inside": 0.9}
    (tmp_path / "in.pkl").write_bytes(pickle.dumps((tab, nees)))
    out = subprocess.run([sys.executable, "-c", _DRAW_BOTH, str(tmp_path / "in.pkl"), str(tmp_path / "two"),
                          str(tmp_path / "one")], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    names = ["montecarlo_t2_error.png", "montecarlo_steady_error.png", "montecarlo_trajectories.png", "montecarlo_trajectories_steady.png",
             "montecarlo_nees.png"]
    assert out.stdout.strip() == f"True {names}", out.stdout + out.stderr
    for p in sorted((tmp_path / "one").glob("*.png")):
        _same_pixels(p, tmp_path / "two" / p.name)


def test_campaign_figures_made_in_advance_are_the_figures_made_when_drawn(tmp_path: Path) -> None:
    """``sappc montecarlo``'s figure worker makes the trajectory figure and the error figure, with
    their first ticks, while the runs go (:data:`~sappc.analysis.plots.CAMPAIGN_FIGURE_SHAPES`);
    both trajectory figures and both error figures drawn on prepared ones are the figures made
    when drawn, every pixel (the log axes' too)."""
    from sappc.analysis import plots
    from sappc.analysis.plots import CAMPAIGN_FIGURE_SHAPES, _campaign_jobs, _prepare_rows, draw_jobs, house_style

    _, tab = _campaign_table(np.random.default_rng(1), 30, 6, 201)
    kw = dict(tab=tab, criteria=(1e-4, 5e-5), title="t", nees=None)
    fresh = draw_jobs(_campaign_jobs(out_dir=tmp_path / "fresh", **kw)[:4], parallel=False)  # type: ignore[arg-type]
    assert CAMPAIGN_FIGURE_SHAPES == ((3, 8.0), (1, 3.8, 3))
    house_style(lambda: [_prepare_rows(*shape) for shape in CAMPAIGN_FIGURE_SHAPES * 2])()
    prepared = draw_jobs(_campaign_jobs(out_dir=tmp_path / "prepared", **kw)[:4], parallel=False)  # type: ignore[arg-type]
    assert not any(plots._PREPARED.values())  # all four drawn on prepared figures
    assert [p.name for p in prepared] == [p.name for p in fresh] == ["montecarlo_t2_error.png", "montecarlo_steady_error.png",
                                                                     "montecarlo_trajectories.png", "montecarlo_trajectories_steady.png"]
    for mine, theirs in zip(fresh, prepared):
        _same_pixels(mine, theirs)

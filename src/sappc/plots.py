"""Paper-style figures of a run: each q_ev component with its performance function and
constraint band (whole run and steady-state zoom), and the actuator torques."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .closed_loop import History

__all__ = ["plot_run"]


def _mark_faults(ax, fault_windows: list[tuple[float, float]], t_end: float) -> None:  # type: ignore[no-untyped-def]
    for start, end in fault_windows:
        ax.axvspan(start, min(end, t_end), color="tab:red", alpha=0.15, lw=0)


def plot_run(
    h: History,
    out_dir: Path,
    *,
    title: str,
    fault_windows: list[tuple[float, float]] = (),  # type: ignore[assignment]
    zoom_from_s: float = 15.0,
    run: int = 0,
) -> list[Path]:
    """Write ``qev.png``, ``qev_zoom.png`` and ``torque.png`` to ``out_dir``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    t = h.t
    q_ev = h.q_ev[:, run]
    paths = []
    for name, mask, zoom in (("qev.png", np.ones_like(t, dtype=bool), False), ("qev_zoom.png", t >= zoom_from_s, True)):
        fig, axes = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
        for i, ax in enumerate(axes):
            ax.fill_between(t[mask], h.band_lower[mask, run, i], h.band_upper[mask, run, i], color="tab:blue", alpha=0.18,
                            lw=0, label="constraint band")
            ax.plot(t[mask], h.rho[mask, run, i], "k--", lw=1.0, label=r"$\rho_%d$" % (i + 1))
            ax.plot(t[mask], q_ev[mask, i], color="tab:blue", lw=1.3, label=r"$q_{ev%d}$" % (i + 1))
            _mark_faults(ax, list(fault_windows), float(t[-1]))
            ax.set_ylabel(r"$q_{ev%d}$" % (i + 1))
            ax.grid(True, alpha=0.3)
            if zoom:
                lo = min(q_ev[mask, i].min(), h.rho[mask, run, i].min())
                hi = max(q_ev[mask, i].max(), h.rho[mask, run, i].max())
                pad = 0.25 * max(hi - lo, 1e-6)
                ax.set_ylim(lo - pad, hi + pad)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        fig.suptitle(f"{title}: attitude error" + (" (zoom)" if zoom else ""))
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)

    fig, axes = plt.subplots(3, 1, figsize=(8, 6.5), sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(t, h.torque_B[:, run, i], lw=1.0, color="tab:green", label=r"$u_%d$" % (i + 1))
        _mark_faults(ax, list(fault_windows), float(t[-1]))
        ax.set_ylabel(r"$u_%d$ [N m]" % (i + 1))
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{title}: actuator torque")
    fig.tight_layout()
    path = out_dir / "torque.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    paths.append(path)
    return paths

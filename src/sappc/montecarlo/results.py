"""A campaign's results: chunk files, the pass criteria per run, the table, the summary, the figures."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc.evaluation.estimation import nees_band
from sappc.evaluation.metrics import NEES_FROM_S, SampleGrid, nees_sample_stride
from sappc.evaluation.requirements import MIN_COMMANDED_FRACTION, lost_control
from sappc.montecarlo.config import CampaignConfig, Criteria
from sappc_msgs_py.contract import ANSWER_NAMES
from sappc.scenario import Scenario

__all__ = ["FORMAT_VERSION", "RunCriteria", "assemble", "chunk_path", "chunks", "run_criteria", "save_chunk"]

Array = NDArray[np.float64]

#: Version of the chunk/manifest format (bumped when their contents change; 3: the switching rates;
#: 4: the loss-of-control time).
FORMAT_VERSION = 4
#: Per-axis columns of the run table.
_AXES = (1, 2, 3)


def chunks(n_runs: int, chunk_runs: int) -> list[tuple[int, list[int]]]:
    return [(i, list(range(s, min(s + chunk_runs, n_runs)))) for i, s in enumerate(range(0, n_runs, chunk_runs))]


def chunk_path(out: Path, index: int) -> Path:
    return out / "chunks" / f"chunk_{index:06d}.npz"


def save_chunk(out: Path, index: int, result: dict[str, NDArray[Any]]) -> None:
    path = chunk_path(out, index)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **result)  # type: ignore[arg-type]  # numpy's stub types **kwds as the allow_pickle flag
    tmp.replace(path)  # atomic: a chunk file is either complete or absent


def _load_chunks(out: Path, n_chunks: int) -> dict[str, Any]:
    """The campaign's table from its chunks, read one at a time: the per-run columns joined, the
    per-sample sums over runs (``tsum_*``, a 6 h run's 2.16 million samples each) added chunk after
    chunk in chunk order (the bits of numpy's sum over a stack of them along its first axis, which
    adds row after row), so the whole campaign's chunks are never held at once (issue 47: 100 runs
    of 6 h held 1.5 GB here)."""
    columns: dict[str, list[Any]] = {}
    sums: dict[str, Array] = {}
    traj: list[dict[str, Any]] = []
    for i in range(n_chunks):
        with np.load(chunk_path(out, i), allow_pickle=False) as part:
            for k in part.files:
                if k.startswith("tsum_"):  # per-sample sums over runs: summed over chunks
                    if k in sums:
                        sums[k] += part[k]
                    else:
                        sums[k] = np.array(part[k])
                elif not k.startswith("traj_"):
                    columns.setdefault(k, []).append(part[k])
            if part["traj_q_ev"].size:
                traj.append({k: part[k] for k in ("traj_t", "traj_q_ev", "traj_rho")})
    table: dict[str, Any] = {k: np.concatenate(v) for k, v in columns.items()}
    table.update(sums)
    table["traj_t"] = traj[0]["traj_t"] if traj else np.zeros(0)
    table["traj_q_ev"] = np.concatenate([p["traj_q_ev"] for p in traj], axis=1) if traj else np.zeros((0, 0, 3))
    table["traj_rho"] = np.concatenate([p["traj_rho"] for p in traj], axis=1) if traj else np.zeros((0, 0, 3))
    return table


def _percentiles(x: Array) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"p50": None, "p90": None, "p99": None, "max": None}
    p = np.percentile(x, [50, 90, 99])
    return {"p50": float(p[0]), "p90": float(p[1]), "p99": float(p[2]), "max": float(x.max())}


def _p95(x: Array) -> float | None:
    """The 95th percentile of the finite values (``None``: none)."""
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 95)) if x.size else None


@dataclasses.dataclass(frozen=True)
class RunCriteria:
    """The paper's pass criteria (experiment 4) evaluated per run, arrays over runs.

    Attributes
    ----------
    rpf_error_at_t2 : max over axes of ``|q_ev,i - rho_i|`` at ``t2``.
    steady_mean_abs_qev : max over axes of the mean ``|q_ev,i|`` over the steady window.
    finite : the run's state stayed finite.
    ok_t2, ok_steady : each criterion met (and the run finite).
    lost : the run lost control (:func:`sappc.evaluation.requirements.lost_control`: the rule every
        path applies, whatever the criteria).
    passed : both criteria met and control kept.
    """

    rpf_error_at_t2: Array
    steady_mean_abs_qev: Array
    finite: NDArray[np.bool_]
    ok_t2: NDArray[np.bool_]
    ok_steady: NDArray[np.bool_]
    lost: NDArray[np.bool_]
    passed: NDArray[np.bool_]


#: The per-run columns of a campaign with reaction wheels (metrics of :mod:`sappc.evaluation.metrics`).
WHEEL_COLUMNS = ("max_abs_wheel_speed_rad_s", "max_abs_wheel_torque_Nm", "wheel_energy_J")
#: Per-run columns of a campaign with flight modes (issue 49): the first entry into TRACK [s] (NaN:
#: never) and the transitions taken.
MODE_COLUMNS = ("time_to_track_s", "mode_transitions")
#: Per-run columns of a campaign with an estimator (:mod:`sappc.evaluation.metrics`).
ESTIMATOR_COLUMNS = ("steady_max_abs_attitude_estimation_error_rad", "final_abs_bias_estimation_error_rad_s", "mean_nees",
                     "filter_inconsistent_fraction", "estimator_recoveries")


def _samples(table: dict[str, Any]) -> NDArray[np.int64]:
    """Each run's samples the controller was active for: its answers of every kind but ``inactive``
    (flight modes: the samples another mode's law flew), summed."""
    out: NDArray[np.int64] = np.sum([np.asarray(table[f"answers_{name}"], dtype=np.int64) for name in ANSWER_NAMES
                                     if name != "inactive"], axis=0)
    return out


def run_criteria(table: dict[str, Any], criteria: Criteria) -> RunCriteria:
    """The pass criteria of the runs in ``table`` (a chunk's or the campaign's per-run arrays):
    the one place that defines what passing means, for the campaign table and for
    ``sappc simulate --from-campaign``."""
    t2 = np.asarray(table["rpf_error_at_t2_per_axis"]).max(axis=1)
    steady = np.asarray(table["steady_mean_abs_qev_per_axis"]).max(axis=1)
    # a refused control step (a non-finite torque, answered with zero) fails the run as a non-finite state does
    finite = np.asarray(table["finite"]).astype(bool) & (np.asarray(table.get("answers_refused", 0)) == 0)
    ok_t2 = finite & (t2 < criteria.rpf_error_at_t2_max)
    ok_steady = finite & (steady < criteria.steady_mean_abs_qev_max)
    lost = lost_control(table["control_lost_at_s"], table["answers_commanded"], _samples(table))
    return RunCriteria(t2, steady, finite, ok_t2, ok_steady, lost, ok_t2 & ok_steady & ~lost)


def nees_consistency(tab: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """The filter's consistency over a campaign: the NEES averaged over the runs at every sample
    from :data:`~sappc.evaluation.metrics.NEES_FROM_S`, against the two-sided 95 % chi-square band
    of that average (:func:`~sappc.evaluation.estimation.nees_band`, 6 degrees of freedom per run).
    For a consistent filter each sample's average falls outside its band with probability 5 %, so
    the fraction of samples inside it is about 0.95 (neighbouring samples are correlated: it
    fluctuates from campaign to campaign); ``t_s``, ``mean`` and the band are the figure's.  A run
    longer than :data:`~sappc.evaluation.metrics.NEES_EXACT_MAX_SAMPLES` samples has its NEES at
    every :func:`~sappc.evaluation.metrics.nees_sample_stride`-th sample only (``tsum_nees``'s
    length): the test and the figure take those samples."""
    grid = SampleGrid.of_run(scenario.duration_s, scenario.control_period_s)  # sample_times' grid, not stored
    t = grid.times_s(np.arange(0, grid.n_samples, nees_sample_stride(grid.n_samples)))
    counted = tab["tsum_nees_runs"]
    n_runs = int(counted.max()) if counted.size else 0
    full = counted == n_runs  # samples where every run has an estimate (from NEES_FROM_S)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counted > 0, tab["tsum_nees"] / np.maximum(counted, 1), np.nan)
    lo, hi = nees_band(max(n_runs, 1))
    inside = (mean >= lo) & (mean <= hi)
    outside_t = t[full & ~inside]
    return {"from_s": NEES_FROM_S, "runs": n_runs, "band_95": [lo, hi], "samples": int(full.sum()),
            "fraction_inside": float(inside[full].mean()) if full.any() else None,
            "mean_over_time": float(np.mean(mean[full])) if full.any() else None,
            "min": float(np.min(mean[full])) if full.any() else None, "max": float(np.max(mean[full])) if full.any() else None,
            "first_times_outside_s": [float(x) for x in outside_t[:20]],
            "t_s": t, "mean": mean}


def _estimator_summary(tab: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """The estimator's part of ``summary.json``: its per-run metrics' percentiles and the NEES
    consistency test (:func:`nees_consistency`)."""
    nees = {k: v for k, v in nees_consistency(tab, scenario).items() if k not in ("t_s", "mean")}
    return {**{k: _percentiles(np.asarray(tab[k], dtype=np.float64)) for k in ESTIMATOR_COLUMNS}, "nees_consistency": nees}


def assemble(out: Path, scenario: Scenario, cfg: CampaignConfig, manifest: dict[str, Any], *, wall_s: float,
             figure_worker: Any = None) -> dict[str, Any]:
    """Write the campaign's table (``runs.csv``), summary (``summary.json``, also returned) and
    figures (:func:`sappc.analysis.plots.campaign_figures`; ``figure_worker``: the
    :class:`~sappc.analysis.plots.FigureWorker` that draws them, when one was started)."""
    from sappc.analysis.plots import campaign_figures

    runs, seed = manifest["runs"], manifest["seed"]
    tab = _load_chunks(out, len(chunks(runs, manifest["chunk_runs"])))
    crit = cfg.criteria
    # sent to the figure worker now, to be drawn while the table is written; waited for (or drawn
    # here, without a worker) at the end
    figures = campaign_figures(tab, out, criteria=(crit.rpf_error_at_t2_max, crit.steady_mean_abs_qev_max), title=scenario.name,
                               nees=nees_consistency(tab, scenario) if "tsum_nees" in tab else None, worker=figure_worker)
    rc = run_criteria(tab, crit)
    t2, steady, finite, ok_t2, ok_steady, passed = rc.rpf_error_at_t2, rc.steady_mean_abs_qev, rc.finite, rc.ok_t2, rc.ok_steady, rc.passed
    lost_at = np.asarray(tab["control_lost_at_s"], dtype=np.float64)
    samples = _samples(tab)

    gain_keys = [k for k in tab if k.startswith("gain_")]
    wheel_keys = [k for k in WHEEL_COLUMNS if k in tab] + [k for k in ESTIMATOR_COLUMNS if k in tab] + [k for k in MODE_COLUMNS if k in tab]
    hw_cols = [(k, i) for k in tab if k.startswith("hw_") for i in range(np.asarray(tab[k]).reshape(runs, -1).shape[1])]
    dispersed = cfg.dispersions.faults is not None
    fault_kinds = [str(c["kind"]) for c in cfg.dispersions.faults.choices] if cfg.dispersions.faults is not None else []
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            ["run", "seed", "passed", "finite"]
            + [f"euler_deg_{i}" for i in _AXES] + [f"omega0_rad_s_{i}" for i in _AXES] + [f"inertia_relative_{i}" for i in _AXES]
            + ["disturbance_scale", "disturbance_phase_rad"] + gain_keys
            + [f"rpf_error_at_t2_{i}" for i in _AXES] + ["rpf_error_at_t2"]
            + [f"steady_mean_abs_qev_{i}" for i in _AXES] + ["steady_mean_abs_qev", "steady_max_abs_qev", "settling_time_s",
                                                           "max_abs_torque_Nm", "torque_sign_changes_per_s", "torque_reversals_per_s",
                                                           "rpf_clamped_components", "rpf_flat_components", "control_lost_at_s"]
            + [f"answers_{name}" for name in ANSWER_NAMES] + wheel_keys + [f"{k[3:]}_{i + 1}" for k, i in hw_cols] + (["fault_kind", "fault_start_s", "fault_end_s"] if dispersed else [])
        )
        for k in range(runs):
            w.writerow(
                [int(tab["run"][k]), seed, bool(passed[k]), bool(finite[k])]
                + [f"{v:.17g}" for v in tab["euler_deg"][k]] + [f"{v:.17g}" for v in tab["omega_BN_B0_rad_s"][k]]
                + [f"{v:.17g}" for v in tab["inertia_relative"][k]]
                + [f"{tab['disturbance_scale'][k]:.17g}", f"{tab['disturbance_phase_rad'][k]:.17g}"]
                + [f"{tab[g][k]:.17g}" for g in gain_keys]
                + [f"{v:.17g}" for v in tab["rpf_error_at_t2_per_axis"][k]] + [f"{t2[k]:.17g}"]
                + [f"{v:.17g}" for v in tab["steady_mean_abs_qev_per_axis"][k]]
                + [f"{steady[k]:.17g}", f"{tab['steady_max_abs_qev'][k]:.17g}", f"{tab['settling_time_s'][k]:.17g}",
                   f"{tab['max_abs_torque_Nm'][k]:.17g}", f"{tab['torque_sign_changes_per_s'][k]:.17g}",
                   f"{tab['torque_reversals_per_s'][k]:.17g}", int(tab["rpf_clamped"][k].sum()), int(tab["rpf_flat"][k].sum()),
                   f"{lost_at[k]:.17g}"]
                + [int(tab[f"answers_{name}"][k]) for name in ANSWER_NAMES] + [f"{tab[w][k]:.17g}" for w in wheel_keys]
                + [f"{np.asarray(tab[h]).reshape(runs, -1)[k, i]:.17g}" for h, i in hw_cols]
                + ([fault_kinds[int(tab["fault_choice"][k])], f"{tab['fault_start_s'][k]:.17g}",
                    f"{tab['fault_start_s'][k] + tab['fault_duration_s'][k]:.17g}"] if dispersed else [])
            )

    def run_ref(k: int) -> dict[str, Any]:
        return {"run": int(k), "seed_sequence": {"entropy": seed, "spawn_key": [int(k)]},
                "rpf_error_at_t2": float(t2[k]), "steady_mean_abs_qev": float(steady[k]), "finite": bool(finite[k])}

    failing = np.flatnonzero(~passed)
    reasons = []
    for k in failing[:100]:
        refused = int(tab["answers_refused"][k])
        why = ([] if tab["finite"][k] else ["non-finite state"]) + ([f"{refused} refused control steps"] if refused else [])
        if np.isfinite(lost_at[k]):
            why.append(f"control lost from {lost_at[k]:g} s to the end")
        commanded = int(tab["answers_commanded"][k])
        if lost_control(np.nan, commanded, samples[k]):
            of = "of the {} samples it was active for" if int(tab.get("answers_inactive", np.zeros(k + 1, dtype=np.int64))[k]) else "of {} samples"
            why.append(f"control lost: torque computed at {commanded} {of.format(int(samples[k]))} (< {MIN_COMMANDED_FRACTION:.0%})")
        if "time_to_track_s" in tab and not np.isfinite(tab["time_to_track_s"][k]):
            why.append("never reached TRACK")
        if finite[k] and not ok_t2[k]:
            why.append(f"rpf_error_at_t2 {t2[k]:.3g} >= {crit.rpf_error_at_t2_max:g}")
        if finite[k] and not ok_steady[k]:
            why.append(f"steady_mean_abs_qev {steady[k]:.3g} >= {crit.steady_mean_abs_qev_max:g}")
        reasons.append({**run_ref(int(k)), "why": "; ".join(why)})
    def worst(values: Array) -> dict[str, Any] | None:
        """The finite run with the largest value, or None when no run has one (a campaign shorter than t2)."""
        ranked = np.where(finite & np.isfinite(values), values, -np.inf)
        return run_ref(int(np.argmax(ranked))) if np.isfinite(ranked).any() else None

    summary: dict[str, Any] = {
        "scenario": scenario.name,
        "runs": runs,
        "seed": seed,
        "criteria": dataclasses.asdict(crit),
        "passed": int(passed.sum()),
        "pass_fraction": float(passed.mean()),
        "failed_runs": reasons,
        "failed_runs_listed": len(reasons),
        "non_finite_runs": int((~finite).sum()),
        "runs_lost_control": int(rc.lost.sum()),
        "controller_answers": {name: {"runs": int((tab[f"answers_{name}"] > 0).sum()), "samples": int(tab[f"answers_{name}"].sum())}
                               for name in ANSWER_NAMES},
        "runs_never_commanded": int((tab["answers_commanded"] == 0).sum()),
        "rpf_clamped_components": int(tab["rpf_clamped"].sum()),
        "rpf_flat_components": int(tab["rpf_flat"].sum()),
        "worst_rpf_error_at_t2": worst(t2),
        "worst_steady_mean_abs_qev": worst(steady),
        "rpf_error_at_t2": _percentiles(t2),
        "steady_mean_abs_qev": _percentiles(steady),
        "settling_time_s": _percentiles(tab["settling_time_s"]),
        "max_abs_torque_Nm": _percentiles(tab["max_abs_torque_Nm"]),
        "torque_sign_changes_per_s": _percentiles(tab["torque_sign_changes_per_s"]),
        "torque_reversals_per_s": _percentiles(tab["torque_reversals_per_s"]),
        **({"estimator": _estimator_summary(tab, scenario)} if "tsum_nees" in tab else {}),
        **({"modes": {"runs_never_tracked": int((~np.isfinite(np.asarray(tab["time_to_track_s"], dtype=np.float64))).sum()),
                      "time_to_track_s": {**_percentiles(np.asarray(tab["time_to_track_s"], dtype=np.float64)),
                                          "p95": _p95(np.asarray(tab["time_to_track_s"], dtype=np.float64))},
                      "mode_transitions": _percentiles(np.asarray(tab["mode_transitions"], dtype=np.float64))}}
           if "time_to_track_s" in tab else {}),
        "wall_time_s": wall_s,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    figures()
    return summary

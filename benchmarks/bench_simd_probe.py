"""Issue 50, groundwork: where a paper Monte Carlo run-step's time goes, and what SIMD lanes could use.

    nice -n 10 python benchmarks/bench_simd_probe.py [--runs 200] [--replay-runs 32] [--repeats 5] > benchmarks/results_speed/simd_probe.json

Measures, on this machine, one thread, median of ``--repeats`` (JSON on stdout, progress on stderr):

1. **The loop and its pieces.**  The campaign kernel per run-step (``run_batch`` of
   ``paper_montecarlo.yaml`` with ``--runs`` runs drawn as ``bench_loop_step.py`` draws them, no
   histories: that benchmark's figure) and its ``perf`` profile by library and symbol (libm's share).
   Then, on the first ``--replay-runs`` runs, timed in turn: the loop without histories and with
   every sample recorded (``stride = 1``, what a campaign's sub-batches run), and each piece the
   loop calls for this scenario, alone, in a tight compiled loop over the inputs the loop itself
   recorded: SAPPC's ``controller_step``, the plant's ``propagate`` (RK4), the input check
   ``sample_verdicts``, the reference and disturbance table reads, the record writes.  The replays
   are checked against the loop's record bit for bit (the replayed torques and states are the
   recorded ones), so each piece sees exactly the loop's inputs.
2. **The SMETF's Newton iterations**, per sample and axis, over those runs: each sample's solve is
   repeated by the kernel's own ``smetf_solve`` from the warm start the step used (rebuilt from the
   controller's state before and after the step; checked: the same ``eps``, bit for bit); the libm
   calls and divisions per run-step (read from the code, the phase-dependent ones counted on the
   runs); each scalar libm call's cost on the runs' arguments.
3. **Vectorised libm with this llvmlite** (child processes with their own numba cache, compiling
   only tiny synthetic kernels: nothing of the project is compiled with changed options): SVML's
   state; LLVM's ``-vector-library`` option (does the loop vectorizer map libm calls to glibc's
   libmvec?); the call-site route (``"vector-function-abi-variant"`` on the scalar declaration,
   the libmvec variants declared), with and without ``memory(none)``, at LLVM's width, at a forced
   width of 8 and with the CPU's 256-bit preference removed (``NUMBA_CPU_FEATURES``): the variants
   called, the throughput per element and the difference in ulps from the scalar calls on the
   arguments the runs produce.
4. **A lane loop over the existing kernels** (child process, LLVM's vectorizer debug output and
   remarks): ``for lane in range(W): kernel(lane's rows)`` for ``propagate``, ``sample_verdicts``
   and ``controller_step``, and over the kernels' scalar-in, scalar-out helpers in structure of
   arrays; whether LLVM vectorises each, why not, and the cost per lane-step.  ``projection`` turns
   the figures into bounds on an SoA kernel's time per run-step (an estimate, not a measurement).

Nothing here changes the project's kernels or their cache.  The Newton count is instrumentation:
it repeats the controller's warm-start prediction (one expression, written in the kernel's order)
to call the kernel's own solver again; the check against the step's ``eps`` proves it the same.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "config" / "scenarios" / "paper_montecarlo.yaml"
#: glibc's vector math library (the x86-64 variants: b SSE4, c AVX, d AVX2, e AVX-512).
LIBMVEC = "libmvec.so.1"
#: The libm functions of a SAPPC run-step (module docstring) and their libmvec variants' arity.
LIBM = {"exp": 1, "pow": 2, "atan": 1, "tanh": 1, "expm1": 1}


def log(msg: str) -> None:
    print(f"[simd_probe {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def med(xs: list[float]) -> dict[str, Any]:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs)}


# ============================================================================= machine


def machine() -> dict[str, Any]:
    info: dict[str, Any] = {"platform": platform.platform(), "python": platform.python_version()}
    flags: set[str] = set()
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name") and "cpu" not in info:
            info["cpu"] = line.split(":", 1)[1].strip()
        if line.startswith("flags") and not flags:
            flags = set(line.split(":", 1)[1].split())
    info["cpus"] = len(os.sched_getaffinity(0))
    info["flags"] = {f: f in flags for f in ("avx", "avx2", "fma", "avx512f", "avx512dq", "avx512vl")}
    import llvmlite
    import llvmlite.binding as llvm
    import numba

    info["llvm_host_cpu"] = llvm.get_host_cpu_name()
    info["numba"], info["llvmlite"], info["llvm"] = numba.__version__, llvmlite.__version__, ".".join(map(str, llvm.llvm_version_info))
    try:
        out = subprocess.run(["ldd", "--version"], capture_output=True, text=True).stdout.splitlines()[0]
        info["glibc"] = out.split()[-1]
    except (OSError, IndexError):
        pass
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no", "src"], capture_output=True,
                               text=True).stdout.strip()
        info["commit"] = head + ("+src changes" if dirty else "")
    except OSError:
        pass
    return info


def svml_state() -> dict[str, Any]:
    """SVML as llvmlite and numba see it (numba -s's lines)."""
    import llvmlite.binding as llvm
    from numba.core import config
    from numba.misc import numba_sysinfo

    s = numba_sysinfo.get_sysinfo()
    return {"llvmlite.binding.has_svml": bool(llvm.has_svml() if callable(llvm.has_svml) else llvm.has_svml),
            "numba.config.USING_SVML": bool(config.USING_SVML),
            "numba_s": {k: s.get(k) for k in ("SVML State", "SVML Lib Loaded", "LLVM SVML Patched", "SVML Operational")},
            "libmvec": _libmvec_symbols()}


def _libmvec_symbols() -> dict[str, list[str]]:
    """The libmvec variants of :data:`LIBM` this glibc exports."""
    import ctypes.util

    path = None
    for cand in ("/lib/x86_64-linux-gnu/libmvec.so.1", "/usr/lib64/libmvec.so.1", "/lib64/libmvec.so.1"):
        if Path(cand).exists():
            path = cand
            break
    path = path or ctypes.util.find_library("mvec")
    if path is None:
        return {}
    out = subprocess.run(["nm", "-D", path], capture_output=True, text=True).stdout
    found: dict[str, list[str]] = {}
    for fn in LIBM:
        found[fn] = sorted(set(re.findall(rf"(_ZGV[bcde]N\d+v+_{fn})\b", out)))
    return found


# ============================================================================= 1. the loop and its pieces


def _inputs(n_runs: int) -> Any:
    """``paper_montecarlo.yaml``'s inputs for ``n_runs`` runs, drawn as ``bench_loop_step.py`` draws them."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    import sappc.offline.compiled_loop as cl
    from sappc.scenario import load_scenario

    sc = load_scenario(str(SCENARIO))
    rng = np.random.default_rng(0)
    q = Rotation.from_euler("ZYX", rng.uniform(-85.0, 85.0, (n_runs, 3)), degrees=True).as_quat()
    return cl.prepare(sc, q_BN0=q, on_infeasible="clamp")


def whole_loop(runs: int, replay_runs: int, repeats: int) -> tuple[dict[str, Any], Any, Any]:
    """The campaign kernel per run-step, one thread, no histories (``bench_loop_step.py``'s figure),
    and its perf profile.  Returns the figures, the replay runs' inputs and their record (stride 1)."""
    import numba

    import sappc.offline.compiled_loop as cl

    numba.set_num_threads(1)
    inp = _inputs(runs)
    T = inp.t.size
    cl.run_batch(inp, 0)
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cl.run_batch(inp, 0)
        walls.append(time.perf_counter() - t0)
    stride0 = [w / (runs * T) * 1e6 for w in walls]
    log("perf profile of the loop")
    prof = perf_profile(inp)
    sub = inp.subset(0, replay_runs)
    buf = cl.run_batch(sub, 1)
    return ({"runs": runs, "samples_per_run": T, "us_per_run_step_stride0": med(stride0), "perf_profile_stride0": prof}, sub, buf)


def perf_profile(inp: Any, seconds: float = 4.0) -> dict[str, Any]:
    """Where the loop's time goes by library and symbol: ``perf record`` (software clock, 2 kHz:
    this virtual machine has no hardware counters) attached to this process while it runs the
    campaign kernel (``run_batch`` of ``inp``, no histories, one thread) for ``seconds``.  The
    compiled code is ``[JIT]``; libm's functions are named.  A sample lands where the core waits, so
    a libm function that starts on a long chain's result carries some of that chain's latency."""
    import shutil

    import sappc.offline.compiled_loop as cl

    if shutil.which("perf") is None:
        return {"available": False}
    with tempfile.TemporaryDirectory(prefix="simd_probe_perf_") as tmp:
        data = str(Path(tmp) / "perf.data")
        p = subprocess.Popen(["perf", "record", "-e", "cpu-clock", "-F", "2000", "-p", str(os.getpid()), "-o", data, "--", "sleep",
                              str(seconds)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(0.3)
        calls = 0
        while p.poll() is None:
            cl.run_batch(inp, 0)
            calls += 1
        rep = subprocess.run(["perf", "report", "-i", data, "--sort", "dso,sym", "--stdio"], capture_output=True, text=True)
    by_dso: dict[str, float] = {}
    libm: dict[str, float] = {}
    other: dict[str, float] = {}
    for line in rep.stdout.splitlines():
        m = re.match(r"^\s*([\d.]+)%\s+(.*?)\s+\[[.k]\]\s+(.*)$", line)
        if not m:
            continue
        pct, dso, sym = float(m.group(1)), m.group(2).strip(), m.group(3).strip()
        dso = "[JIT]" if dso.startswith("[JIT]") else dso
        by_dso[dso] = by_dso.get(dso, 0.0) + pct
        if dso.startswith("libm"):
            name = re.sub(r"^(__ieee754_|__)|(_fma|_avx2|_sse2)$|@.*$", "", sym)
            libm[name] = libm.get(name, 0.0) + pct
        elif dso != "[JIT]":
            other[f"{dso}: {sym}"] = pct
    if not by_dso:
        return {"available": False, "stderr": rep.stderr[-500:]}
    top_other = dict(sorted(other.items(), key=lambda kv: -kv[1])[:8])
    return {"available": True, "seconds": seconds, "run_batch_calls": calls, "percent_by_library": dict(sorted(by_dso.items(), key=lambda kv: -kv[1])),
            "percent_libm_by_function": dict(sorted(libm.items(), key=lambda kv: -kv[1])),
            "libm_percent": sum(libm.values()), "top_other_symbols_percent": top_other}


def _replay_kernels() -> dict[str, Any]:
    """The replays, compiled with the project's options (not cached: they are this probe's)."""
    import numpy as np

    from gnc_common.compiled import jit
    from gnc_common.input_check import sample_verdicts
    from sappc_controller.core.kernels import KIND_SAPPC, O_TORQUE, S_HAS_PREV, S_PREV, S_T0, controller_step, smetf_solve
    from sappc_controller.core.kernels import P_TANTH
    from spacecraft_sim.core.kernels import propagate

    ns = 1_000_000_000

    @jit(cache=False)
    def ctrl_replay(X, t_ns, dt, ref_q, ref_w, ref_wd, k0, prm, coef, N_STATE, work, out, yc, torque):
        """controller_step over each run's recorded states (the loop's inputs, exact sensors)."""
        for n in range(X.shape[0]):
            state = np.zeros(N_STATE)
            first = True
            for k in range(k0[n], X.shape[1]):
                t_stamp = t_ns[k] / ns
                if first:
                    state[S_T0] = t_stamp
                    first = False
                for i in range(7):
                    yc[i] = X[n, k, i]
                controller_step(KIND_SAPPC, t_stamp, dt, yc[:4], yc[4:], ref_q[k], ref_w[k], ref_wd[k], prm[n], coef[n], state, work, out)
                for i in range(3):
                    torque[n, k, i] = out[O_TORQUE, i]

    @jit(cache=False)
    def newton_replay(X, t_ns, dt, ref_q, ref_w, ref_wd, k0, prm, coef, N_STATE, work, out, yc, steps, mismatches):
        """The SMETF's Newton steps of each sample and axis: the step's solve again, from its warm start."""
        for n in range(X.shape[0]):
            state = np.zeros(N_STATE)
            prev = np.zeros(15)
            first = True
            k_tan = prm[n, P_TANTH]
            for k in range(k0[n], X.shape[1]):
                t_stamp = t_ns[k] / ns
                if first:
                    state[S_T0] = t_stamp
                    first = False
                has_prev = state[S_HAS_PREV] != 0.0
                for i in range(15):
                    prev[i] = state[S_PREV + i]
                for i in range(7):
                    yc[i] = X[n, k, i]
                controller_step(KIND_SAPPC, t_stamp, dt, yc[:4], yc[4:], ref_q[k], ref_w[k], ref_wd[k], prm[n], coef[n], state, work, out)
                for i in range(3):
                    z, delta = state[S_PREV + 6 + i], state[S_PREV + 12 + i]  # this sample's, written by the step
                    guess = 0.0
                    if has_prev:  # the kernel's warm start (sappc_transform), in its order
                        guess = (prev[i] + prev[3 + i] * (z - prev[6 + i])) + prev[9 + i] * (delta - prev[12 + i])
                    eps, _, s = smetf_solve(z, delta, k_tan, has_prev, guess)
                    steps[n, k, i] = s
                    if eps != state[S_PREV + i]:
                        mismatches[0] += 1

    @jit(cache=False)
    def plant_replay(X, U, D, dt, substeps, J, J_inv, x, out_x, umax):
        """propagate from each recorded state with the recorded torque (clipped) and disturbance."""
        u = np.empty(3)
        for n in range(X.shape[0]):
            for k in range(X.shape[1] - 1):
                for i in range(7):
                    x[i] = X[n, k, i]
                for i in range(3):
                    u[i] = min(max(U[n, k, i], -umax), umax) + D[k, i]
                propagate(x, u, dt, substeps, J[n], J_inv[n])
                for i in range(7):
                    out_x[n, k + 1, i] = x[i]

    @jit(cache=False)
    def verdict_replay(X, ref_q, ref_w, ref_wd, bounds, yc, rejected):
        ok = 0
        for n in range(X.shape[0]):
            for k in range(X.shape[1]):
                for i in range(7):
                    yc[i] = X[n, k, i]
                if sample_verdicts(True, True, yc[:4], yc[4:], ref_q[k], ref_w[k], ref_wd[k], bounds, rejected):
                    ok += 1
        return ok

    @jit(cache=False)
    def copy_replay(X, yc):
        """The loop's per-sample copy of the state into the controller's input (the replays' own overhead)."""
        s = 0.0
        for n in range(X.shape[0]):
            for k in range(X.shape[1]):
                for i in range(7):
                    yc[i] = X[n, k, i]
                s += yc[0]
        return s

    @jit(cache=False)
    def table_replay(n_runs, t, t_ns, ref_q, ref_w, ref_wd, table, d):
        """The shared tables a sample reads: its time and stamp, the reference's three rows, the disturbance's row."""
        s = 0.0
        for n in range(n_runs):
            for k in range(t.shape[0]):
                s += t[k] + t_ns[k] / ns
                for i in range(3):
                    d[i] = table[k, i]
                s += ((ref_q[k, 0] + ref_q[k, 3]) + (ref_w[k, 0] + ref_w[k, 2]) + (ref_wd[k, 1] + d[2]))
        return s

    @jit(cache=False)
    def record_replay(pub, x, d, rec_out, rec_x, rec_d, rec_status):
        """The record of every sample (stride 1): the published rows, the state, the disturbance, the answer."""
        for r in range(rec_out.shape[0]):
            for j in range(rec_out.shape[1]):
                for row in range(pub.shape[0]):
                    for c in range(4):
                        rec_out[r, j, row, c] = pub[row, c]
                for i in range(7):
                    rec_x[r, j, i] = x[i]
                for i in range(3):
                    rec_d[r, j, i] = d[i]
                rec_status[r, j] = 1

    return dict(ctrl=ctrl_replay, newton=newton_replay, plant=plant_replay, verdict=verdict_replay, copy=copy_replay, table=table_replay,
                record=record_replay)


def pieces(sub: Any, run: Any, repeats: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """Each piece alone over the replay runs (ns per call, i.e. per run-step), checked against the
    loop's record; the Newton statistics; the realistic arguments of the libm calls (for the
    children)."""
    import numpy as np

    from sappc_controller.core.kernels import C_L, C_T1, N_OUT, N_STATE, N_WORK, O_EPS, O_TORQUE, O_V, P_P, P_RPF_T2, P_T3, P_VFLOOR

    import sappc.offline.compiled_loop as cl

    rec = run.record
    g, c = sub.grid, sub.controller
    X = np.ascontiguousarray(rec.x)  # (N, T, 7): the true state, which the exact sensors measure
    N, T = X.shape[0], X.shape[1]
    # each run's first valid sample (the controller's start: rec.start is the probe's, not kept by run_batch): its first answer
    k0 = np.argmax(rec.status == 0, axis=1).astype(np.int64)  # ANSWER_COMMANDED; before it, the watchdog's zero
    kern = _replay_kernels()
    work, out, yc = np.zeros((N_WORK, 4)), np.zeros((N_OUT, 4)), np.zeros(7)
    torque = np.zeros((N, T, 3))
    t_c = time.perf_counter()
    args = (X, g.t_ns, g.dt, g.ref_q, g.ref_w, g.ref_wd, k0, c.prm, c.coef, N_STATE, work, out, yc)
    kern["ctrl"](*args, torque)
    log(f"controller replay compiled ({time.perf_counter() - t_c:.0f} s)")
    res: dict[str, Any] = {}
    ok_ctrl = bool(np.array_equal(torque, rec.out[:, :, O_TORQUE, :3]))
    # the plant
    U = np.ascontiguousarray(rec.out[:, :, O_TORQUE, :3])
    D = np.ascontiguousarray(sub.disturbance.table)
    x = np.zeros(7)
    out_x = np.zeros_like(X)
    out_x[:, 0] = X[:, 0]
    pl = sub.plant
    umax = float(sub.actuator.max_torque_Nm)
    kern["plant"](X, U, D, g.dt, pl.substeps, pl.J, pl.J_inv, x, out_x, umax)
    ok_plant = bool(np.array_equal(out_x, X))
    rejected = np.zeros(2, dtype=np.int64)
    n_ok = kern["verdict"](X, g.ref_q, g.ref_w, g.ref_wd, c.bounds, yc, rejected)
    d3 = np.zeros(3)
    pub = np.ascontiguousarray(rec.out[0, -1])
    rec_out, rec_x, rec_d, rec_status = (np.zeros_like(rec.out), np.zeros_like(rec.x), np.zeros_like(rec.d), np.zeros_like(rec.status))
    timings: dict[str, list[float]] = {k: [] for k in ("loop_stride0", "loop_stride1", "controller_step", "propagate", "sample_verdicts",
                                                      "state_copy", "table_reads", "record_writes")}
    calls = {"controller_step": float(sum(T - int(k) for k in k0)), "propagate": float(N * (T - 1)), "sample_verdicts": float(N * T),
             "state_copy": float(N * T), "table_reads": float(N * T), "record_writes": float(N * T), "loop_stride0": float(N * T),
             "loop_stride1": float(N * T)}
    kern["copy"](X, yc)
    kern["table"](N, g.t, g.t_ns, g.ref_q, g.ref_w, g.ref_wd, D, d3)
    kern["record"](pub, X[0, 0], D[0], rec_out, rec_x, rec_d, rec_status)
    for _ in range(repeats):
        for name, call in (("loop_stride0", lambda: cl.run_batch(sub, 0)), ("loop_stride1", lambda: cl.run_batch(sub, 1, into=run)),
                           ("controller_step", lambda: kern["ctrl"](*args, torque)),
                           ("propagate", lambda: kern["plant"](X, U, D, g.dt, pl.substeps, pl.J, pl.J_inv, x, out_x, umax)),
                           ("sample_verdicts", lambda: kern["verdict"](X, g.ref_q, g.ref_w, g.ref_wd, c.bounds, yc, rejected)),
                           ("state_copy", lambda: kern["copy"](X, yc)),
                           ("table_reads", lambda: kern["table"](N, g.t, g.t_ns, g.ref_q, g.ref_w, g.ref_wd, D, d3)),
                           ("record_writes", lambda: kern["record"](pub, X[0, 0], D[0], rec_out, rec_x, rec_d, rec_status))):
            t0 = time.perf_counter()
            call()
            timings[name].append((time.perf_counter() - t0) / calls[name] * 1e9)
    res["ns_per_call"] = {k: med(v) for k, v in timings.items()}
    res["checks"] = {"controller_replay_equals_loop_torques_bit_for_bit": ok_ctrl, "plant_replay_equals_loop_states_bit_for_bit": ok_plant,
                     "valid_samples": int(n_ok), "of_samples": N * T, "statuses_commanded": bool((rec.status == 0).all()),
                     "start_sample": sorted(set(int(k) for k in k0))}
    # the Newton steps
    steps = np.full((N, T, 3), -1, dtype=np.int64)
    mism = np.zeros(1, dtype=np.int64)
    t_c = time.perf_counter()
    kern["newton"](*args, steps, mism)
    log(f"Newton replay compiled and run ({time.perf_counter() - t_c:.0f} s)")
    res["newton"] = newton_stats(steps, g.t, int(mism[0]))
    # the libm calls per run-step: counted on the runs where they depend on the phase
    tau = g.t[None, :] - g.t[k0][:, None]  # the law's time since the start (k0: the first sample)
    t1 = c.coef[:, C_T1, :]  # (N, 3)
    t2 = c.prm[:, P_RPF_T2]
    rpf_exp = ((tau[:, :, None] < t1[:, None, :]) & (tau[:, :, None] < t2[:, None, None])).sum(axis=2)  # (N, T)
    s = steps[steps >= 0]
    res["libm_per_run_step"] = libm_counts(float(rpf_exp.mean()), float(s.mean()) if s.size else float("nan"))
    # realistic arguments of each libm call (for the children's ulp and throughput tests)
    V = np.maximum(rec.out[:, :, O_V, :3], c.prm[0, P_VFLOOR]).ravel()
    p, T3 = c.prm[0, P_P], c.prm[0, P_T3]
    Vp = V ** p
    V3p = np.maximum(rec.out[:, :, O_V, 2], c.prm[0, P_VFLOOR]).ravel() ** p
    M3 = np.exp(V3p) / (V3p * (2.0 * p * T3))
    l_t = (-c.coef[:, C_L, :][:, None, :] * np.maximum(tau, 0.0)[:, :, None])[(tau[:, :, None] < t1[:, None, :])]
    rng = np.random.default_rng(1)
    tanh_args = rng.choice([-1.0, 1.0], 20000) * 10.0 ** rng.uniform(-4.0, 2.0, 20000)
    eps = rec.out[:, :, O_EPS, :3].ravel()
    argset = {"exp": np.concatenate([Vp, l_t]), "pow": V, "atan": np.concatenate([eps, eps * (1.0 + 1e-3)]),
              "tanh": tanh_args, "expm1": -M3 * g.dt}
    argset = {k: np.ascontiguousarray(v[np.isfinite(v)]) for k, v in argset.items()}
    res["libm_argument_ranges"] = {k: {"n": int(v.size), "min": float(v.min()), "max": float(v.max()),
                                       "source": src} for (k, v), src in zip(argset.items(), (
                                           "V^p of the runs' V1, V2, V3 (the gains' exp) and -l tau of the RPF's exponential phase",
                                           "the runs' V1, V2, V3 floored at V_floor (pow(V, p), p = 0.1)",
                                           "the runs' final eps and eps (1 + 1e-3) (the Newton iterates near the root)",
                                           "synthetic: +-10^U(-4, 2) (z2 / mu is not recorded)",
                                           "-M3 dt from the runs' V3 (the filter's expm1)"))}
    return res, argset


def newton_stats(steps: Any, t: Any, mismatches: int) -> dict[str, Any]:
    import numpy as np

    s = steps
    valid = s >= 0
    vals = s[valid]
    hist = {int(v): int(c) for v, c in zip(*np.unique(vals, return_counts=True))}
    warm = s[:, 1:, :][valid[:, 1:, :]]
    per_step = np.where(valid, s, 0).sum(axis=2)  # (N, T): Newton steps of a run-step (3 axes)
    transient = t < 20.0
    out: dict[str, Any] = {"mismatches_with_the_steps_eps": mismatches, "histogram_steps_per_axis_sample": hist,
                           "mean_steps_per_axis_sample_warm": float(warm.mean()), "max_steps_warm": int(warm.max()),
                           "cold_first_sample_steps": [int(v) for v in s[:, 0, :].ravel()[:12]],
                           "mean_steps_per_run_step": float(per_step[:, 1:].mean()),
                           "mean_steps_per_run_step_t_lt_20s": float(per_step[:, 1:][:, transient[1:]].mean()),
                           "mean_steps_per_run_step_t_ge_20s": float(per_step[:, 1:][:, ~transient[1:]].mean()),
                           "atan_calls_per_run_step": float((np.where(valid, s + 1, 0).sum(axis=2))[:, 1:].mean())}
    # lanes: W consecutive runs stepped together iterate until the slowest lane has converged
    lanes = {}
    N = s.shape[0]
    for W in (4, 8):
        g = N // W
        if g == 0:
            continue
        blk = np.where(valid, s, 0)[: g * W, 1:, :].reshape(g, W, -1, 3)
        lanes[f"W{W}"] = {"mean_of_max_over_lanes_per_axis_sample": float(blk.max(axis=1).mean()),
                          "mean_per_lane_per_axis_sample": float(blk.mean()),
                          "ratio_masked_over_scalar": float(blk.max(axis=1).mean() / max(blk.mean(), 1e-300))}
    out["lanes"] = lanes
    return out


def libm_counts(rpf_exp_mean: float, newton_steps_mean: float) -> dict[str, Any]:
    """libm calls of one SAPPC run-step of paper_montecarlo (read from the code; the loop checks and
    the RK4 call no libm function: their square roots are instructions, vsqrtsd)."""
    atan = 3.0 * (newton_steps_mean + 1.0)  # smetf_solve: one arctan per residual, steps + 1 per axis
    divisions = 3.0 * (9.0 + 2.0 * newton_steps_mean) + 8.0 + 6.0 + 9.0 + 1.0
    table = [
        ("pow", 3.0, "predefined_time_gain x3: M_q (V1), M_omega (V2), M3 (V3): max(V, V_floor) ** p"),
        ("exp", 3.0 + rpf_exp_mean, "predefined_time_gain x3 (exp(V^p)); rpf_evaluate: exp(-l tau) per axis in its exponential phase "
                                    f"(tau < t1 and tau < t2: {rpf_exp_mean:.3f} a run-step on these runs)"),
        ("expm1", 1.0, "filter_update: -expm1(-M3 dt) (rate and torque filters off: P_RATE_WC = P_TORQUE_WC = 0)"),
        ("tanh", 3.0, "backstepping_law: D_m tanh(z2_i / mu), i = 0..2"),
        ("atan", atan, f"smetf_solve: (Newton steps + 1) per axis, {newton_steps_mean:.3f} steps per axis-sample on these runs"),
    ]
    return {"calls": {name: {"per_run_step": n, "where": where} for name, n, where in table},
            "total_libm_calls_per_run_step": sum(n for _, n, _ in table),
            "sqrt_instructions_per_run_step": {"n": 6.0, "where": "sample_verdicts: 2 quaternion norms, 3 vector magnitudes (nonzero); "
                                               "rk4_step: 1 quaternion norm (vsqrtsd, not libm)"},
            "divisions_per_run_step": {"n": divisions, "where": {
                "sappc_transform (3 axes)": f"3 x (9 + 2 x Newton steps) = {3 * (9 + 2 * newton_steps_mean):.1f}: delta, z, the lower bound's 2, "
                                            "2 a Newton step, P_s's 2, d eps/d delta, psi, eta",
                "backstepping_law": "8: eps / psi x3, Gamma^-1's / q0, the gains' 3, the filter's / dt",
                "propagate": "6: dt / substeps, dt / 6, the quaternion's normalisation x4",
                "sample_verdicts": "9: each vector scaled by its largest component (3 x 3)",
                "the loop": "1: the stamp in seconds"}, "note": "no fastmath: LLVM keeps every division (vdivsd; vdivpd in lanes)"}}


def libm_scalar_cost(argset: dict[str, Any], repeats: int) -> dict[str, Any]:
    """Each scalar libm call's cost on the runs' arguments, in this process (the project's options):
    a loop of independent calls (LLVM vectorises the loop around them and calls the scalar function
    once per element, 4 a vector) and a dependent chain (each call waits for the last: the Newton
    loop's pattern)."""
    import numpy as np

    from gnc_common.compiled import jit

    @jit(cache=False)
    def thr_exp(x, y):
        for i in range(x.shape[0]):
            y[i] = np.exp(x[i])

    @jit(cache=False)
    def thr_pow(x, y):
        for i in range(x.shape[0]):
            y[i] = x[i] ** 0.1

    @jit(cache=False)
    def thr_atan(x, y):
        for i in range(x.shape[0]):
            y[i] = np.arctan(x[i])

    @jit(cache=False)
    def thr_tanh(x, y):
        for i in range(x.shape[0]):
            y[i] = np.tanh(x[i])

    @jit(cache=False)
    def thr_expm1(x, y):
        for i in range(x.shape[0]):
            y[i] = np.expm1(x[i])

    @jit(cache=False)
    def lat_exp(x):
        a = 0.0
        for i in range(x.shape[0]):
            a = np.exp(x[i] + a * 1e-300)
        return a

    @jit(cache=False)
    def lat_pow(x):
        a = 0.0
        for i in range(x.shape[0]):
            a = (x[i] + a * 1e-300) ** 0.1
        return a

    @jit(cache=False)
    def lat_atan(x):
        a = 0.0
        for i in range(x.shape[0]):
            a = np.arctan(x[i] + a * 1e-300)
        return a

    @jit(cache=False)
    def lat_tanh(x):
        a = 0.0
        for i in range(x.shape[0]):
            a = np.tanh(x[i] + a * 1e-300)
        return a

    @jit(cache=False)
    def lat_expm1(x):
        a = 0.0
        for i in range(x.shape[0]):
            a = np.expm1(x[i] + a * 1e-300)
        return a

    @jit(cache=False)
    def thr_div(x, y):
        for i in range(x.shape[0]):
            y[i] = 1.5 / x[i]

    @jit(cache=False)
    def lat_div(x):
        a = 1.0
        for i in range(x.shape[0]):
            a = x[i] / (a + 1.0)
        return a

    @jit(cache=False)
    def thr_none(x, y):
        for i in range(x.shape[0]):
            y[i] = x[i] * 1.5

    thr = {"exp": thr_exp, "pow": thr_pow, "atan": thr_atan, "tanh": thr_tanh, "expm1": thr_expm1}
    lat = {"exp": lat_exp, "pow": lat_pow, "atan": lat_atan, "tanh": lat_tanh, "expm1": lat_expm1}
    out: dict[str, Any] = {}
    for name in LIBM:
        x = np.resize(argset[name], 1 << 16)
        y = np.empty_like(x)
        thr[name](x, y)
        lat[name](x)
        tt, tl = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(4):
                thr[name](x, y)
            tt.append((time.perf_counter() - t0) / (4 * x.size) * 1e9)
            t0 = time.perf_counter()
            for _ in range(4):
                lat[name](x)
            tl.append((time.perf_counter() - t0) / (4 * x.size) * 1e9)
        asm = thr[name].inspect_asm(thr[name].signatures[0])
        vec = bool(re.search(r"ymm|zmm", asm))
        out[name] = {"ns_per_call_independent": med(tt), "ns_per_call_dependent_chain": med(tl),
                     "loop_vectorised_around_scalar_calls": vec}
    x = np.resize(argset["exp"], 1 << 16)
    y = np.empty_like(x)
    thr_none(x, y)
    tn = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(4):
            thr_none(x, y)
        tn.append((time.perf_counter() - t0) / (4 * x.size) * 1e9)
    out["loop_without_call_ns_per_element"] = med(tn)
    x = np.resize(argset["pow"], 1 << 16) + 1.0
    thr_div(x, y)
    lat_div(x)
    td, tdl = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(4):
            thr_div(x, y)
        td.append((time.perf_counter() - t0) / (4 * x.size) * 1e9)
        t0 = time.perf_counter()
        for _ in range(4):
            lat_div(x)
        tdl.append((time.perf_counter() - t0) / (4 * x.size) * 1e9)
    asm = thr_div.inspect_asm(thr_div.signatures[0])
    out["division"] = {"ns_per_element_vectorised_loop": med(td), "vector_instruction": sorted(set(re.findall(r"vdivp[sd]", asm))),
                       "ymm": "ymm" in asm, "zmm": "zmm" in asm, "ns_per_division_dependent_chain_with_an_add": med(tdl)}
    return out


# ============================================================================= children (own options, own cache)


def run_child(mode: str, extra: list[str], argfile: str | None, timeout: int = 600, env_extra: dict[str, str] | None = None) -> dict[str, Any]:
    """``mode`` in a child process with its own numba cache directory (the project's cache is
    untouched: the children compile only this probe's kernels with their options)."""
    with tempfile.TemporaryDirectory(prefix="simd_probe_") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, **(env_extra or {}))
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", mode, *(["--argfile", argfile] if argfile else []), *extra]
        t0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=str(ROOT))
        if p.returncode != 0:
            return {"error": f"exit {p.returncode}", "stderr_tail": p.stderr[-3000:]}
        lines = [line for line in p.stdout.splitlines() if line.startswith("{")]
        res = json.loads(lines[-1])
        res["child_wall_s"] = round(time.perf_counter() - t0, 1)
        res["llvm_debug_lines"] = _lv_lines(p.stderr)
        return res


def _lv_lines(stderr: str) -> dict[str, list[str]]:
    """The loop vectorizer's decisions in a child's stderr (its debug output and remarks), by the
    function compiled (``LV: Checking a loop in ... from <name>``), deduplicated with counts."""
    keep = re.compile(r"^(LV: (Not vectorizing|Can't vectorize|Vectorizing|Selecting VF|We can vectorize|Found a non-intrinsic|"
                      r"Found unvectorizable|Unsupported|Loop contains|Did not find|Found an outer|Not inserting|Found FP op)|"
                      r"remark: .*(vectoriz|Vectoriz|SLP)|(WIDEN-CALL|WIDEN-INTRINSIC|REPLICATE) .*call)")
    groups: dict[str, dict[str, int]] = {}
    checked: dict[str, int] = {}
    current = "(before the first loop)"
    for raw in stderr.splitlines():
        line = raw.strip()
        m = re.match(r"LV: Checking a loop in '.*' from (.*)$", line)
        if m:
            current = m.group(1).split(".<locals>.")[-1]
            checked[current] = checked.get(current, 0) + 1
            continue
        if line.startswith("=== "):
            current = line[4:]
            continue
        line = re.sub(r"_ZN\w+", "<fn>", line)
        line = re.sub(r"%[\w.]+", "%v", line)
        if keep.search(line) or "using library function" in line:
            g = groups.setdefault(current, {})
            g[line] = g.get(line, 0) + 1
    return {name: [f"innermost loops checked: {checked.get(name, 0)}"] + [f"{k}  (x{v})" if v > 1 else k for k, v in g.items()][:40]
            for name, g in groups.items()}


def _set_llvm_options(opts: list[str]) -> None:
    import llvmlite.binding as llvm

    for o in opts:
        llvm.set_option("", o)  # errors are silent (LLVMParseCommandLineOptions prints them to nulls())


def _vector_intrinsic(name: str, nargs: int, variants: tuple[tuple[str, int], ...], readnone: bool = True) -> Any:
    """A numba intrinsic for the scalar libm ``name`` whose declaration carries the vector function
    ABI's mapping to glibc's libmvec variants (``"vector-function-abi-variant"``, what
    ``#pragma omp declare simd`` produces in C), ``memory(none)`` (no errno: what
    ``-fno-math-errno`` declares), the vector variants declared and kept (``llvm.compiler.used``).
    The loop vectorizer then calls the variant of the width it picks; a scalar remainder calls the
    scalar function.  ``readnone`` false: the declaration as numba's (LLVM infers that it may write
    errno), to show what the mapping needs."""
    from llvmlite import ir
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    d = ir.DoubleType()
    pars = "v" * nargs
    names = [f"_ZGV{isa}N{w}{pars}_{name}" for isa, w in variants]
    attr = '"vector-function-abi-variant"="' + ",".join(f"{m}({m})" for m in names) + '"'

    def codegen(context, builder, signature, args):  # noqa: ARG001
        mod = builder.module
        fn = cgutils.get_or_insert_function(mod, ir.FunctionType(d, [d] * nargs), name)
        for a in (attr, "nounwind", *(("readnone",) if readnone else ())):
            set.add(fn.attributes, a)  # llvmlite's set accepts only its known names: the string attribute added as is
        used = []
        for (isa, w), m in zip(variants, names):
            vt = ir.VectorType(d, w)
            used.append(cgutils.get_or_insert_function(mod, ir.FunctionType(vt, [vt] * nargs), m))
        if "llvm.compiler.used" not in mod.globals:
            pt = ir.PointerType(ir.IntType(8))
            arr = ir.ArrayType(pt, len(used))
            g = ir.GlobalVariable(mod, arr, "llvm.compiler.used")
            g.linkage = "appending"
            g.section = "llvm.metadata"
            g.initializer = ir.Constant(arr, [u.bitcast(pt) for u in used])
        return builder.call(fn, args)

    if nargs == 1:
        @intrinsic
        def f1(typingctx, x):  # noqa: ARG001
            return types.float64(types.float64), codegen
        return f1

    @intrinsic
    def f2(typingctx, x, y):  # noqa: ARG001
        return types.float64(types.float64, types.float64), codegen
    return f2


def _ulps(a: Any, b: Any) -> Any:
    """|a - b| in units in the last place (the distance between the float64 bit patterns)."""
    import numpy as np

    ia = a.view(np.int64)
    ib = b.view(np.int64)
    ia = np.where(ia < 0, np.int64(-(2**63)) - ia, ia)  # a monotone integer order of the floats
    ib = np.where(ib < 0, np.int64(-(2**63)) - ib, ib)
    return np.abs(ia - ib)


def child_libmvec(argfile: str, route: str, vf: int, repeats: int) -> dict[str, Any]:
    """``route``: ``veclib:NAME`` (LLVM's -vector-library option, plain math calls) or ``attribute``
    (the call-site mapping); ``vf``: 0 (LLVM's choice) or a forced width."""
    import llvmlite.binding as llvm

    opts = []
    if route.startswith("veclib:"):  # LLVM's own mapping (LIBMVEC in LLVM 21+, LIBMVEC-X86 before); a wrong name is ignored silently
        opts += [f"-vector-library={route.split(':', 1)[1]}"]
    if vf:
        opts += [f"-force-vector-width={vf}"]
    opts += ["-debug-only=loop-vectorize", "-pass-remarks=loop-vectorize", "-pass-remarks-missed=loop-vectorize"]
    _set_llvm_options(opts)
    llvm.load_library_permanently(LIBMVEC)
    import numba
    import numpy as np

    argset = dict(np.load(argfile))
    variants = (("e", 8), ("d", 4), ("b", 2))
    vlib = {n: _vector_intrinsic(n, k, variants, readnone=route != "attribute-errno") for n, k in LIBM.items()}
    opt = dict(fastmath=False, error_model="numpy", cache=False)
    if route.startswith("attribute"):
        ve, vp, va, vt, vm = (vlib[n] for n in ("exp", "pow", "atan", "tanh", "expm1"))

        @numba.njit(**opt)
        def k_exp(x, y):
            for i in range(x.shape[0]):
                y[i] = ve(x[i])

        @numba.njit(**opt)
        def k_pow(x, y):
            for i in range(x.shape[0]):
                y[i] = vp(x[i], 0.1)

        @numba.njit(**opt)
        def k_atan(x, y):
            for i in range(x.shape[0]):
                y[i] = va(x[i])

        @numba.njit(**opt)
        def k_tanh(x, y):
            for i in range(x.shape[0]):
                y[i] = vt(x[i])

        @numba.njit(**opt)
        def k_expm1(x, y):
            for i in range(x.shape[0]):
                y[i] = vm(x[i])
    else:
        @numba.njit(**opt)
        def k_exp(x, y):
            for i in range(x.shape[0]):
                y[i] = np.exp(x[i])

        @numba.njit(**opt)
        def k_pow(x, y):
            for i in range(x.shape[0]):
                y[i] = x[i] ** 0.1

        @numba.njit(**opt)
        def k_atan(x, y):
            for i in range(x.shape[0]):
                y[i] = np.arctan(x[i])

        @numba.njit(**opt)
        def k_tanh(x, y):
            for i in range(x.shape[0]):
                y[i] = np.tanh(x[i])

        @numba.njit(**opt)
        def k_expm1(x, y):
            for i in range(x.shape[0]):
                y[i] = np.expm1(x[i])

    # the scalar reference: the same calls with the loop vectorizer off for these loops (one call per element)
    @numba.njit(**opt)
    def s_all(xe, ye, xp, yp, xa, ya, xt, yt, xm, ym):
        for i in range(xe.shape[0]):
            ye[i] = np.exp(xe[i])
        for i in range(xp.shape[0]):
            yp[i] = xp[i] ** 0.1
        for i in range(xa.shape[0]):
            ya[i] = np.arctan(xa[i])
        for i in range(xt.shape[0]):
            yt[i] = np.tanh(xt[i])
        for i in range(xm.shape[0]):
            ym[i] = np.expm1(xm[i])

    ks = {"exp": k_exp, "pow": k_pow, "atan": k_atan, "tanh": k_tanh, "expm1": k_expm1}
    xs = {n: np.ascontiguousarray(np.resize(argset[n], 1 << 16)) for n in LIBM}
    ref = {n: np.empty_like(xs[n]) for n in LIBM}
    s_all(xs["exp"], ref["exp"], xs["pow"], ref["pow"], xs["atan"], ref["atan"], xs["tanh"], ref["tanh"], xs["expm1"], ref["expm1"])
    out: dict[str, Any] = {"route": route, "forced_vf": vf, "llvm_options": opts, "functions": {}}
    for n, k in ks.items():
        y = np.empty_like(xs[n])
        k(xs[n], y)
        asm = k.inspect_asm(k.signatures[0])
        ir_text = k.inspect_llvm(k.signatures[0])
        zgv = sorted(set(re.findall(r"(_ZGV[bcde]N\d+v+_\w+)", asm)))
        vec_intr = sorted(set(re.findall(r"@llvm\.(\w+)\.v(\d+)f64", ir_text)))
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(4):
                k(xs[n], y)
            times.append((time.perf_counter() - t0) / (4 * y.size) * 1e9)
        u = _ulps(y, ref[n])
        rel = np.abs(y - ref[n]) / np.maximum(np.abs(ref[n]), 1e-300)
        out["functions"][n] = {"libmvec_variants_called": zgv, "vector_intrinsics_in_ir": [f"llvm.{a}.v{b}f64" for a, b in vec_intr],
                               "uses_zmm": "zmm" in asm, "uses_ymm": "ymm" in asm, "ns_per_element": med(times),
                               "ulps_vs_scalar_glibc": {"max": int(u.max()), "mean": float(u.mean()),
                                                        "fraction_differing": float((u > 0).mean())},
                               "max_relative_difference": float(rel.max()), "n_args": int(y.size)}
    return out


def child_lanes(argfile: str, repeats: int) -> dict[str, Any]:
    """A lane loop over the existing kernels, ``for lane in range(W)`` innermost over one sample, with
    the vectorizer's debug output (stderr, parsed by the parent) and what it costs per lane-step."""
    _set_llvm_options(["-debug-only=loop-vectorize", "-pass-remarks-missed=loop-vectorize", "-pass-remarks-analysis=loop-vectorize",
                       "-pass-remarks=loop-vectorize|slp-vectorizer"])
    import numpy as np

    from gnc_common.compiled import jit
    from gnc_common.input_check import sample_verdicts
    from sappc_controller.core.kernels import KIND_SAPPC, N_OUT, N_STATE, N_WORK, O_TORQUE, S_T0, controller_step
    from spacecraft_sim.core.kernels import propagate

    a = dict(np.load(argfile))
    X, ref_q, ref_w, ref_wd, t_ns = a["X"], a["ref_q"], a["ref_w"], a["ref_wd"], a["t_ns"]
    prm, coef, J, J_inv, U, D, bounds = a["prm"], a["coef"], a["J"], a["J_inv"], a["U"], a["D"], a["bounds"]
    dt, substeps, umax = float(a["dt"]), int(a["substeps"]), float(a["umax"])
    W = X.shape[0]
    T = X.shape[1]

    @jit(cache=False)
    def lanes_plant(X, U, D, dt, substeps, J, J_inv, x, u):
        """Each sample: for every lane, its state from the record, its torque, propagate (rows of AoS arrays)."""
        for k in range(X.shape[1] - 1):
            for lane in range(X.shape[0]):
                for i in range(7):
                    x[lane, i] = X[lane, k, i]
                for i in range(3):
                    u[lane, i] = U[lane, k, i] + D[k, i]
                propagate(x[lane], u[lane], dt, substeps, J[lane], J_inv[lane])

    @jit(cache=False)
    def lanes_plant_one_substep(X, U, D, dt, J, J_inv, x, u):
        """The same with the substeps a constant 1 (the scenario's): no inner loop left in the lane loop."""
        for k in range(X.shape[1] - 1):
            for lane in range(X.shape[0]):
                for i in range(7):
                    x[lane, i] = X[lane, k, i]
                for i in range(3):
                    u[lane, i] = U[lane, k, i] + D[k, i]
                propagate(x[lane], u[lane], dt, 1, J[lane], J_inv[lane])

    @jit(cache=False)
    def lanes_verdicts(X, ref_q, ref_w, ref_wd, bounds, yc, rejected, ok):
        for k in range(X.shape[1]):
            for lane in range(X.shape[0]):
                for i in range(7):
                    yc[lane, i] = X[lane, k, i]
                ok[lane] = sample_verdicts(True, True, yc[lane, :4], yc[lane, 4:], ref_q[k], ref_w[k], ref_wd[k], bounds, rejected[lane])

    @jit(cache=False)
    def lanes_controller(X, t_ns, dt, ref_q, ref_w, ref_wd, prm, coef, state, work, out, yc, torque):
        for k in range(X.shape[1]):
            t_stamp = t_ns[k] / 1_000_000_000
            for lane in range(X.shape[0]):
                for i in range(7):
                    yc[lane, i] = X[lane, k, i]
                controller_step(KIND_SAPPC, t_stamp, dt, yc[lane, :4], yc[lane, 4:], ref_q[k], ref_w[k], ref_wd[k], prm[lane], coef[lane],
                                state[lane], work[lane], out[lane])
                for i in range(3):
                    torque[lane, k, i] = out[lane, O_TORQUE, i]

    from gnc_common.compiled import dcm_BR_times_of, gamma_inverse_of
    from sappc_controller.core.kernels import P_P, P_Q0FLOOR, P_T1, P_VFLOOR, predefined_time_gain

    @jit(cache=False)
    def soa_geometry(XS, O, q0f):
        """Structure of arrays, (T, component, lane): the kernels' scalar-in, scalar-out helpers per
        lane, C_e v then Gamma^-1 of it (gnc_common.compiled's dcm_BR_times_of, gamma_inverse_of)."""
        for k in range(XS.shape[0]):
            for lane in range(XS.shape[2]):
                c = dcm_BR_times_of(XS[k, 0, lane], XS[k, 1, lane], XS[k, 2, lane], XS[k, 3, lane], XS[k, 4, lane], XS[k, 5, lane],
                                    XS[k, 6, lane])
                g = gamma_inverse_of(XS[k, 0, lane], XS[k, 1, lane], XS[k, 2, lane], XS[k, 3, lane], c[0], c[1], c[2], q0f)
                O[0, lane] = g[0]
                O[1, lane] = g[1]
                O[2, lane] = g[2]

    @jit(cache=False)
    def soa_gain(VS, M, p, T1, Vf):
        """The predefined-time gain per lane (kernels.predefined_time_gain: pow, exp, a division)."""
        for k in range(VS.shape[0]):
            for lane in range(VS.shape[1]):
                M[lane] = predefined_time_gain(VS[k, lane], p, T1, Vf)

    res: dict[str, Any] = {"W": W, "samples": T, "kernels": {}}

    def asm_profile(k: Any) -> dict[str, Any]:
        asm = k.inspect_asm(k.signatures[0])
        body = [line.split()[0] for line in asm.splitlines() if line.startswith("\t") and not line.startswith("\t.")]
        packed = sum(1 for m in body if re.match(r"v(add|sub|mul|div|fmadd\w*|sqrt|max|min|and|or|xor|blendv)pd$", m))
        scalar = sum(1 for m in body if re.match(r"v(add|sub|mul|div|fmadd\w*|sqrt|max|min)sd$", m))
        return {"instructions": len(body), "packed_double_arith": packed, "scalar_double_arith": scalar,
                "zmm_mentions": asm.count("zmm"), "ymm_mentions": asm.count("ymm"),
                "calls_to_nrt_incref_decref": len(re.findall(r"NRT_(?:incref|decref)", asm)),
                "calls_to_libm": {f: len(re.findall(rf"\${f}\b", asm)) for f in ("atan", "exp", "pow", "tanh", "expm1")}}

    def timed(name: str, call: Any, per: float) -> None:
        t0 = time.perf_counter()
        call()
        compile_s = time.perf_counter() - t0
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            call()
            ts.append((time.perf_counter() - t0) / per * 1e9)
        res["kernels"][name] = {"compile_and_first_run_s": round(compile_s, 1), "ns_per_lane_step": med(ts)}

    x, u = np.zeros((W, 7)), np.zeros((W, 3))
    print("=== lanes_plant", file=sys.stderr, flush=True)
    timed("propagate_substeps_runtime", lambda: lanes_plant(X, U, D, dt, substeps, J, J_inv, x, u), W * (T - 1))
    res["kernels"]["propagate_substeps_runtime"]["asm"] = asm_profile(lanes_plant)
    print("=== lanes_plant_one_substep", file=sys.stderr, flush=True)
    timed("propagate_substeps_1", lambda: lanes_plant_one_substep(X, U, D, dt, J, J_inv, x, u), W * (T - 1))
    res["kernels"]["propagate_substeps_1"]["asm"] = asm_profile(lanes_plant_one_substep)
    yc, rejected, ok = np.zeros((W, 7)), np.zeros((W, 2), dtype=np.int64), np.zeros(W, dtype=np.bool_)
    print("=== lanes_verdicts", file=sys.stderr, flush=True)
    timed("sample_verdicts", lambda: lanes_verdicts(X, ref_q, ref_w, ref_wd, bounds, yc, rejected, ok), W * T)
    res["kernels"]["sample_verdicts"]["asm"] = asm_profile(lanes_verdicts)
    XS = np.ascontiguousarray(X.transpose(1, 2, 0))  # (T, 7, W)
    VS = np.ascontiguousarray(np.maximum(a["V1"], 1e-12).T)  # (T, W)
    O, M = np.zeros((3, W)), np.zeros(W)
    p, T1, Vf, q0f = prm[0, P_P], prm[0, P_T1], prm[0, P_VFLOOR], prm[0, P_Q0FLOOR]
    # the same loops with one lane (the vector body never runs: the scalar code of the same source) over as many lane-steps
    XS1 = np.ascontiguousarray(XS.transpose(0, 2, 1).reshape(T * W, 7)[:, :, None])
    VS1 = np.ascontiguousarray(VS.reshape(T * W, 1))
    print("=== soa_geometry", file=sys.stderr, flush=True)
    timed("soa_geometry_W_lanes", lambda: soa_geometry(XS, O, q0f), W * T)
    timed("soa_geometry_one_lane", lambda: soa_geometry(XS1, O, q0f), W * T)
    res["kernels"]["soa_geometry_W_lanes"]["asm"] = asm_profile(soa_geometry)
    print("=== soa_gain", file=sys.stderr, flush=True)
    timed("soa_gain_W_lanes", lambda: soa_gain(VS, M, p, T1, Vf), W * T)
    timed("soa_gain_one_lane", lambda: soa_gain(VS1, M, p, T1, Vf), W * T)
    res["kernels"]["soa_gain_W_lanes"]["asm"] = asm_profile(soa_gain)
    state = np.zeros((W, N_STATE))
    work, out, torque = np.zeros((W, N_WORK, 4)), np.zeros((W, N_OUT, 4)), np.zeros((W, T, 3))

    def ctrl() -> None:
        state[:] = 0.0
        state[:, S_T0] = 0.0
        lanes_controller(X, t_ns, dt, ref_q, ref_w, ref_wd, prm, coef, state, work, out, yc, torque)

    print("=== lanes_controller", file=sys.stderr, flush=True)
    timed("controller_step", ctrl, W * T)
    res["kernels"]["controller_step"]["asm"] = asm_profile(lanes_controller)
    res["controller_lane_loop_equals_loop_torques"] = bool(np.array_equal(torque, a["torque"]))
    return res


# ============================================================================= what it implies


def projection(r: dict[str, Any]) -> dict[str, Any]:
    """Bounds on an SoA kernel's time per run-step from these figures (an estimate, not a
    measurement): the libm calls at libmvec's cost per element (the Newton's arctan calls times the
    lanes' masking: every lane iterates as long as the slowest), the rest of the pieces divided by
    an arithmetic speed-up ``s`` over lanes, the loop's glue left as it is."""
    b = r["budget_ns_per_run_step"]
    calls = {f: v["per_run_step"] for f, v in r["pieces"]["libm_per_run_step"]["calls"].items()}
    newton = r["pieces"]["newton"]
    out: dict[str, Any] = {"assumptions": "T_new = L_vec + (pieces - L_scalar) / s + rest_of_loop, s the speed-up of the rest of the "
                                          "pieces over lanes; L_scalar either the calls per run-step times their cost alone (independent "
                                          "calls) or libm's share of the loop's perf samples; the record writes (stride 1) added unchanged"}
    sum0, rest, rec_cost = b["sum_of_pieces_stride0"], b["rest_of_loop_stride0"], b["record_cost_in_loop_stride1_minus_0"]
    bounds = [("L_scalar_calls_x_cost", b["libm_estimate_independent_calls"])]
    prof = r["loop"].get("perf_profile_stride0", {})
    if prof.get("available"):  # libm's share of the loop's samples (libm itself; numba's wrappers are in the rest), of the replay runs' loop
        bounds.append(("L_scalar_perf_share", prof["libm_percent"] / 100.0 * b["loop_stride0"]))
    out["libm_scalar_ns_per_run_step_used"] = dict(bounds)
    for W, key in ((4, "attribute_vfauto"), (8, "attribute_vf8")):
        lib = r["libmvec"].get(key, {}).get("functions")
        lanes = newton["lanes"].get(f"W{W}")
        if not lib or not lanes:
            continue
        atan_masked = 3.0 * (lanes["mean_of_max_over_lanes_per_axis_sample"] + 1.0)
        L_vec = sum((atan_masked if f == "atan" else calls[f]) * lib[f]["ns_per_element"]["median"] for f in LIBM)
        rows = {}
        for s_ar in (1.0, 2.0, 3.0, 4.0, W * 1.0):
            for label, L in bounds:
                A = max(sum0 - L, 0.0)
                t_new = L_vec + A / s_ar + rest
                rows[f"s={s_ar:g},{label}"] = {"ns_per_run_step": t_new, "speedup_stride0": b["loop_stride0"] / t_new,
                                                "speedup_stride1_records_unchanged": b["loop_stride1"] / (t_new + rec_cost)}
        out[f"W{W}"] = {"libm_vec_ns_per_run_step": L_vec, "atan_calls_masked_per_run_step": atan_masked, "rows": rows}
    rows = {}
    for s_ar in (2.0, 3.0, 4.0, 8.0):  # bit for bit with today: the lanes call scalar glibc (its cost per element unchanged)
        for label, L in bounds:
            t_new = L + max(sum0 - L, 0.0) / s_ar + rest
            rows[f"s={s_ar:g},{label}"] = {"ns_per_run_step": t_new, "speedup_stride0": b["loop_stride0"] / t_new}
    out["scalar_glibc_in_lanes"] = {"rows": rows}
    div = r["libm_scalar_cost"].get("division", {})
    if div:
        n_div = r["pieces"]["libm_per_run_step"]["divisions_per_run_step"]["n"]
        out["division_floor_ns_per_run_step_in_lanes"] = {"n_divisions": n_div, "ns": n_div * div["ns_per_element_vectorised_loop"]["median"],
                                                          "note": "the divisions alone at the vectorised loop's cost per element "
                                                                  "(vdivpd: about 2 cycles an element whatever the width)"}
    return out


# ============================================================================= main


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200, help="runs of the whole-loop figure (default 200, bench_loop_step.py's)")
    parser.add_argument("--replay-runs", type=int, default=32, help="runs replayed piece by piece (default 32, a campaign's sub-batch)")
    parser.add_argument("--lanes", type=int, default=8, help="lanes of the lane-loop test (default 8: AVX-512's doubles)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--argfile", help=argparse.SUPPRESS)
    parser.add_argument("--route", default="attribute", help=argparse.SUPPRESS)
    parser.add_argument("--vf", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child == "libmvec":
        print(json.dumps(child_libmvec(args.argfile, args.route, args.vf, args.repeats)))
        return
    if args.child == "lanes":
        print(json.dumps(child_lanes(args.argfile, args.repeats)))
        return

    import numpy as np

    load_before = os.getloadavg()
    result: dict[str, Any] = {"what": "issue 50 groundwork: a paper_montecarlo run-step's time by piece, vectorised libm, lane loops",
                              "command": " ".join(["nice -n 10 python benchmarks/bench_simd_probe.py", *sys.argv[1:]]),
                              "date": time.strftime("%Y-%m-%d %H:%M"), "machine": machine(),
                              "nice": os.nice(0), "load_average_before": list(load_before)}
    log("SVML state")
    result["svml"] = svml_state()
    log("the whole loop")
    result["loop"], sub, run = whole_loop(args.runs, args.replay_runs, args.repeats)
    log(f"the loop: {result['loop']['us_per_run_step_stride0']['median']:.3f} us a run-step; the pieces")
    result["pieces"], argset = pieces(sub, run, args.repeats)
    ns = {k: v["median"] for k, v in result["pieces"]["ns_per_call"].items()}
    loop0, loop1 = ns["loop_stride0"], ns["loop_stride1"]  # the replay runs' loop, timed in turn with the pieces
    sum0 = ns["controller_step"] + ns["propagate"] + ns["sample_verdicts"] + ns["table_reads"]
    result["budget_ns_per_run_step"] = {
        "loop_stride0": loop0, "loop_stride1": loop1, "record_cost_in_loop_stride1_minus_0": loop1 - loop0,
        "loop_note": "the replay runs through run_batch (one thread), no histories and every sample recorded, timed in turn with the pieces",
        "controller_step": ns["controller_step"], "propagate": ns["propagate"], "sample_verdicts": ns["sample_verdicts"],
        "table_reads": ns["table_reads"], "record_writes_alone": ns["record_writes"],
        "sum_of_pieces_stride0": sum0, "rest_of_loop_stride0": loop0 - sum0,
        "note": "each piece alone includes its replay's copy of the recorded state into its input (state_copy times that copy "
                "alone, with a sum to keep it); the rest is the loop's glue: status logic, isfinite checks, the published rows' copy, "
                "loop-carried scalars"}
    log("scalar libm costs")
    result["libm_scalar_cost"] = libm_scalar_cost(argset, args.repeats)
    cost = result["libm_scalar_cost"]
    calls = result["pieces"]["libm_per_run_step"]["calls"]
    est_thr = sum(calls[f]["per_run_step"] * cost[f]["ns_per_call_independent"]["median"] for f in LIBM)
    est_lat = sum(calls[f]["per_run_step"] * cost[f]["ns_per_call_dependent_chain"]["median"] for f in LIBM)
    result["budget_ns_per_run_step"]["libm_estimate_independent_calls"] = est_thr
    result["budget_ns_per_run_step"]["libm_estimate_dependent_chain"] = est_lat
    with tempfile.TemporaryDirectory(prefix="simd_probe_args_") as tmp:
        argfile = str(Path(tmp) / "args.npz")
        np.savez(argfile, **argset)
        result["libmvec"] = {}
        import llvmlite.binding as llvm

        no256 = {"NUMBA_CPU_FEATURES": llvm.get_host_cpu_features().flatten() + ",-prefer-256-bit"}  # the host's, less the 256-bit tuning
        for route, vf, env in (("veclib:LIBMVEC", 0, None), ("veclib:LIBMVEC-X86", 0, None), ("attribute-errno", 0, None), ("attribute", 0, None),
                               ("attribute", 8, None), ("attribute", 0, no256)):
            key = f"{route}_vf{vf or 'auto'}" + ("_cpu_features_minus_prefer_256_bit" if env else "")
            log(f"libmvec child: {key}")
            result["libmvec"][key] = run_child("libmvec", ["--route", route, "--vf", str(vf), "--repeats", str(args.repeats)], argfile,
                                               env_extra=env)
        W = min(args.lanes, sub.n_runs)
        lanefile = str(Path(tmp) / "lanes.npz")
        rec = run.record
        np.savez(lanefile, X=np.ascontiguousarray(rec.x[:W]), ref_q=sub.grid.ref_q, ref_w=sub.grid.ref_w, ref_wd=sub.grid.ref_wd,
                 t_ns=sub.grid.t_ns, prm=np.ascontiguousarray(sub.controller.prm[:W]), coef=np.ascontiguousarray(sub.controller.coef[:W]),
                 J=np.ascontiguousarray(sub.plant.J[:W]), J_inv=np.ascontiguousarray(sub.plant.J_inv[:W]),
                 U=np.ascontiguousarray(np.clip(rec.out[:W, :, 0, :3], -sub.actuator.max_torque_Nm, sub.actuator.max_torque_Nm)),
                 D=sub.disturbance.table, bounds=sub.controller.bounds, dt=sub.grid.dt, substeps=sub.plant.substeps,
                 umax=sub.actuator.max_torque_Nm, torque=np.ascontiguousarray(rec.out[:W, :, 0, :3]),
                 V1=np.ascontiguousarray(rec.out[:W, :, 9, 0]))
        log(f"lane-loop child: W = {W}")
        result["lane_loop"] = run_child("lanes", ["--repeats", str(args.repeats)], lanefile)
    result["projection"] = projection(result)
    result["load_average_after"] = list(os.getloadavg())
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

"""Plain numpy oracles of the plant models, for the tests only (not a product path).

The product computes every plant model through the compiled kernels
(:mod:`spacecraft_sim.core.kernels`); these are independent, readable transcriptions of the same
equations (the paper's and the module docstrings'), written without the kernels' operation order,
so a test compares the two to a few ulps, not bit for bit (except where no arithmetic is involved:
windows, draws).

Shapes: states (N, 7) ``(q_BN (x, y, z, w), omega_BN_B)``, torques (N, 3), inertia (3, 3) or
(N, 3, 3); times (T,); disturbances (T, N, 3).
"""

from __future__ import annotations

import numpy as np

TIME_TOLERANCE_S = 1e-9


# ----------------------------------------------------------------------------- rigid body


def _per_run(J: np.ndarray, n: int) -> np.ndarray:
    return np.broadcast_to(J, (n, 3, 3)) if J.ndim == 2 else J


def quat_times_vector(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``q ⊗ (w, 0)`` (Hamilton, scalar last), rows of (N, 4) and (N, 3)."""
    qv, q0 = q[:, :3], q[:, 3:]
    return np.concatenate((q0 * w + np.cross(qv, w), -np.sum(qv * w, axis=1, keepdims=True)), axis=1)


def derivative(x: np.ndarray, torque_B: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``dq/dt = 1/2 q ⊗ (omega, 0)``, ``J domega/dt = torque - omega × J omega``."""
    n = x.shape[0]
    Jn = _per_run(J, n)
    q, w = x[:, :4], x[:, 4:]
    Jw = np.einsum("nij,nj->ni", Jn, w)
    wdot = np.linalg.solve(Jn, (torque_B - np.cross(w, Jw))[..., None])[..., 0]
    return np.concatenate((0.5 * quat_times_vector(q, w), wdot), axis=1)


def rk4_step(x: np.ndarray, torque_B: np.ndarray, J: np.ndarray, dt: float) -> np.ndarray:
    """Classical RK4 with the torque held, then ``q`` projected onto the unit sphere."""
    k1 = derivative(x, torque_B, J)
    k2 = derivative(x + 0.5 * dt * k1, torque_B, J)
    k3 = derivative(x + 0.5 * dt * k2, torque_B, J)
    k4 = derivative(x + dt * k3, torque_B, J)
    y = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    y[:, :4] /= np.linalg.norm(y[:, :4], axis=1, keepdims=True)
    return y


def propagate(x: np.ndarray, torque_B: np.ndarray, J: np.ndarray, dt: float, substeps: int) -> np.ndarray:
    for _ in range(substeps):
        x = rk4_step(x, torque_B, J, dt / substeps)
    return x


# ----------------------------------------------------------------------------- reference


def reference_rates(t: np.ndarray, amplitude_deg_s: float = 0.573, periods_s: tuple[float, float, float] = (40.0, 30.0, 50.0)
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Sec. V.A: ``omega_d = A [cos(t/p0), sin(t/p1), -cos(t/p2)]`` and its time derivative, (T, 3)."""
    a = np.deg2rad(amplitude_deg_s)
    p0, p1, p2 = periods_s
    t = np.asarray(t, dtype=np.float64)
    w = a * np.stack((np.cos(t / p0), np.sin(t / p1), -np.cos(t / p2)), axis=-1)
    wd = a * np.stack((-np.sin(t / p0) / p0, np.cos(t / p1) / p1, np.sin(t / p2) / p2), axis=-1)
    return w, wd


# ----------------------------------------------------------------------------- disturbances


def paper_periodic(t: np.ndarray, omega_p: float = 0.01, scale: float | np.ndarray = 1.0, phase: float | np.ndarray = 0.0) -> np.ndarray:
    """The paper's disturbance (Sec. V.A), (T, N, 3) for per-run ``scale`` and ``phase`` (N,)."""
    scale = np.atleast_1d(np.asarray(scale, dtype=np.float64))
    phase = np.atleast_1d(np.asarray(phase, dtype=np.float64))
    wt = omega_p * np.asarray(t, dtype=np.float64)[:, None] + phase[None, :]
    d = 1e-3 * np.stack((
        4 * np.sin(3 * wt) + 3 * np.cos(10 * wt) - 20,
        -1.5 * np.sin(2 * wt) + 3 * np.cos(5 * wt) + 20,
        3 * np.sin(10 * wt) - 8 * np.cos(4 * wt) + 20,
    ), axis=-1)
    return scale[None, :, None] * d


def window(t: np.ndarray, start_s: float, end_s: float, torque_Nm: tuple[float, float, float]) -> np.ndarray:
    """``torque_Nm`` on ``start <= t < end`` (tolerance ``TIME_TOLERANCE_S``), (T, 1, 3)."""
    on = (np.asarray(t) >= start_s - TIME_TOLERANCE_S) & (np.asarray(t) < end_s - TIME_TOLERANCE_S)
    return on[:, None, None] * np.asarray(torque_Nm, dtype=np.float64)


def random_torque(t: np.ndarray, sigma_Nm: tuple[float, float, float], hold_s: float, seeds: list[int]) -> np.ndarray:
    """Window ``k = floor(t / hold)`` of run ``n`` draws ``default_rng([seed_n, k]).standard_normal(3)``
    times sigma, (T, N, 3)."""
    out = np.empty((np.size(t), len(seeds), 3))
    for i, tt in enumerate(np.asarray(t, dtype=np.float64)):
        k = int(np.floor(tt / hold_s + TIME_TOLERANCE_S / hold_s))
        for n, s in enumerate(seeds):
            out[i, n] = np.random.default_rng([s, k]).standard_normal(3) * np.asarray(sigma_Nm)
    return out


# ----------------------------------------------------------------------------- reference


def reference_quaternions_dop853(t: np.ndarray, q0: np.ndarray, amplitude_deg_s: float, periods_s: tuple[float, float, float],
                                 rtol: float = 1e-12, atol: float = 1e-14) -> np.ndarray:
    """``q_RN`` (T, 4) on ``t`` by scipy's adaptive DOP853, normalised at the samples.

    With the default tolerances this is the reference the numpy core used when the golden data
    of ``tests/data/`` were recorded (``solve_ivp(..., method="DOP853", t_eval=t, rtol=1e-12,
    atol=1e-14)``); with tighter ones, an accurate solution to measure the product's integrator
    against.  scipy's steps go through BLAS (``np.dot``), so its last bits depend on the OpenBLAS
    kernel the host picks (docs/parity.md): an oracle, not a product path."""
    from scipy.integrate import solve_ivp

    def rhs(tt: float, q: np.ndarray) -> np.ndarray:
        w = reference_rates(np.array([tt]), amplitude_deg_s, periods_s)[0][0]
        return 0.5 * quat_times_vector(q[None], w[None])[0]

    sol = solve_ivp(rhs, (0.0, float(t[-1])), np.asarray(q0, dtype=np.float64), method="DOP853", t_eval=t, rtol=rtol, atol=atol)
    q = sol.y.T
    return np.asarray(q / np.linalg.norm(q, axis=1, keepdims=True))

"""A plain numpy MEKF, for the tests only (not a product path): ``docs/estimator.md`` transcribed.

The product's filter is one compiled kernel (:func:`sappc_estimator.core.mekf.mekf_step`); this
is an independent transcription of the specification page, written for clarity, not speed, and
deliberately by other routes where the page allows one:

* ``Φ = expm(F h)`` of the 6x6 ``F = [[-[w×], -I], [0, 0]]``, not the closed form M&C eq. 6.83
  the kernel evaluates: :func:`expm` below, the Taylor series summed to convergence with scaling
  and squaring (checked against :func:`scipy.linalg.expm` in the tests; scipy's own is not called
  a step because its OpenBLAS threads make it ~3 ms a call on a loaded 2-core host);
* ``Qd`` built per axis as 2x2 blocks (M&C eq. 6.93) and scattered into a 6x6 matrix;
* the Joseph form with full 6x6 numpy matrices and ``H = [I 0]`` written out, ``S⁻¹`` by
  :func:`numpy.linalg.inv` and the NIS by :func:`numpy.linalg.solve`;
* ``dq`` and ``rotvec`` as the page states them (their agreement with
  :class:`scipy.spatial.transform.Rotation` is itself tested).

Quaternions are scalar last ``(x, y, z, w)``, Hamilton product; ``q = q_BN``.

The filter's statuses are the strings of :data:`STATUS` (same order as the kernel's
``STATUS_NAMES``, so that ``STATUS.index(name)`` is the kernel's code).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Status names, in the order of the kernel's codes (``STATUS_NONE`` = 0 ...).
STATUS = ("none", "initialised", "propagated", "updated", "rejected", "reinitialised")


# ----------------------------------------------------------------------------- quaternions


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (scalar last): ``(p0 q_v + q0 p_v + p_v × q_v, p0 q0 - p_v·q_v)``."""
    pv, p0 = p[:3], p[3]
    qv, q0 = q[:3], q[3]
    return np.concatenate((p0 * qv + q0 * pv + skew(pv) @ qv, [p0 * q0 - pv @ qv]))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """``q*``: the vector part negated."""
    return np.array([-q[0], -q[1], -q[2], q[3]])


def normalise(q: np.ndarray) -> np.ndarray:
    """``q / |q|``."""
    return q / np.linalg.norm(q)


def dq(r: np.ndarray) -> np.ndarray:
    """The unit quaternion of the rotation vector ``r`` [rad]: ``(sin(|r|/2) r/|r|, cos(|r|/2))``,
    ``(0, 0, 0, 1)`` for ``r = 0``."""
    r = np.asarray(r, dtype=np.float64)
    angle = np.linalg.norm(r)
    if angle == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.concatenate((np.sin(angle / 2.0) * r / angle, [np.cos(angle / 2.0)]))


def rotvec(q: np.ndarray) -> np.ndarray:
    """The rotation vector [rad] of the shortest rotation of the unit quaternion ``q``: with
    ``s = sign(q_w)`` (+1 at ``q_w = 0``) and ``v = s q_v``, ``2 atan2(|v|, s q_w) v / |v|``,
    and ``2 v / (s q_w)`` when ``|v| = 0``."""
    s = 1.0 if q[3] >= 0.0 else -1.0
    v = s * np.asarray(q[:3], dtype=np.float64)
    n = np.linalg.norm(v)
    if n == 0.0:
        return 2.0 * v / (s * q[3])
    return 2.0 * np.arctan2(n, s * q[3]) * v / n


def skew(w: np.ndarray) -> np.ndarray:
    """``[w×]``, the cross-product matrix: ``skew(w) @ u = w × u``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def attitude_error(q_hat: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """The true attitude error of an estimate, ``rotvec(q_hat* ⊗ q_true)`` [rad] (body frame):
    the ``a`` of ``q_true = q_hat ⊗ dq(a)``."""
    return rotvec(quat_multiply(quat_conjugate(q_hat), q_true))


# ----------------------------------------------------------------------------- the filter's matrices


def expm(A: np.ndarray) -> np.ndarray:
    """The matrix exponential ``sum_k A^k / k!``: ``A`` scaled by ``2^-s`` to a 1-norm <= 1/2, the
    series summed until a term no longer changes the sum, then squared ``s`` times."""
    norm = np.max(np.sum(np.abs(A), axis=0))
    s = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.0 else 0
    B = A / 2.0**s
    total = np.eye(A.shape[0])
    term = np.eye(A.shape[0])
    for k in range(1, 40):
        term = term @ B / k
        if not np.any(np.abs(term) > np.finfo(float).eps * np.abs(total)):
            break
        total = total + term
    for _ in range(s):
        total = total @ total
    return total


def transition(w_rad_s: np.ndarray, h_s: float) -> np.ndarray:
    """``Φ = expm(F h)``, ``F = [[-[w×], -I], [0, 0]]`` (6x6): the error state's transition over
    ``h`` at the constant rate ``w`` (M&C 6.2.2)."""
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(w_rad_s)
    F[:3, 3:] = -np.eye(3)
    return expm(F * h_s)


def process_noise(sv2: np.ndarray, su2: np.ndarray, h_s: float) -> np.ndarray:
    """``Qd`` (6x6), M&C eq. 6.93 per axis ``i``: the 2x2 block
    ``[[σv² h + σu² h³/3, -σu² h²/2], [-σu² h²/2, σu² h]]`` on the rows/columns ``(a_i, b_i)``."""
    Q = np.zeros((6, 6))
    for i in range(3):
        a, b = i, 3 + i
        Q[a, a] = sv2[i] * h_s + su2[i] * h_s**3 / 3.0
        Q[a, b] = Q[b, a] = -su2[i] * h_s**2 / 2.0
        Q[b, b] = su2[i] * h_s
    return Q


# ----------------------------------------------------------------------------- the filter


@dataclass
class Output:
    """One step's outputs (``None`` before initialisation, the status always)."""

    status: str
    q_hat: np.ndarray | None = None
    omega_hat: np.ndarray | None = None
    b_hat: np.ndarray | None = None
    sigma: np.ndarray | None = None
    nis: float | None = None
    monitor_level: int | None = None
    usable: bool | None = None
    recoveries: int | None = None
    monitor_nis_sum: float | None = None  # the window's NIS sum at the last verdict (NaN before one)
    monitor_mean: float | None = None  # and its mean statistic
    monitor_drift: float | None = None  # the drift test's statistic (the largest CUSUM)


@dataclass
class MekfOracle:
    """``docs/estimator.md``'s filter, one :meth:`step` per sample.

    Parameters
    ----------
    R_rad2 : (3,) tracker noise variance per body axis [rad²].
    sv2_rad2_s : (3,) ``σ_v²``, the gyro's angle random walk squared [rad²/s].
    su2_rad2_s3 : (3,) ``σ_u²``, the bias random walk squared [rad²/s³].
    P0a_rad2, P0b_rad2_s2 : (3,) the initial attitude [rad²] and bias [rad²/s²] variances.
    b0_rad_s : (3,) the initial bias estimate [rad/s].
    gate : threshold on the NIS (``inf``: no gate).
    max_rejections : consecutive rejections that re-initialise the attitude (>= 1).
    init : ``"from_tracker"`` or ``"from_prior"``; q_prior : (4,) used with ``"from_prior"``.
    max_norm_error, max_rate : the plausibility bounds of step 0 (norm error, rate [rad/s]).
    nis_initial : the "last NIS" before any update (the page does not state it; the caller
        passes the kernel's ``new_state()`` value, see the test module).
    window : the health monitor's window [compared samples]; nis_band : (4,) its NIS-sum bounds
        (error low, warning low, warning high, error high); mean_bounds : (2,) the mean test's
        (warning, error); recovery_rad2_s2 : (3,) the bias covariance a recovery adds;
        persistence : verdicts in a row outside the error band that fail the monitor;
        drift_reference, drift_threshold : the drift test's CUSUM reference value and threshold
        [innovation sigmas] (``inf``: no drift test).
    """

    R_rad2: np.ndarray
    sv2_rad2_s: np.ndarray
    su2_rad2_s3: np.ndarray
    P0a_rad2: np.ndarray
    P0b_rad2_s2: np.ndarray
    b0_rad_s: np.ndarray
    gate: float
    max_rejections: int
    init: str = "from_tracker"
    q_prior: np.ndarray | None = None
    max_norm_error: float = 1e-6
    max_rate: float = 10.0
    nis_initial: float = float("nan")
    window: int = 20
    nis_band: tuple[float, float, float, float] = (0.0, 0.0, float("inf"), float("inf"))
    mean_bounds: tuple[float, float] = (float("inf"), float("inf"))
    recovery_rad2_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    persistence: int = 1
    drift_reference: float = 0.5
    drift_threshold: float = float("inf")
    # filter state between steps
    initialised: bool = False
    q_hat: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))
    b_hat: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    P: np.ndarray = field(default_factory=lambda: np.full((6, 6), np.nan))
    omega_prev: np.ndarray | None = None
    t_prev: float | None = None
    provisional: bool = False
    n_updates: int = 0
    n_rejections: int = 0
    n_consecutive: int = 0
    n_reinit: int = 0
    nis: float = float("nan")
    epoch: float = float("-inf")  # the epoch of the last tracker sample used
    confirmed: bool = False
    monitor: list[tuple[float, float, np.ndarray]] = field(default_factory=list)  # (t, NIS, whitened innovation), oldest first
    level: int = 0
    fails: int = 0
    outside: int = 0  # verdicts in a row outside the error band
    cusum_up: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the drift test's CUSUMs, upward per component
    cusum_down: np.ndarray = field(default_factory=lambda: np.zeros(3))  # and downward
    n_recover: int = 0
    n_drift: int = 0  # failed monitors the drift test started
    verdict_nis_sum: float = float("nan")  # the last verdict's figures (kept through a re-initialisation)
    verdict_mean: float = float("nan")

    def __post_init__(self) -> None:
        for name in ("R_rad2", "sv2_rad2_s", "su2_rad2_s3", "P0a_rad2", "P0b_rad2_s2", "b0_rad_s"):
            setattr(self, name, np.array(getattr(self, name), dtype=np.float64).reshape(3))
        if self.init not in ("from_tracker", "from_prior"):
            raise ValueError(f"init must be from_tracker or from_prior, got {self.init!r}")
        self.nis = self.nis_initial

    @classmethod
    def from_params(cls, prm: np.ndarray, nis_initial: float = float("nan")) -> MekfOracle:
        """The oracle of the kernel's parameter array (its documented ``EP_*`` layout)."""
        from sappc_estimator.core import mekf

        def three(c: int) -> np.ndarray:
            return np.array(prm[c:c + 3], dtype=np.float64)

        init = "from_tracker" if int(prm[mekf.EP_INIT]) == mekf.INIT_FROM_TRACKER else "from_prior"
        return cls(R_rad2=three(mekf.EP_R), sv2_rad2_s=three(mekf.EP_SV2), su2_rad2_s3=three(mekf.EP_SU2),
                   P0a_rad2=three(mekf.EP_P0A), P0b_rad2_s2=three(mekf.EP_P0B), b0_rad_s=three(mekf.EP_B0),
                   gate=float(prm[mekf.EP_GATE]), max_rejections=int(prm[mekf.EP_MAXREJ]), init=init,
                   q_prior=np.array(prm[mekf.EP_Q0:mekf.EP_Q0 + 4], dtype=np.float64), nis_initial=nis_initial,
                   max_norm_error=float(prm[mekf.EP_MAX_NORM_ERR]), max_rate=float(prm[mekf.EP_MAX_RATE]),
                   window=int(prm[mekf.EP_MON_WINDOW]), nis_band=tuple(float(v) for v in prm[mekf.EP_MON_NIS:mekf.EP_MON_NIS + 4]),
                   mean_bounds=(float(prm[mekf.EP_MON_MEAN]), float(prm[mekf.EP_MON_MEAN + 1])), recovery_rad2_s2=three(mekf.EP_RECOVERY_PBB),
                   persistence=int(prm[mekf.EP_MON_PERSIST]), drift_reference=float(prm[mekf.EP_MON_DRIFT]),
                   drift_threshold=float(prm[mekf.EP_MON_DRIFT + 1]))

    # -- the page's steps ------------------------------------------------------------------

    def _initialise(self, q: np.ndarray) -> None:
        self.q_hat = np.array(q, dtype=np.float64)
        self.b_hat = self.b0_rad_s.copy()
        self.P = np.diag(np.concatenate((self.P0a_rad2, self.P0b_rad2_s2)))
        self.initialised = True

    def _reinitialise_attitude(self, q_meas: np.ndarray) -> None:
        """The page's "re-initialising the attitude": q_hat = the sample, P_aa = R, P_ab = 0."""
        self.q_hat = np.array(q_meas, dtype=np.float64)
        self.P[:3, :] = 0.0
        self.P[:, :3] = 0.0
        self.P[:3, :3] = np.diag(self.R_rad2)

    def _propagate(self, h: float, omega_meas: np.ndarray) -> None:
        assert self.omega_prev is not None
        w = (self.omega_prev + omega_meas) / 2.0 - self.b_hat
        self.q_hat = normalise(quat_multiply(self.q_hat, dq(w * h)))
        Phi = transition(w, h)
        P = Phi @ self.P @ Phi.T + process_noise(self.sv2_rad2_s, self.su2_rad2_s3, h)
        self.P = (P + P.T) / 2.0

    def _inflate(self, age_s: float, axes: np.ndarray | None = None) -> None:
        """The recovery: a bias step of covariance Q = diag(recovery) ``age_s`` ago, carried to now
        through Phi12 = -I age: P += [[Q age², -Q age], [-Q age, Q]]; about the ``axes`` (3 bools;
        ``None``: every axis) only, Q's other entries 0."""
        Q = np.diag(self.recovery_rad2_s2 * (1.0 if axes is None else axes))
        G = np.vstack((-age_s * np.eye(3), np.eye(3)))  # (6, 3): how a bias step then shows now
        self.P = self.P + G @ Q @ G.T

    def _reinitialise_after_failure(self, q_meas: np.ndarray) -> None:
        """A lost attitude: re-initialised from the sample, the bias kept, its covariance inflated,
        the monitor's window emptied, the estimate unconfirmed."""
        self._reinitialise_attitude(q_meas)
        self._inflate(0.0)
        self._empty_monitor()
        self.fails = 0
        self.level = 1
        self.confirmed = False
        self.n_reinit += 1

    def _empty_monitor(self) -> None:
        """The window emptied, its count of verdicts outside reset, the CUSUMs back to 0."""
        self.monitor = []
        self.outside = 0
        self.cusum_up = np.zeros(3)
        self.cusum_down = np.zeros(3)

    @property
    def drift(self) -> float:
        """The drift test's statistic: the largest of its six CUSUMs."""
        return float(max(np.max(self.cusum_up), np.max(self.cusum_down)))

    def _monitor(self, t_s: float, q_meas: np.ndarray, white: np.ndarray, status: str) -> str:
        self.monitor.append((t_s, self.nis, white))
        self.monitor = self.monitor[-self.window:]
        # the drift test: Page's CUSUM per component and sign, g <- max(0, g +- w - k)
        self.cusum_up = np.maximum(0.0, self.cusum_up + white - self.drift_reference)
        self.cusum_down = np.maximum(0.0, self.cusum_down - white - self.drift_reference)
        drifted = self.drift > self.drift_threshold
        full = len(self.monitor) == self.window
        if not (full or drifted):
            return status
        too_large = failed = False
        if full:
            nis_sum = sum(m[1] for m in self.monitor)
            total = np.sum([m[2] for m in self.monitor], axis=0)
            mean = float(total @ total) / self.window
            self.verdict_nis_sum, self.verdict_mean = float(nis_sum), mean
            err_lo, warn_lo, warn_hi, err_hi = self.nis_band
            too_large = nis_sum > err_hi or mean > self.mean_bounds[1]
            outside = too_large or nis_sum < err_lo
            self.outside = self.outside + 1 if outside else 0
            failed = self.outside >= self.persistence
            self.level = 2 if failed else 1 if (outside or nis_sum < warn_lo or nis_sum > warn_hi or mean > self.mean_bounds[0]) else 0
            if not too_large:
                self.fails = 0
        if drifted:
            self.level = 2
            self.n_drift += 1
        elif not (too_large and failed):
            return status
        self.fails += 1
        if self.fails >= 2:
            self._reinitialise_after_failure(q_meas)
            self.n_consecutive = 0
            return "reinitialised"
        # the window failed: a step about any axis; the drift test alone: about the axes whose CUSUM passed its threshold
        axes = None if (too_large and failed) else np.maximum(self.cusum_up, self.cusum_down) > self.drift_threshold
        self._inflate(t_s - self.monitor[0][0], axes)
        self._empty_monitor()
        self.n_recover += 1
        return status

    def _update(self, q_meas: np.ndarray, t_s: float) -> str:
        r = rotvec(quat_multiply(quat_conjugate(self.q_hat), q_meas))
        R = np.diag(self.R_rad2)
        S = self.P[:3, :3] + R
        self.nis = float(r @ np.linalg.solve(S, r))
        white = np.linalg.solve(np.linalg.cholesky(S), r)  # L^-1 r, S = L L^T
        if not self.nis <= self.gate:
            self.n_rejections += 1
            self.n_consecutive += 1
            if self.max_rejections >= 1 and self.n_consecutive >= self.max_rejections:
                self._reinitialise_after_failure(q_meas)
                self.n_consecutive = 0
                return "reinitialised"
            return "rejected"
        H = np.hstack((np.eye(3), np.zeros((3, 3))))
        K = self.P @ H.T @ np.linalg.inv(S)
        IKH = np.eye(6) - K @ H
        P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.P = (P + P.T) / 2.0
        dx = K @ r
        self.q_hat = normalise(quat_multiply(self.q_hat, dq(dx[:3])))
        self.b_hat = self.b_hat + dx[3:]
        self.n_updates += 1
        self.n_consecutive = 0
        self.confirmed = True
        return self._monitor(t_s, q_meas, white, "updated")

    def step(self, t_s: float, q_meas: np.ndarray, omega_meas: np.ndarray, epoch_s: float | None = None) -> Output:
        """One step at time ``t_s`` [s] with the tracker's quaternion ``q_meas`` (4,), measured at
        ``epoch_s`` [s] (``None``: at ``t_s``), and the gyro's rate ``omega_meas`` (3,) [rad/s];
        returns the outputs (page, step 6)."""
        q_meas = np.asarray(q_meas, dtype=np.float64)
        omega_meas = np.asarray(omega_meas, dtype=np.float64)
        epoch = float(t_s if epoch_s is None else epoch_s)
        # 0. no measurement: nothing changes, no output
        if not (abs(np.linalg.norm(q_meas) - 1.0) <= self.max_norm_error and np.linalg.norm(omega_meas) <= self.max_rate
                and epoch <= t_s):
            return Output("none")  # a NaN fails the comparisons too
        # 1. a new tracker sample: one of a later epoch than the last used
        new = epoch > self.epoch
        if not self.initialised:
            # 2. initialisation
            status = "initialised"
            if self.init == "from_tracker":
                self._initialise(q_meas)
                self.provisional = epoch < t_s
                self.confirmed = True  # a tracker measurement, held at most one period
            else:
                assert self.q_prior is not None
                self._initialise(self.q_prior)
                status = self._update(q_meas, t_s)
        else:
            # 3. propagation, then the provisional attitude replaced or 4. the update with a new sample
            assert self.t_prev is not None
            self._propagate(t_s - self.t_prev, omega_meas)
            status = "propagated"
            if new and self.provisional:
                self._reinitialise_attitude(q_meas)
                self.provisional = False
                self.confirmed = True
                status = "initialised"
            elif new:
                status = self._update(q_meas, t_s)
        # 5. remember
        if new:
            self.epoch = epoch
        self.omega_prev = omega_meas.copy()
        self.t_prev = float(t_s)
        # 6. outputs
        if not self.initialised:
            return Output(status)
        return Output(status, q_hat=self.q_hat.copy(), omega_hat=omega_meas - self.b_hat, b_hat=self.b_hat.copy(),
                      sigma=np.sqrt(np.diag(self.P)), nis=self.nis, monitor_level=self.level, usable=self.confirmed,
                      recoveries=self.n_recover, monitor_nis_sum=self.verdict_nis_sum, monitor_mean=self.verdict_mean,
                      monitor_drift=self.drift)

    @property
    def counters(self) -> tuple[int, int, int, int, int]:
        """(updates, rejections, consecutive rejections, re-initialisations, drift alarms)."""
        return (self.n_updates, self.n_rejections, self.n_consecutive, self.n_reinit, self.n_drift)

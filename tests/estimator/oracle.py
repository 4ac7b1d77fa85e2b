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
    # filter state between steps
    initialised: bool = False
    q_hat: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))
    b_hat: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    P: np.ndarray = field(default_factory=lambda: np.full((6, 6), np.nan))
    q_prev: np.ndarray | None = None
    omega_prev: np.ndarray | None = None
    t_prev: float | None = None
    seen: bool = False
    provisional: bool = False
    n_updates: int = 0
    n_rejections: int = 0
    n_consecutive: int = 0
    n_reinit: int = 0
    nis: float = float("nan")

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
                   max_norm_error=float(prm[mekf.EP_MAX_NORM_ERR]), max_rate=float(prm[mekf.EP_MAX_RATE]))

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

    def _update(self, q_meas: np.ndarray) -> str:
        r = rotvec(quat_multiply(quat_conjugate(self.q_hat), q_meas))
        R = np.diag(self.R_rad2)
        S = self.P[:3, :3] + R
        self.nis = float(r @ np.linalg.solve(S, r))
        if not self.nis <= self.gate:
            self.n_rejections += 1
            self.n_consecutive += 1
            if self.max_rejections >= 1 and self.n_consecutive >= self.max_rejections:
                self._reinitialise_attitude(q_meas)
                self.n_consecutive = 0
                self.n_reinit += 1
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
        return "updated"

    def step(self, t_s: float, q_meas: np.ndarray, omega_meas: np.ndarray) -> Output:
        """One step at time ``t_s`` [s] with the tracker's quaternion ``q_meas`` (4,) and the gyro's
        rate ``omega_meas`` (3,) [rad/s]; returns the outputs (page, step 6)."""
        q_meas = np.asarray(q_meas, dtype=np.float64)
        omega_meas = np.asarray(omega_meas, dtype=np.float64)
        # 0. no measurement: nothing changes, no output
        if not (abs(np.linalg.norm(q_meas) - 1.0) <= self.max_norm_error and np.linalg.norm(omega_meas) <= self.max_rate):
            return Output("none")  # a NaN fails the comparisons too
        # 1. a new tracker sample: the first step's, or one differing in any component
        assert self.q_prev is not None or not self.seen
        new = (not self.seen) or bool(np.any(q_meas != self.q_prev))
        if not self.initialised:
            # 2. initialisation
            status = "initialised"
            if self.init == "from_tracker":
                self._initialise(q_meas)
                self.provisional = True
            else:
                assert self.q_prior is not None
                self._initialise(self.q_prior)
                status = self._update(q_meas)
        else:
            # 3. propagation, then the provisional attitude replaced or 4. the update with a new sample
            assert self.t_prev is not None
            self._propagate(t_s - self.t_prev, omega_meas)
            status = "propagated"
            if new and self.provisional:
                self._reinitialise_attitude(q_meas)
                self.provisional = False
                status = "initialised"
            elif new:
                status = self._update(q_meas)
        # 5. remember
        self.q_prev = q_meas.copy()
        self.omega_prev = omega_meas.copy()
        self.t_prev = float(t_s)
        self.seen = True
        # 6. outputs
        if not self.initialised:
            return Output(status)
        return Output(status, q_hat=self.q_hat.copy(), omega_hat=omega_meas - self.b_hat, b_hat=self.b_hat.copy(),
                      sigma=np.sqrt(np.diag(self.P)), nis=self.nis)

    @property
    def counters(self) -> tuple[int, int, int, int]:
        """(updates, rejections, consecutive rejections, re-initialisations)."""
        return (self.n_updates, self.n_rejections, self.n_consecutive, self.n_reinit)

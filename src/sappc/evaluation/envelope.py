"""The figures of a long run from a bounded history (issue 47; docs/design/streaming.md, item 3).

:class:`HistoryEnvelope` is fed a run's record a block at a time (each block a
:class:`~sappc.evaluation.history.History` of the next samples, views of a reused buffer are
fine: it copies what it keeps) and gives back a History that
:func:`sappc.analysis.plots.plot_run` draws as it draws any History:

- A run of at most ``full_rate_max_samples`` samples (:data:`FULL_RATE_MAX_SAMPLES`) is kept
  whole: :meth:`HistoryEnvelope.history` is the run's History, every array equal (its figures are
  the files the full record gives).
- A longer one is cut into time bins fixed up front from the run's span (:data:`ENVELOPE_BINS`
  of them over the zoom window ``[zoom_from_s, t_end_s]``, as many again before it); in each bin,
  for every series a figure draws and each of its components, the sample of least value and the
  sample of greatest value (the first one on a tie) are kept, each at its own time.  The History
  given back is the union of those samples in time order (a sample that is the extreme of several
  series, or both of one, is there once): every row is a sample of the run, whole (its time and
  every field's value at that time), so a one-sample spike anywhere in the record is in the
  figure's data at its time and value, and a line through the rows draws, in each bin, the
  series' whole range.  The figures need no change: ``plot_run`` draws lines through these rows
  as through a full record.  The result does not depend on how the record was cut into blocks.

The series that select samples are the ones the figures draw (``plot_run``, ``plot_estimator``,
``plot_wheels``, ``plot_compare``), each as the figure computes it:

==========================  ==================================================================
field                       the values whose least and greatest samples are kept in each bin
==========================  ==================================================================
``q_BR``                    ``q_ev = q_BR[..., :3]``: least and greatest ``q_ev_i``, and least
                            ``|q_ev_i|`` (``qev_log`` draws ``|q_ev_i|``; its greatest is one of
                            the two extremes).  The quaternion's scalar part is not drawn: it
                            selects nothing.  Every kept row is a whole sample, so each kept
                            quaternion is the run's own, unit norm as recorded (no component is
                            taken from another sample).
``rho``                     least and greatest ``rho_i`` and least ``|rho_i|`` (as ``q_ev``).
``band_lower/upper``        least and greatest of each (the band's outer and inner edges).
``torque_B``, ``eps``       least and greatest of each component.
``V``                       least and greatest ``|V_i|`` (drawn on a log axis as ``|V_i|``).
wheels                      least and greatest of each wheel's speed and motor torque; with
                            ``wheels`` given (``W`` matching), of each component of the torque not
                            delivered ``tau + G u`` (the third panel of ``wheels.png``).
``estimate``                the attitude estimation error
                            (:func:`~sappc.evaluation.estimation.attitude_errors` of
                            ``estimate.q_BN`` and ``q_BN``), the bias error ``gyro_bias_true -
                            gyro_bias`` (when recorded), each ``|P_ii|`` (the figures draw
                            ``3 sqrt(|P_ii|)``, monotonic in it) and the NIS: least and greatest.
                            ``estimator_nis.png`` puts a dot at each sample whose NIS differs from
                            the sample before: on an envelope, each bin's least and greatest NIS
                            (and the NIS at the other kept samples), not every tracker update.
==========================  ==================================================================

The other fields select nothing (no figure reads them) and are carried at the kept samples, each
at its exact value there: ``omega_BN_B``, ``torque_cmd_B``, ``disturbance_B``, ``z``, ``q_BN``
(read only through the estimation error), the flags ``saturated`` (bool) and the integer codes
(``estimate.status`` int8, ``monitor_level``, ``usable``, ``recoveries``: a flag or a code set only
between kept samples is not in the envelope; the metrics count those, not the figures), the
estimator's rate estimate and monitor sum, and ``orbit`` (the fields and the rods' dipoles: not
drawn).  The covariance (T, N, 6, 6) keeps only what the figures read, its diagonal: the
envelope's covariance has the kept samples' diagonals and NaN off the diagonal (it is for the
figures, not for a NEES).

Non-finite values: a NaN (no value there: before the filter's first estimate, before the law's
first valid sample, after a loss of control) is never a bin's extreme while the bin has a number;
a bin that has none keeps its first sample, so a line has its gap there.  ``inf`` is a value: the
greatest (or least) there is.

The zoom figure (``qev_zoom`` draws from ``zoom_from_s`` on, its view set by that window's
extremes; ``qev_log`` draws the whole run): the bins are two grids, ``bins`` bins over
``[t_start_s, zoom_from_s)`` and ``bins`` over ``[zoom_from_s, t_end_s]``, so the zoom window always
has its ``bins`` bins whatever the run's length, no bin straddles its start (the zoom's mask takes
whole bins: its extremes and its view are the record's), and the transient before it is kept at
full rate where its samples are fewer than the bins (15 s at 100 Hz: 1500 samples in 1000 bins of
15 ms).  A run whose span does not hold ``zoom_from_s`` has one grid of ``bins`` bins.

Memory: at most ``2 bins`` bins of at most ``C`` rows each (:attr:`HistoryEnvelope.max_rows`;
``C`` the drawn components' least and greatest, 96 with four wheels, the estimator and the
orbit), whatever the run's duration.  A bin of smooth series keeps two or three rows (their
extremes at its ends); of noisy ones, more: the 30 min of ``paper_tracking_orbit`` (wheels, the
MEKF, the orbit; 670 bytes a row) keep 42 rows a bin after the zoom's start (bins of 180
samples), the same samples in the bins of a 6 h run 53 a bin, in those of 7 days 63 a bin: about
65,000 rows, some 45 MB (and the buffer's spare room, at most a quarter more) for a week's run.
Blocks are binned :data:`CHUNK_SAMPLES` samples at a time (the temporaries of the
selection are bounded by that, not by the block).  Use::

    env = HistoryEnvelope(t_end_s, wheels=scenario.wheels)
    for block in blocks:        # History of samples k .. k + B - 1 (t: those samples' times)
        env.add(block)
    plot_run(env.history(), out_dir, title=...)
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sappc.evaluation.estimation import N_ERROR_STATES, EstimateHistory, attitude_errors
from sappc.evaluation.history import History

if TYPE_CHECKING:
    from spacecraft_sim.core.wheels import ReactionWheels

__all__ = ["CHUNK_SAMPLES", "ENVELOPE_BINS", "FULL_RATE_MAX_SAMPLES", "HistoryEnvelope", "ZOOM_FROM_S"]

Array = NDArray[np.float64]

#: Bins of each of the envelope's two time grids (before the zoom window and over it).  The
#: figures are 8 in wide at 110 dpi, about 750 pixel columns of data: 1000 bins is more than one
#: bin a column, so each column holds its bins' least and greatest samples and a line through them
#: covers the column's range as the full-rate line does; a curve then has at most 2000 points a
#: grid (its own extremes) and the other series' rows.
ENVELOPE_BINS = 1000

#: Runs of at most this many samples are kept whole (their figures are the full record's files).
#: The paper's 60 s experiments are 6001 samples at 100 Hz; this keeps up to 200 s at 100 Hz (or
#: 60 s at 333 Hz) whole.  Below it an envelope would save nothing: 20001 whole samples (about 20
#: MB with the estimator and the orbit, the covariance whole) are less than the envelope of a long
#: run of the orbit scenario holds (some 45 MB: module docstring), and a run of fewer samples has
#: under ten samples a bin of the 2000, most of which some drawn component's extreme keeps anyway.
FULL_RATE_MAX_SAMPLES = 20001

#: Where the zoom window starts [s]: :func:`sappc.analysis.plots.plot_run`'s ``zoom_from_s``
#: (the paper's steady state from 15 s); a test checks they agree.
ZOOM_FROM_S = 15.0

#: Samples of a block binned at once: the selection's temporaries are a few (CHUNK_SAMPLES, C)
#: arrays (C about 100: some 6 MB each), whatever the block's size (the offline driver's are
#: 65536 samples).
CHUNK_SAMPLES = 8192

#: Key of the covariance's diagonal in the kept rows (the envelope keeps only the diagonal).
_COV = "estimate.covariance"


class HistoryEnvelope:
    """The bounded History of a run fed block by block (module docstring).

    ``t_end_s``: the time of the run's last sample (or its planned end), ``t_start_s`` its first
    [s]: the bins are fixed from them up front (a sample outside falls in the first or last bin).
    ``zoom_from_s``: where the zoom figures start (``plot_run``'s argument of that name).
    ``bins``: bins of each grid.  ``full_rate_max_samples``: a run of at most that many samples is
    kept whole.  ``wheels``: the wheel set, for the extremes of the torque it did not deliver (as
    ``plot_run``'s ``wheels``; ``None``: that series selects nothing).  With N runs (a
    campaign's sub-batch), the extremes of every run's components are kept (their union).

    :meth:`add` takes the next block, :meth:`history` gives the History to draw (it may be called
    again after more blocks)."""

    def __init__(self, t_end_s: float, *, t_start_s: float = 0.0, zoom_from_s: float = ZOOM_FROM_S, bins: int = ENVELOPE_BINS,
                 full_rate_max_samples: int = FULL_RATE_MAX_SAMPLES, wheels: ReactionWheels | None = None) -> None:
        if not (math.isfinite(t_start_s) and math.isfinite(t_end_s) and t_end_s > t_start_s):
            raise ValueError(f"the run's span must be finite and positive: t_start_s {t_start_s!r}, t_end_s {t_end_s!r}")
        if bins < 1 or full_rate_max_samples < 0:
            raise ValueError(f"bins must be >= 1 and full_rate_max_samples >= 0, got {bins!r}, {full_rate_max_samples!r}")
        self.t_start_s, self.t_end_s, self.zoom_from_s = float(t_start_s), float(t_end_s), float(zoom_from_s)
        self.bins_per_grid, self.full_rate_max_samples = int(bins), int(full_rate_max_samples)
        # (first time [s], bin width [s]) of each grid; grid g's bins are g * bins .. (g + 1) * bins - 1
        if self.t_start_s < self.zoom_from_s < self.t_end_s:
            self._grids = [(self.t_start_s, (self.zoom_from_s - self.t_start_s) / bins),
                           (self.zoom_from_s, (self.t_end_s - self.zoom_from_s) / bins)]
        else:
            self._grids = [(self.t_start_s, (self.t_end_s - self.t_start_s) / bins)]
        self._G = None if wheels is None else np.asarray(wheels.G, dtype=np.float64)
        self._samples = 0
        self._t_last = -math.inf
        self._layout: tuple[Any, ...] | None = None  # which optional fields the run has, and N
        self._blocks: list[History] | None = []  # the whole run while it is short enough; None once binned
        self._kept = _Rows()  # the rows of the closed bins
        # the last bin's rows (the next block may go on with it), their selecting values (C, R) and their bins
        self._open: tuple[dict[str, NDArray[Any]], Array, NDArray[np.int64]] | None = None
        self._columns: int | None = None

    @property
    def samples(self) -> int:
        """Samples fed so far."""
        return self._samples

    @property
    def full_rate(self) -> bool:
        """Whether the run is still kept whole (at most ``full_rate_max_samples`` samples so far)."""
        return self._blocks is not None

    @property
    def n_bins(self) -> int:
        """The bins of the envelope (both grids)."""
        return self.bins_per_grid * len(self._grids)

    @property
    def max_rows(self) -> int | None:
        """The most samples the envelope keeps once binned: a row per bin and per selecting
        column (``None`` before the first block: the columns depend on the fields)."""
        return None if self._columns is None else self.n_bins * self._columns

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays the envelope holds now (its buffers' capacity included)."""
        n = self._kept.nbytes
        if self._open is not None:
            n += sum(a.nbytes for a in self._open[0].values()) + self._open[1].nbytes + self._open[2].nbytes
        for h in self._blocks or ():
            n += sum(a.nbytes for a in _fields(h).values())
        return n

    def add(self, block: History) -> None:
        """Take the next samples of the run: ``block.t`` (B,) their times (from the last one fed
        on, non-decreasing), its arrays (B, N, ...).  Views are fine: what is kept is copied."""
        t = np.asarray(block.t, dtype=np.float64)
        B = t.shape[0]
        if t.ndim != 1:
            raise ValueError(f"a block's t must be (B,), got shape {t.shape}")
        if B == 0:
            return
        if not (np.all(np.isfinite(t)) and t[0] >= self._t_last and np.all(t[1:] >= t[:-1])):
            raise ValueError("a block's times must be finite, non-decreasing and from the last time fed on")
        layout = _layout(block)
        if self._layout is None:
            self._layout = layout
        elif layout != self._layout:
            raise ValueError(f"a block with other fields or runs than the first: {layout} against {self._layout}")
        self._t_last = float(t[-1])
        if self._blocks is not None and self._samples + B <= self.full_rate_max_samples:
            self._blocks.append(_copy(block))
        else:
            if self._blocks is not None:  # the run is longer than a short one: bin what was kept, then go on binning
                earlier, self._blocks = self._blocks, None
                for h in earlier:
                    self._bin(h)
            self._bin(block)
        self._samples += B

    def history(self) -> History:
        """The History to draw: the whole run while it is short (a copy), else its envelope."""
        if self._samples == 0:
            raise ValueError("no sample was fed to the envelope")
        if self._blocks is not None:
            parts = [_fields(h) for h in self._blocks]
            return _history({k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, covariance_whole=True)
        rows = self._kept.view()
        if self._open is not None:
            last = self._open[0]
            rows = {k: np.concatenate((rows[k], last[k])) if k in rows else last[k].copy() for k in last}
        return _history(rows, covariance_whole=False)

    # -- binning -------------------------------------------------------------------------------

    def _bin(self, h: History) -> None:
        for lo in range(0, h.t.shape[0], CHUNK_SAMPLES):
            self._bin_chunk(h.samples(lo, min(lo + CHUNK_SAMPLES, h.t.shape[0])))

    def _bin_of(self, t: Array) -> NDArray[np.int64]:
        """Each sample's bin: ``floor((t - start) / width)`` in its grid, clipped to the grid (a
        monotonic function of ``t``, the same for any blocking)."""
        n = self.bins_per_grid
        out = np.empty(t.shape[0], dtype=np.int64)
        zoomed = t >= self.zoom_from_s if len(self._grids) == 2 else np.zeros(t.shape[0], dtype=bool)
        for g, mask in enumerate((~zoomed, zoomed)[: len(self._grids)]):
            start, width = self._grids[g]
            out[mask] = g * n + np.clip(np.floor((t[mask] - start) / width), 0, n - 1).astype(np.int64)
        return out

    def _bin_chunk(self, h: History) -> None:
        bins = self._bin_of(h.t)
        values = self._selecting_values(h)
        keep = _first_least(bins, values)
        rows, values, bins = _take_rows(h, keep), values[:, keep], bins[keep]
        if self._open is not None:  # the last bin of the previous chunk may go on in this one
            open_rows, open_values, open_bins = self._open
            rows = {k: np.concatenate((open_rows[k], rows[k])) for k in rows}
            values, bins = np.concatenate((open_values, values), axis=1), np.concatenate((open_bins, bins))
            keep = _first_least(bins, values)
            rows, values, bins = {k: a[keep] for k, a in rows.items()}, values[:, keep], bins[keep]
        last = int(np.searchsorted(bins, bins[-1]))  # the last bin stays open: the next block may go on with it
        if last:
            self._kept.append({k: a[:last] for k, a in rows.items()})
        self._open = ({k: a[last:] for k, a in rows.items()}, values[:, last:], bins[last:])

    def _selecting_values(self, h: History) -> Array:
        """(C, B) the values whose per-bin least sample is kept: each drawn series' components
        (module docstring), negated for the greatest, NaN as +inf (never the least while a number
        is there)."""
        B = h.t.shape[0]
        least: list[NDArray[Any]] = []  # series whose least sample is kept
        both: list[NDArray[Any]] = []  # series whose least and greatest samples are kept
        q_ev = h.q_BR[..., :3]
        least += [np.abs(q_ev), np.abs(h.rho)]
        both += [q_ev, h.rho, h.band_lower, h.band_upper, h.torque_B, h.eps, np.abs(h.V)]
        if h.wheel_speed_rad_s is not None and h.wheel_torque_Nm is not None:
            both += [h.wheel_speed_rad_s, h.wheel_torque_Nm]
            G = self._G
            if G is not None and G.shape[1] == h.wheel_torque_Nm.shape[2]:
                undelivered = h.torque_B.copy()  # tau + G u, summed wheel after wheel (the same bits for any blocking)
                for j in range(G.shape[1]):
                    undelivered += h.wheel_torque_Nm[..., j : j + 1] * G[:, j]
                both.append(undelivered)
        est = h.estimate
        if est is not None:
            both.append(attitude_errors(est.q_BN, h.q_BN))
            if est.gyro_bias_true is not None:
                both.append(est.gyro_bias_true - est.gyro_bias)
            both += [np.abs(np.diagonal(est.covariance, axis1=-2, axis2=-1)), est.nis]
        parts = [(a.reshape(B, -1), False) for a in least + both] + [(a.reshape(B, -1), True) for a in both]
        values = np.empty((sum(a.shape[1] for a, _ in parts), B))  # a column's samples contiguous: argmin runs along them
        row = 0
        for a, negated in parts:
            rows = values[row : row + a.shape[1]]
            if negated:
                np.negative(a.T, out=rows)
            else:
                rows[...] = a.T
            row += a.shape[1]
        np.copyto(values, np.inf, where=np.isnan(values))
        self._columns = values.shape[0]
        return values


def _first_least(bins: NDArray[np.int64], values: Array) -> NDArray[np.intp]:
    """The rows (sorted, each once) that are, in their bin (``bins`` (R,) non-decreasing), the
    first of least value of some column of ``values`` (C, R) (no NaN)."""
    R = bins.shape[0]
    starts = np.concatenate(([0], np.flatnonzero(bins[1:] != bins[:-1]) + 1))
    keep = np.zeros(R, dtype=bool)
    if starts.shape[0] <= _FEW_BINS:  # a bin or a few (a long run's chunk): argmin along each, one pass
        for lo, hi in zip(starts, np.append(starts[1:], R)):
            keep[lo + np.argmin(values[:, lo:hi], axis=1)] = True
    else:  # many bins of a few samples each
        least = np.minimum.reduceat(values, starts, axis=1)
        at_least = values == np.repeat(least, np.diff(np.append(starts, R)), axis=1)
        keep[np.minimum.reduceat(np.where(at_least, np.arange(R), R), starts, axis=1).ravel()] = True
    return np.flatnonzero(keep)


#: Up to this many bins in a chunk, each bin's rows are found by an argmin over it (one pass over
#: the chunk); with more, by reductions over every bin at once (a loop over bins of a few samples
#: would be Python's).  Both find the same rows.
_FEW_BINS = 16


def _layout(h: History) -> tuple[Any, ...]:
    """The fields a block has (which optional ones are there, and their trailing shapes)."""
    return tuple((k, a.shape[1:], a.dtype.str) for k, a in _fields(h).items() if k != "t")


def _fields(h: History) -> dict[str, NDArray[Any]]:
    """Every array of ``h`` by name (the estimator's as ``estimate.<name>``); absent ones left out."""
    out = {f.name: a for f in dataclasses.fields(h) if isinstance(a := getattr(h, f.name), np.ndarray)}
    if h.estimate is not None:
        est = h.estimate
        out.update({f"estimate.{f.name}": a for f in dataclasses.fields(est)
                    if isinstance(a := getattr(est, f.name), np.ndarray)})
    return out


def _copy(h: History) -> History:
    """``h`` with every array copied (a block may be a view of a buffer the driver reuses)."""
    return _history({k: np.array(a) for k, a in _fields(h).items()}, covariance_whole=True)


def _take_rows(h: History, keep: NDArray[np.intp]) -> dict[str, NDArray[Any]]:
    """Rows ``keep`` of every array of ``h`` (copies), the covariance as its diagonal (R, N, 6)."""
    out = {}
    for k, a in _fields(h).items():
        out[k] = np.diagonal(a, axis1=-2, axis2=-1)[keep] if k == _COV else a[keep]
    return out


def _history(rows: dict[str, NDArray[Any]], *, covariance_whole: bool) -> History:
    """A History of named arrays (:func:`_fields`' names); the covariance from its diagonal (NaN
    off it) unless ``covariance_whole``."""
    main = {k: a for k, a in rows.items() if not k.startswith("estimate.")}
    est = {k.removeprefix("estimate."): a for k, a in rows.items() if k.startswith("estimate.")}
    if est and not covariance_whole:
        diagonal = est["covariance"]
        cov = np.full(diagonal.shape + (N_ERROR_STATES,), np.nan)
        i = np.arange(N_ERROR_STATES)
        cov[..., i, i] = diagonal
        est["covariance"] = cov
    return History(**main, estimate=EstimateHistory(**est) if est else None)


class _Rows:
    """Rows appended in order, in arrays whose capacity is the first of :data:`_ROWS_START`, grown
    by a quarter at a time, that holds the rows: the same for the same rows however they were
    appended, at most a quarter more than they need."""

    def __init__(self) -> None:
        self._arrays: dict[str, NDArray[Any]] = {}
        self._n = 0

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self._arrays.values())

    def append(self, rows: dict[str, NDArray[Any]]) -> None:
        k = next(iter(rows.values())).shape[0]
        capacity = next(iter(self._arrays.values())).shape[0] if self._arrays else 0
        if self._n + k > capacity:
            size = _ROWS_START
            while size < self._n + k:  # the same capacity for the same rows, however they were appended
                size += size // _ROWS_GROWTH
            grown = {name: np.empty((size,) + a.shape[1:], dtype=a.dtype) for name, a in rows.items()}
            for name, a in self._arrays.items():
                grown[name][: self._n] = a[: self._n]
            self._arrays = grown
        for name, a in rows.items():
            self._arrays[name][self._n : self._n + k] = a
        self._n += k

    def view(self) -> dict[str, NDArray[Any]]:
        return {name: a[: self._n] for name, a in self._arrays.items()}


#: First capacity of the kept rows: a few rows a bin of a few hundred bins.
_ROWS_START = 1024
#: The kept rows' capacity grows by 1 / _ROWS_GROWTH at a time: at most a quarter of it unused
#: (doubling would leave up to half of some 50 MB), for rows copied about 5 times over on average.
_ROWS_GROWTH = 4

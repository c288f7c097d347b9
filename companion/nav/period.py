"""The one record of a control period's average, and the averager that builds it from samples.

:class:`PeriodAverage` is what a period's magnetometer samples come to: D, I and F averaged, the
gravity-referenced I and the levelled magnetic heading of the gravity samples, the standard error
of each average from the period's own scatter (:mod:`companion.nav.inclination`), and the sample
times. The companion builds it from live samples (:class:`companion.nav.magnetometer.MagProcessor`
feeds a :class:`PeriodAverager` one sample at a time); the Monte Carlo's vectorised sample path
(:func:`sitl.world.sampling.sample_period`) feeds the same averager a period's samples at once
(:meth:`PeriodAverager.add_samples`); :class:`companion.nav.navigator.Navigator` turns it into a
step. Pure: samples in (message or mission time, SI units), averages out.

Sample rows hold, per sample: time, D (unwrapped around the period's first sample), I, the field
in NED (3), ``|F|``, ``m . f`` (body field dot specific force; NaN: not a gravity sample), the
specific force in NED (3), the body field (3) and the body specific force (3) (NaN: not a heading
sample).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.frames import Vector3
from companion.nav.heading import levelled_heading_deg
from companion.nav.inclination import mad_standard_errors, ratio_inclination_deg

__all__ = ["SAMPLE_COLUMNS", "PeriodAverage", "PeriodAverager", "measured_inclination"]

_NAN3: Vector3 = (math.nan, math.nan, math.nan)
SAMPLE_COLUMNS = 17   # time, D, I, field NED (3), |F|, m.f, force NED (3), body field (3), body force (3)
PENDING_ROWS = 256    # rows kept as tuples at most before they are written to the array


@dataclass(frozen=True)
class PeriodAverage:
    """D, I and the total intensity ``f_nt`` (nT) averaged over ``count`` samples; NaN when there
    were none. F is the mean of the per-sample magnitudes, so it needs no attitude at all.
    ``incl_grav_deg``: the gravity-referenced I of the ``grav_count`` gravity samples (a ratio of
    averages); ``*_se_*``: the standard errors of the averages from the period's own scatter
    (robust: a few spikes do not widen them; :mod:`companion.nav.inclination`);
    ``mag_heading_deg``: the magnetic heading of the gravity samples' mean body field, levelled by
    their mean specific force (:func:`companion.nav.heading.levelled_heading_deg`)."""

    decl_deg: float
    incl_deg: float
    count: int
    mean_time_s: float
    first_time_s: float
    last_time_s: float
    field_ned_nt: Vector3 = (math.nan, math.nan, math.nan)
    f_nt: float = math.nan
    incl_grav_deg: float = math.nan
    grav_count: int = 0
    decl_se_deg: float = math.nan
    incl_se_deg: float = math.nan
    f_se_nt: float = math.nan
    incl_grav_se_deg: float = math.nan
    mag_heading_deg: float = math.nan

    @property
    def valid(self) -> bool:
        return self.count > 0 and math.isfinite(self.decl_deg) and math.isfinite(self.incl_deg)

    def window_s(self, end_time_s: float, max_s: float) -> float:
        """Span that puts the average's reference time (``end - window/2``) at the mean sample time."""
        if not self.count:
            return 0.0
        return min(max(2.0 * (end_time_s - self.mean_time_s), 0.0), max_s)


def measured_inclination(avg: PeriodAverage, heading_free: bool) -> tuple[float, float]:
    """(I, its standard error) a navigator measures with: gravity-referenced (field and
    accelerometer only, so no heading enters) for a heading-free element set when the period had
    gravity samples, else the tilt-compensated I."""
    if heading_free and math.isfinite(avg.incl_grav_deg):
        return avg.incl_grav_deg, avg.incl_grav_se_deg
    return avg.incl_deg, avg.incl_se_deg


class PeriodAverager:
    """Accumulates per-sample rows (module docstring); :meth:`take` averages those up to a time.

    D is unwrapped around the first sample of the period, so an average across +-180 deg is
    right; the result is wrapped back into (-180, 180]. The samples are rows of one array that
    grows by doubling, and the averages at the step are column operations on a slice. A sample
    added is a tuple in :attr:`_pending` until something reads the rows (or :data:`PENDING_ROWS`
    wait): numpy converts a row written on its own in 1.3 us, a block of them in a fraction of
    that per row, and a list append costs 0.05 us (the 10 Hz pipeline's share; the same float64
    values either way). The samples in use are rows ``_first`` to ``_count``, then the pending
    ones: :meth:`drop_before` on samples in time order (a sliding window, every tick while
    waiting) moves ``_first`` instead of copying the window.
    """

    def __init__(self) -> None:
        self._rows = np.empty((64, SAMPLE_COLUMNS))
        self._first = 0
        self._count = 0
        self._pending: list[tuple] = []   # rows added since the last read, written to the array at the next
        self._ref_d: float | None = None

    def __len__(self) -> int:
        return self._count + len(self._pending) - self._first

    def _flush(self) -> None:
        """Write the pending rows to the array (one numpy call for all of them)."""
        pending = self._pending
        if pending:
            self._room(len(pending))
            self._rows[self._count:self._count + len(pending)] = pending
            self._count += len(pending)
            pending.clear()

    def _room(self, extra: int) -> None:
        if self._count + extra > len(self._rows) and self._first:   # the dropped rows' room first
            self._keep(self._rows[self._first:self._count].copy())
        while self._count + extra > len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])

    def add(self, time_s: float, decl_deg: float, incl_deg: float, ned_nt: Vector3 = (0.0, 0.0, 0.0),
            mag_dot_force: float = math.nan, force_ned: Vector3 = (math.nan, math.nan, math.nan),
            mag_body: Vector3 = _NAN3, force_body: Vector3 = _NAN3) -> None:
        """One sample; ``mag_dot_force`` (``m . f`` in the body frame, nT m/s^2) and ``force_ned`` (the
        specific force in NED) make it a gravity sample for I_g (module docstring), NaN: not one;
        with its body-frame field ``mag_body`` (nT) and ``force_body`` (m/s^2) it counts for the heading."""
        if self._ref_d is None:
            self._ref_d = decl_deg
        d = self._ref_d + ((decl_deg - self._ref_d + 180.0) % 360.0 - 180.0)
        pending = self._pending
        pending.append((time_s, d, incl_deg, ned_nt[0], ned_nt[1], ned_nt[2], math.sqrt(
            ned_nt[0] * ned_nt[0] + ned_nt[1] * ned_nt[1] + ned_nt[2] * ned_nt[2]), mag_dot_force,
            force_ned[0], force_ned[1], force_ned[2], *mag_body, *force_body))
        if len(pending) >= PENDING_ROWS:
            self._flush()

    def add_samples(self, time_s: np.ndarray, ned_nt: np.ndarray, mag_dot_force: np.ndarray, force_ned: np.ndarray,
                    mag_body: np.ndarray, force_body: np.ndarray) -> None:
        """Many samples at once (N of each; vectors (N, 3)), as N calls of :meth:`add` with D and I
        per :mod:`companion` (``atan2(E, N)``, ``atan2(Dn, hypot(N, E))``) would add them: the
        Monte Carlo's vectorised sample path."""
        ned = np.asarray(ned_nt, dtype=float)
        count = len(ned)
        if not count:
            return
        self._flush()
        n, e, down = ned[:, 0], ned[:, 1], ned[:, 2]
        decl = np.degrees(np.arctan2(e, n))
        if self._ref_d is None:
            self._ref_d = float(decl[0])
        self._room(count)
        rows = self._rows[self._count:self._count + count]
        rows[:, 0] = time_s
        rows[:, 1] = self._ref_d + ((decl - self._ref_d + 180.0) % 360.0 - 180.0)
        rows[:, 2] = np.degrees(np.arctan2(down, np.hypot(n, e)))
        rows[:, 3:6] = ned
        rows[:, 6] = np.sqrt(n * n + e * e + down * down)
        rows[:, 7] = mag_dot_force
        rows[:, 8:11] = force_ned
        rows[:, 11:14] = mag_body
        rows[:, 14:17] = force_body
        self._count += count

    def _keep(self, rows: np.ndarray) -> None:
        """Keep only ``rows`` (a copy, in order) for the next period."""
        self._first = 0
        self._count = len(rows)
        self._rows[:self._count] = rows
        self._ref_d = float(rows[0, 1]) if self._count else None

    def take(self, end_time_s: float) -> PeriodAverage:
        """Average the samples with ``time <= end_time_s``; later samples stay for the next period.

        The usual period (samples in time order, every one a gravity and heading sample) is read
        through views of the rows, with no copies; the averages are the same numbers either way."""
        self._flush()
        rows = self._rows[self._first:self._count]
        due = rows[:, 0] <= end_time_s
        n = int(np.count_nonzero(due))
        a = rows[:n] if due[:n].all() else rows[due]      # (n, 17): every average a column operation
        if not n:
            self._keep(rows[~due])
            return PeriodAverage(math.nan, math.nan, 0, math.nan, math.nan, math.nan)
        means = a[:, :7].mean(axis=0)
        d = (float(means[1]) + 180.0) % 360.0 - 180.0
        # a gravity sample has m.f and the force in NED; a heading sample the body field and force too
        # (a row sum is finite only if each value is: the values are far from overflow)
        grav = np.isfinite(a[:, 7:11].sum(axis=1))
        body = grav & np.isfinite(a[:, 11:17].sum(axis=1))
        g = a if grav.all() else a[grav]
        incl_grav, incl_grav_se = ratio_inclination_deg(g[:, 7], g[:, 3:6], g[:, 8:11])
        h = a if body.all() else a[body]
        heading = levelled_heading_deg(*h[:, 11:17].mean(axis=0).reshape(2, 3)) if len(h) else math.nan
        se_d, se_i, se_f = mad_standard_errors(a[:, (1, 2, 6)].T).tolist()
        result = PeriodAverage(d, float(means[2]), n, float(means[0]), float(a[0, 0]), float(a[-1, 0]),
                               (float(means[3]), float(means[4]), float(means[5])), float(means[6]), incl_grav,
                               len(g), se_d, se_i, se_f, incl_grav_se, heading)
        self._keep(rows[~due])    # after the averages: ``a`` may be a view of the rows kept over
        return result

    def drop_before(self, time_s: float) -> None:
        """Forget the samples older than ``time_s``."""
        self._flush()
        rows = self._rows[self._first:self._count]
        kept = rows[:, 0] >= time_s
        dropped = len(rows) - int(np.count_nonzero(kept))
        if dropped == len(rows):
            self.clear()
        elif kept[dropped:].all():   # in time order: the oldest go, the rest stay where they are
            if dropped:
                self._first += dropped
                self._ref_d = float(self._rows[self._first, 1])
        else:
            self._keep(rows[kept])

    def clear(self) -> None:
        self._first = 0
        self._count = 0
        self._pending.clear()
        self._ref_d = None

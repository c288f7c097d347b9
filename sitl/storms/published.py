"""Space-weather indices as they are published: at time t a feed gives only what a service had
published by t, the quick-look value, not the definitive one.

An index is a series of intervals (Kp: 3 h; Dst, RC: 1 h; SYM-H: 1 min) with a definitive value
each (:class:`IndexSeries`). A service publishes an interval's quick-look value only after the
interval has ended: in batches (Kp's nowcast once its 3-hour interval is over; the hourly
updates of Kyoto's real-time Dst and SYM-H; DTU's hourly RC) some delay after the batch's end
(:class:`Publication`). The quick-look value differs from the definitive one (different
stations, unchecked baselines): a seeded perturbation, a per-run offset plus a per-value scatter,
rounded to the index's own step (Kp: thirds) and clipped to its range. The definitive values are
what the world's truth is made of; the navigator only ever sees :meth:`PublishedIndex.value_at`.

What the services publish, and when (the defaults of :data:`KP_NOWCAST` and :data:`RING_QUICKLOOK`;
the full table with the sources is in ``docs/storms.md``):

* **Kp, GFZ nowcast.** GFZ Potsdam computes a nowcast Kp in near real time from 1-minute data of
  the Kp observatories (Matzka et al. 2021, Space Weather 19, e2020SW002641, doi:10.1029/2020SW002641,
  "the near real-time production of the nowcast Kp index"), cadence every 3 hours (PITHIA e-Science
  Centre entry of GFZ's nowcast ap/Kp); the nowcast file says "the most recent values are nowcast
  values and will be replaced by definitive values" (GFZ ``Kp_ap_Ap_SN_F107_nowcast.txt``), the
  definitive values are appended monthly, "typically during the second week of a month" (GFZ Kp
  data publication, doi:10.5880/Kp.0001). The quick-look Kp page is refreshed every 15 minutes
  (spaceweatherlive.com forum, "SWPC 1-minute Kp-Index"). Default: a completed interval's value
  15 min after its end. NOAA SWPC's estimated planetary K (1-minute product, 8 stations) is a
  running estimate of the current interval, not the interval's index: not modelled.
  Quick-look error: Kp is given in thirds; the nowcast's difference to the definitive Kp is of the
  order of one step (a K-type nowcast's RMS error against the definitive index is below one K unit:
  Stankov, Stegen and Warnant, "K-type geomagnetic index nowcast with data quality control", RMI
  Belgium; the nowcast-to-definitive statistics of Matzka et al. 2021 were not in the sources searched):
  default 1/3 (1 sigma) per value, no offset, rounded to thirds and clipped to 0..9.
* **Dst and SYM-H, WDC Kyoto real-time (quick-look).** Real-time Dst is hourly, "derived from
  unverified raw data", "replaced by provisional and final values at later dates" (IUGONET
  description of WDC Kyoto's real-time Dst); a Dst value stamped at an hour is the mean of the hour
  before (Sheffield UOSSW page). Kyoto's Dst "is frequently updated within a few hours of its
  initial value" (AER Dst page); "prompt data is available after one day, provisional values a
  couple of months later, definitive values on average 12-18 months after the event" (UKSSDC Dst
  availability). Two real-time Dst products differ by 7 nT rms, 6 nT on average (Space
  Environment Corporation's RDst against Kyoto's real-time Dst; "both ... will differ similarly
  from a definitive ... value"). Default: values published at the end of each UTC hour plus
  30 min; error a per-run offset of 6 nT and a scatter of 4 nT (1 sigma; together 7 nT rms).
* **RC, DTU Space.** The hourly RC index of the CHAOS models (Olsen et al. 2014, GJI 197,
  doi:10.1093/gji/ggu033) is re-released with each CHAOS version (ChaosMagPy's changelog: "Updated
  built-in RC-index file to RC_1997-2025_June25_v6"); its near-real-time latency is not documented in
  the sources searched. Default: as the real-time Dst (hourly, 30 min after the hour, the same
  error), an assumption stated as such.

>>> import numpy as np
>>> series = IndexSeries("Kp", np.array([0.0, 10800.0]), 10800.0, np.array([3.0, 5.0]))
>>> feed = PublishedIndex(series, Publication(delay_s=900.0))
>>> [feed.value_at(t) for t in (10800.0, 11700.0, 21600.0, 22500.0)]
[nan, 3.0, 3.0, 5.0]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.storms.common import FloatArray

__all__ = ["INDEX_SEED_KEY", "IndexSeries", "KP_NOWCAST", "Publication", "PublishedIndex", "PublishedValue", "RING_QUICKLOOK"]


INDEX_SEED_KEY = 0x696E6478
"""Second word of a feed's seed ``[seed, INDEX_SEED_KEY, stream]``: the quick-look errors' own stream."""


@dataclass(frozen=True, eq=False)
class IndexSeries:
    """Definitive values of an index over intervals ``[start_s, start_s + length_s)`` (POSIX UTC),
    in time order; NaN where the index is missing."""

    name: str
    start_s: FloatArray
    length_s: float
    value: FloatArray

    def __post_init__(self) -> None:
        if self.start_s.shape != self.value.shape or self.start_s.ndim != 1 or self.start_s.size == 0:
            raise ValueError(f"{self.name}: one value per interval start, at least one")
        if not self.length_s > 0.0 or (np.diff(self.start_s) < self.length_s - 1e-6).any():
            raise ValueError(f"{self.name}: intervals must be in time order and not overlap")

    @property
    def end_s(self) -> FloatArray:
        """Each interval's end (POSIX UTC s)."""
        return self.start_s + self.length_s

    def definitive_at(self, time_s: float) -> float:
        """The definitive value of the interval containing ``time_s`` (NaN outside the series):
        the world's truth, never what a navigator can have at ``time_s``."""
        i = int(np.searchsorted(self.start_s, time_s, side="right")) - 1
        if i < 0 or time_s >= self.start_s[i] + self.length_s:
            return math.nan
        return float(self.value[i])


@dataclass(frozen=True)
class Publication:
    """When a service publishes an interval's quick-look value, and how far it is from the definitive.

    An interval ending at ``e`` is published at ``ceil(e / batch_s) * batch_s + delay_s`` (UTC
    batches; ``batch_s`` 0: each interval at its own end + ``delay_s``). Quick-look value:
    ``definitive + offset + scatter`` with ``offset ~ N(0, offset_sigma)`` drawn once per run and
    ``scatter ~ N(0, scatter_sigma)`` per interval, rounded to ``step`` (0: not rounded) and
    clipped to ``[lo, hi]``. Units are the index's.
    """

    delay_s: float = 0.0
    batch_s: float = 0.0
    offset_sigma: float = 0.0
    scatter_sigma: float = 0.0
    step: float = 0.0
    lo: float = -math.inf
    hi: float = math.inf

    def __post_init__(self) -> None:
        for name in ("delay_s", "batch_s", "offset_sigma", "scatter_sigma", "step"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"publication {name} must be finite and >= 0, not {value!r}")
        if not self.lo < self.hi:
            raise ValueError(f"publication range [{self.lo}, {self.hi}] is empty")

    def published_s(self, end_s: FloatArray) -> FloatArray:
        """When intervals ending at ``end_s`` are published (POSIX UTC s), never before ``end + delay``."""
        end = np.asarray(end_s, dtype=np.float64)
        batch_end = np.ceil(end / self.batch_s - 1e-9) * self.batch_s if self.batch_s > 0.0 else end
        return np.maximum(batch_end, end) + self.delay_s


#: GFZ's nowcast Kp (module docstring): 15 min after the 3-hour interval, one third's scatter, thirds, 0..9.
KP_NOWCAST = Publication(delay_s=900.0, batch_s=0.0, offset_sigma=0.0, scatter_sigma=1.0 / 3.0,
                         step=1.0 / 3.0, lo=0.0, hi=9.0)
#: Kyoto's real-time Dst / SYM-H and DTU's RC (module docstring): hourly batches + 30 min, 6 nT offset, 4 nT scatter.
RING_QUICKLOOK = Publication(delay_s=1800.0, batch_s=3600.0, offset_sigma=6.0, scatter_sigma=4.0, step=0.0)


@dataclass(frozen=True)
class PublishedValue:
    """One published quick-look value: its interval (POSIX UTC s), when it was published, the value."""

    start_s: float
    end_s: float
    published_s: float
    value: float


class PublishedIndex:
    """The feed of one index as a service publishes it (:class:`Publication`), the quick-look errors
    drawn once at construction from ``[seed, INDEX_SEED_KEY, stream]`` (the same run, the same feed;
    ``stream`` keeps two indices of one run apart). :meth:`for_seed` is the feed of another run.

    Callable: ``feed(t)`` is :meth:`value_at`, what the world's ground station sends at ``t``.
    """

    def __init__(self, series: IndexSeries, publication: Publication, seed: int = 0, stream: int = 0) -> None:
        self.series = series
        self.publication = publication
        self.seed, self.stream = int(seed), int(stream)
        rng = np.random.default_rng([self.seed, INDEX_SEED_KEY, self.stream])
        offset = publication.offset_sigma * rng.standard_normal() if publication.offset_sigma > 0.0 else 0.0
        scatter = (publication.scatter_sigma * rng.standard_normal(series.value.size)
                   if publication.scatter_sigma > 0.0 else 0.0)
        quick = series.value + offset + scatter
        if publication.step > 0.0:
            quick = np.round(quick / publication.step) * publication.step
        self.quick_look: FloatArray = np.clip(quick, publication.lo, publication.hi)
        self.published_s: FloatArray = publication.published_s(series.end_s)
        # later intervals are never published earlier (ceil and + delay keep the order)
        self._published_sorted = np.maximum.accumulate(self.published_s)

    def for_seed(self, seed: int) -> PublishedIndex:
        """The same index and publication with the quick-look errors of run ``seed``."""
        return self if int(seed) == self.seed else PublishedIndex(self.series, self.publication, seed, self.stream)

    def latest(self, time_s: float) -> PublishedValue | None:
        """The most recent interval published by ``time_s`` (None before the first)."""
        i = int(np.searchsorted(self._published_sorted, time_s, side="right")) - 1
        if i < 0 or not math.isfinite(time_s):
            return None
        return PublishedValue(float(self.series.start_s[i]), float(self.series.end_s[i]),
                              float(self.published_s[i]), float(self.quick_look[i]))

    def value_at(self, time_s: float) -> float:
        """The quick-look value of the latest interval published by ``time_s``; NaN before the first
        (or where that interval's index is missing)."""
        latest = self.latest(float(time_s))
        return math.nan if latest is None else latest.value

    __call__ = value_at

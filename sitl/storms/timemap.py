"""Storm time vs mission time (:class:`StormTimeMap`: real time from a start, or a window
compressed onto the mission), and the search for the storm's sharpest window.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from sitl.storms.common import SUDDEN_COMMENCEMENT_S, FloatArray, StormWindow, _iso, utc_s
from sitl.storms.iaga import IagaRecord

__all__ = ["StormTimeMap", "sharpest_window"]

@dataclass(frozen=True)
class StormTimeMap:
    """How mission elapsed time (s since mission start) maps onto storm time (POSIX UTC).

    rule ``"utc"``: ``storm = mission_start_utc_s + elapsed`` (the mission flies through the
    storm in real time, starting at ``mission_start_utc_s``).

    rule ``"compress"``: the storm window ``[window.start_s, window.end_s]`` is mapped
    linearly onto ``[0, mission_duration_s]`` of mission time (the paper's use: a six-hour
    storm record spans the whole simulated mission). ``storm = start + elapsed * k`` with
    ``k = window.duration_s / mission_duration_s``; beyond the expected duration the map
    continues linearly (the disturbance's ``outside`` policy then applies at the data end).
    """

    rule: Literal["utc", "compress"]
    mission_start_utc_s: float | None = None
    window: StormWindow | None = None
    mission_duration_s: float | None = None

    def __post_init__(self) -> None:
        if self.rule == "utc":
            if self.mission_start_utc_s is None or not math.isfinite(self.mission_start_utc_s):
                raise ValueError("rule 'utc' needs mission_start_utc_s (POSIX UTC seconds)")
        elif self.rule == "compress":
            if self.window is None:
                raise ValueError("rule 'compress' needs a storm window")
            if self.mission_duration_s is None or not self.mission_duration_s > 0.0:
                raise ValueError("rule 'compress' needs mission_duration_s > 0")
        else:
            raise ValueError(f"unknown storm time rule {self.rule!r} (use 'utc' or 'compress')")

    @classmethod
    def utc(cls, mission_start_utc_s: float) -> StormTimeMap:
        """Real-time rule starting the mission at ``mission_start_utc_s``."""
        return cls("utc", mission_start_utc_s=float(mission_start_utc_s))

    @classmethod
    def compress(cls, window: StormWindow, mission_duration_s: float) -> StormTimeMap:
        """Window-onto-mission rule."""
        return cls("compress", window=window, mission_duration_s=float(mission_duration_s))

    @property
    def rate(self) -> float:
        """Storm seconds per mission second (1 for ``"utc"``)."""
        if self.rule == "utc":
            return 1.0
        assert self.window is not None and self.mission_duration_s is not None
        return self.window.duration_s / self.mission_duration_s

    def storm_time_s(self, mission_elapsed_s: ArrayLike) -> FloatArray:
        """Storm time (POSIX UTC seconds) of mission elapsed seconds (array or scalar)."""
        e = np.asarray(mission_elapsed_s, dtype=np.float64)
        if self.rule == "utc":
            assert self.mission_start_utc_s is not None
            return self.mission_start_utc_s + e
        assert self.window is not None
        return self.window.start_s + e * self.rate


def sharpest_window(
    records: Mapping[str, IagaRecord] | Sequence[IagaRecord],
    length_s: float = 93 * 60.0,
    *,
    search: tuple[float, float] | None = None,
    step_s: float = 60.0,
    name: str = "short storm",
) -> StormWindow:
    """The window of ``length_s`` with the largest mean |dH/dt| averaged over the stations.

    Mean |dH/dt| over ``[t0, t0 + L]`` is the total variation of H in the window divided by
    L, evaluated per station from minute differences of ``H = hypot(X, Y)`` (intervals
    touching a NaN count as zero change) and averaged over the stations. Start times are
    tried every ``step_s`` (on whole minutes) with the window inside ``search``.

    Args:
        search: (earliest start, latest end) in POSIX UTC. Default: from the sudden
            commencement minus ``length_s - step_s`` (the window must contain or follow
            the 17:07 commencement) to 2024-05-11 00:00 UTC (the main phase of 10 May).

    Returns:
        The first window of largest mean |dH/dt|.
    """
    recs = list(records.values()) if isinstance(records, Mapping) else list(records)
    if not recs:
        raise ValueError("no station records")
    lo, hi = search if search is not None else (SUDDEN_COMMENCEMENT_S - length_s + step_s, utc_s("2024-05-11T00:00"))
    first = math.ceil(lo / step_s) * step_s
    starts = np.arange(first, hi - length_s + 0.5 * step_s, step_s)
    if starts.size == 0:
        raise ValueError(f"search span {_iso(lo)} .. {_iso(hi)} shorter than the window ({length_s} s)")
    mean_rate = np.zeros(starts.size)
    for r in recs:
        dh = np.abs(np.diff(r.h_nt))
        dh[~np.isfinite(dh)] = 0.0
        cum = np.concatenate([[0.0], np.cumsum(dh)])  # total variation up to each sample
        if r.time_s[0] > starts[0] or r.time_s[-1] < starts[-1] + length_s:
            raise ValueError(f"station {r.code} does not cover the search span")
        mean_rate += (np.interp(starts + length_s, r.time_s, cum) - np.interp(starts, r.time_s, cum)) / length_s
    best = int(np.argmax(mean_rate))
    return StormWindow(name, float(starts[best]), float(starts[best] + length_s))

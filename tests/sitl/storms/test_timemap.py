"""sitl.storms.timemap: storm time vs mission time, the storm windows and the sharpest-window search.

Expected values are read from the raw file text by regular expressions (not by the reader
under test) or computed from physics, never copied from the implementation.
"""
from __future__ import annotations

import numpy as np
import pytest

from sitl import storms as S
from tests.sitl.storms.storm_data import WESTERN_PACIFIC, posix


# ------------------------------------------------------------------------------ time and windows


def test_storm_time_map_rules() -> None:
    start = posix("2024-05-10 18:00")
    utc = S.StormTimeMap.utc(start)
    np.testing.assert_array_equal(utc.storm_time_s([0.0, 3600.0, 90.5]), [start, start + 3600.0, start + 90.5])
    assert utc.rate == 1.0

    duration = 20.0 * 3600.0
    comp = S.StormTimeMap.compress(S.LONG_STORM, duration)
    assert comp.storm_time_s(0.0) == S.LONG_STORM.start_s == start
    assert comp.storm_time_s(duration) == pytest.approx(posix("2024-05-11 00:00"), abs=1e-6)
    assert comp.storm_time_s(duration / 2.0) == pytest.approx(posix("2024-05-10 21:00"), abs=1e-6)
    assert comp.rate == pytest.approx(6.0 / 20.0)
    assert comp.storm_time_s(np.zeros((2, 3))).shape == (2, 3)

    with pytest.raises(ValueError, match="unknown storm time rule"):
        S.StormTimeMap("realtime", mission_start_utc_s=start)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="mission_start_utc_s"):
        S.StormTimeMap("utc")
    with pytest.raises(ValueError, match="mission_duration_s"):
        S.StormTimeMap("compress", window=S.LONG_STORM, mission_duration_s=0.0)


def test_windows() -> None:
    assert (S.LONG_STORM.start_s, S.LONG_STORM.end_s) == (posix("2024-05-10 18:00"), posix("2024-05-11 00:00"))
    assert S.SHORT_STORM.duration_s == 93 * 60
    with pytest.raises(ValueError):
        S.StormWindow("backwards", 10.0, 5.0)


def test_sharpest_window(records) -> None:
    window = S.sharpest_window(records)
    assert window == S.SHORT_STORM  # the published constant is what the data give
    assert window.duration_s == 93 * 60
    assert window.end_s > S.SUDDEN_COMMENCEMENT_S
    assert window.end_s <= posix("2024-05-11 00:00")

    # Independent brute force on the four stations stamped on whole minutes: summed |dH| over
    # 93 consecutive minute steps, every start from 15:35 (window ending after 17:07) on 10 May.
    length = 93
    total = np.zeros(0)
    for code in WESTERN_PACIFIC:
        rec = records[code]
        steps = np.abs(np.diff(rec.h_nt))
        sums = np.convolve(steps, np.ones(length), mode="valid")  # sums[k]: from minute k to k + 93
        total = sums if total.size == 0 else total + sums
    minute0 = records["kak"].time_s
    first = int(np.flatnonzero(minute0 == S.SUDDEN_COMMENCEMENT_S - (length - 1) * 60.0)[0])
    last = int(np.flatnonzero(minute0 == posix("2024-05-11 00:00") - length * 60.0)[0])
    best = first + int(np.argmax(total[first : last + 1]))
    wpac = S.sharpest_window([records[c] for c in WESTERN_PACIFIC])
    assert wpac.start_s == minute0[best]
    # Sharper than the long window on average, and than the window that starts at the SC.
    mean_rate = total / (length * 60.0)
    long_start = int(np.flatnonzero(minute0 == S.LONG_STORM.start_s)[0])
    sc_start = int(np.flatnonzero(minute0 == S.SUDDEN_COMMENCEMENT_S)[0])
    assert mean_rate[best] > mean_rate[long_start : long_start + 360 - length].mean()
    assert mean_rate[best] > mean_rate[sc_start]


def _synthetic_record(time_s: np.ndarray, x: np.ndarray, y: np.ndarray) -> S.IagaRecord:
    nan = np.full(time_s.size, np.nan)
    return S.IagaRecord(
        code="SYN", name="synthetic", lat_deg=0.0, lon_deg=0.0, lon_east_deg=0.0, elevation_m=0.0,
        reported="XYZF", time_s=time_s, x_nt=x, y_nt=y, z_nt=np.zeros(time_s.size), f_nt=nan, sources=(),
    )


def test_sharpest_window_uses_horizontal_intensity() -> None:
    """A 20-minute H oscillation carried by Y (H = hypot(X, Y), X = Y) beats a weaker one in X alone."""
    t = posix("2024-05-10 00:00") + 60.0 * np.arange(600)
    x = np.full(t.size, 20000.0)
    y = np.full(t.size, 20000.0)
    burst_y = slice(300, 320)  # 05:00-05:20: Y swings +-50 nT, H by about +-35 nT
    y[burst_y] += 50.0 * (-1.0) ** np.arange(20)
    burst_x = slice(100, 120)  # 01:40-02:00: X swings +-30 nT, H by about +-21 nT
    x[burst_x] += 30.0 * (-1.0) ** np.arange(20)
    window = S.sharpest_window([_synthetic_record(t, x, y)], 20 * 60.0, search=(t[0], t[-1]))
    assert window.start_s in (t[299], t[300])  # both contain all 20 swings
    assert window.duration_s == 1200.0

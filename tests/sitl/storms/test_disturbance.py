"""sitl.storms.disturbance: the interpolated disturbance field on the real stations.

Expected values are read from the raw file text by regular expressions (not by the reader
under test) or computed from physics, never copied from the implementation.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from sitl import storms as S
from tests.sitl.storms.storm_data import posix, quiet_median


# ------------------------------------------------------------------------------ disturbance


def test_disturbance_equals_station_deviation_at_station(records, disturbance) -> None:
    for code, rec in records.items():
        x0, y0, z0 = (quiet_median(v, rec.time_s) for v in (rec.x_nt, rec.y_nt, rec.z_nt))
        t = rec.time_s[1:-1]  # FRD's first/last minutes lie outside the common span
        for lon in (rec.lon_deg, rec.lon_east_deg):
            dn, de, dd = disturbance.disturbance_ned_nt(rec.lat_deg, lon, t)
            np.testing.assert_allclose(dn, rec.x_nt[1:-1] - x0, rtol=0, atol=1e-9)
            np.testing.assert_allclose(de, rec.y_nt[1:-1] - y0, rtol=0, atol=1e-9)
            np.testing.assert_allclose(dd, rec.z_nt[1:-1] - z0, rtol=0, atol=1e-9)
        # Linear in time between minutes.
        dn_mid, _, _ = disturbance.disturbance_ned_nt(rec.lat_deg, rec.lon_deg, t[:-1] + 15.0)
        np.testing.assert_allclose(dn_mid, 0.75 * rec.x_nt[1:-2] + 0.25 * rec.x_nt[2:-1] - x0, atol=1e-9)


def test_interpolation_between_stations_is_a_convex_blend(records, disturbance) -> None:
    t = np.arange(S.LONG_STORM.start_s, S.LONG_STORM.end_s, 600.0)
    station = disturbance.station_values(t)  # (M, 3, T)
    dn, de, dd = disturbance.disturbance_ned_nt(27.0, 150.0, t)  # in the paper's area, KAK..GUA
    for k, comp in enumerate((dn, de, dd)):
        assert np.all(comp >= station[:, k].min(axis=0) - 1e-9)
        assert np.all(comp <= station[:, k].max(axis=0) + 1e-9)
    w = disturbance.weights(27.0, 150.0)
    assert w.sum() == pytest.approx(1.0) and np.all(w > 0.0)
    kak = disturbance.codes.index("KAK")
    gua = disturbance.codes.index("GUA")
    assert w[kak] + w[gua] > 0.8  # the nearest stations dominate
    # Continuous at a station: 1 m away the value is the station's within a millionth.
    rec = records["kak"]
    near = disturbance.disturbance_ned_nt(rec.lat_deg + 1e-5, rec.lon_deg, t)[0]
    np.testing.assert_allclose(near, station[kak, 0], rtol=1e-6, atol=1e-6)


def test_scale_time_offset_and_outside_policy(records, disturbance) -> None:
    rec = records["gua"]
    t = np.array([posix("2024-05-10 20:00"), posix("2024-05-10 21:30:20")])
    base = np.array(disturbance.disturbance_ned_nt(20.0, 150.0, t))
    doubled = disturbance.with_mapping(scale=2.0)
    np.testing.assert_allclose(doubled.disturbance_ned_nt(20.0, 150.0, t), 2.0 * base, rtol=1e-12)
    shifted = disturbance.with_mapping(time_offset_s=3600.0)
    np.testing.assert_allclose(shifted.disturbance_ned_nt(20.0, 150.0, t - 3600.0), base, rtol=1e-12)
    assert disturbance.scale == 1.0 and disturbance.time_offset_s == 0.0  # the original is unchanged

    lo, hi = disturbance.time_range_s
    assert lo == posix("2024-05-10 00:00:30") and hi == posix("2024-05-11 23:59")
    with pytest.raises(ValueError, match="outside the data span"):
        disturbance.disturbance_ned_nt(20.0, 150.0, [lo, hi + 1.0])
    hold = S.StormDisturbance.from_records(records, outside="hold")
    zero = S.StormDisturbance.from_records(records, outside="zero")
    late = hold.disturbance_ned_nt(rec.lat_deg, rec.lon_deg, hi + 7200.0)
    assert late[0] == rec.x_nt[-1] - quiet_median(rec.x_nt, rec.time_s)
    assert zero.disturbance_ned_nt(rec.lat_deg, rec.lon_deg, hi + 7200.0) == (0.0, 0.0, 0.0)
    inside = zero.disturbance_ned_nt(rec.lat_deg, rec.lon_deg, hi)
    assert inside[0] == late[0]


def test_broadcasting_matches_pointwise(disturbance) -> None:
    rng = np.random.default_rng(7)
    lat = rng.uniform(20.0, 35.0, size=(6, 1))
    lon = rng.uniform(140.0, 170.0, size=(6, 1))
    t = rng.uniform(S.LONG_STORM.start_s, S.LONG_STORM.end_s, size=4)
    grid = disturbance.disturbance_ned_nt(lat, lon, t)
    assert all(g.shape == (6, 4) for g in grid)
    for i in range(6):
        for j in range(4):
            point = disturbance.disturbance_ned_nt(lat[i, 0], lon[i, 0], t[j])
            for c in range(3):
                assert grid[c][i, j] == pytest.approx(float(point[c]), abs=1e-9)
    scalar_t = disturbance.disturbance_ned_nt(lat[:, 0], lon[:, 0], t[1])
    np.testing.assert_allclose(scalar_t[2], grid[2][:, 1], atol=1e-9)


def test_speed_1e5_points(disturbance) -> None:
    rng = np.random.default_rng(1)
    n = 100_000
    lat, lon = rng.uniform(27.0, 34.0, n), rng.uniform(145.0, 165.0, n)
    t = rng.uniform(S.LONG_STORM.start_s, S.LONG_STORM.end_s, n)
    disturbance.disturbance_ned_nt(lat, lon, t)
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        dn, _, _ = disturbance.disturbance_ned_nt(lat, lon, t)
        best = min(best, time.perf_counter() - t0)
    assert dn.shape == (n,) and np.isfinite(dn).all()
    assert best < 0.5, f"{best * 1e3:.0f} ms for 1e5 points"

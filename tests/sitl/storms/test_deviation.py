"""sitl.storms.deviation: the quiet baseline, eq. 64 and the (D, I) shift of a disturbance.

Expected values are read from the raw file text by regular expressions (not by the reader
under test) or computed from physics, never copied from the implementation.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sitl import storms as S
from tests.sitl.storms.storm_data import WESTERN_PACIFIC, posix, quiet_median


def test_quiet_baseline_interval_is_quiet(records) -> None:
    window = S.QUIET_BASELINE
    assert (window.start_s, window.end_s) == (posix("2024-05-10 12:00"), posix("2024-05-10 17:00"))
    assert window.end_s < S.SUDDEN_COMMENCEMENT_S == posix("2024-05-10 17:07")
    for code in WESTERN_PACIFIC:
        rec = records[code]
        inside = (rec.time_s >= window.start_s) & (rec.time_s < window.end_s)
        for comp in (rec.x_nt, rec.y_nt, rec.z_nt):
            assert np.ptp(comp[inside]) < 35.0, code
        assert S.quiet_baseline(rec) == (
            quiet_median(rec.x_nt, rec.time_s),
            quiet_median(rec.y_nt, rec.time_s),
            quiet_median(rec.z_nt, rec.time_s),
        )
    # ... against a storm ten times larger.
    assert -S.station_deviation(records["kak"]).dh_nt.min() > 350.0


def test_eq64_dbh(records, disturbance) -> None:
    np.testing.assert_array_equal(S.eq64_dbh_nt([3.0, -3.0, 0.0, -0.0], [4.0, 4.0, -5.0, 0.0]), [5.0, -5.0, 5.0, 0.0])
    rec = records["kak"]
    t = rec.time_s[(rec.time_s >= S.LONG_STORM.start_s) & (rec.time_s <= S.LONG_STORM.end_s)]
    dx = np.interp(t, rec.time_s, rec.x_nt) - quiet_median(rec.x_nt, rec.time_s)
    dy = np.interp(t, rec.time_s, rec.y_nt) - quiet_median(rec.y_nt, rec.time_s)
    expected = np.where(dx < 0, -1.0, 1.0) * np.sqrt(dx**2 + dy**2)
    np.testing.assert_allclose(disturbance.dbh_nt(rec.lat_deg, rec.lon_deg, t), expected, atol=1e-9)
    assert expected.min() < -350.0  # main phase: dB_H strongly negative


def _wmm2020_at_kak(shared_data: Path) -> tuple[float, float, float]:
    lat, lon, alt_m, year = 36.232, 140.186, 36.0, 2024.36
    try:
        from companion.nav.field import load_wmm
    except ImportError:
        from pygeomag import GeoMag

        res = GeoMag(coefficients_file=str(shared_data / "wmm" / "WMM2020.COF")).calculate(
            glat=lat, glon=lon, alt=alt_m / 1000.0, time=year
        )
        return res.x, res.y, res.z
    el = load_wmm("WMM2020").elements(lat, lon, alt_m, year)
    return float(el.x_nt), float(el.y_nt), float(el.z_nt)


def test_declination_inclination_shift_at_kak(shared_data: Path, records, disturbance) -> None:
    x, y, z = _wmm2020_at_kak(shared_data)
    h2 = x * x + y * y
    f2 = h2 + z * z
    rec = records["kak"]
    sel = (rec.time_s >= S.LONG_STORM.start_s) & (rec.time_s <= S.LONG_STORM.end_s)
    t = rec.time_s[sel]
    x0, y0 = quiet_median(rec.x_nt, rec.time_s), quiet_median(rec.y_nt, rec.time_s)
    z0 = quiet_median(rec.z_nt, rec.time_s)
    h_obs = np.hypot(rec.x_nt[sel], rec.y_nt[sel])
    k = int(np.argmin(h_obs))  # H falls most
    dx, dy, dz = rec.x_nt[sel][k] - x0, rec.y_nt[sel][k] - y0, rec.z_nt[sel][k] - z0

    dn, de, dd = disturbance.disturbance_ned_nt(rec.lat_deg, rec.lon_deg, t)
    d_shift, i_shift = S.di_shift_deg(x, y, z, dn, de, dd)
    # First-order physics: dD = (X dY - Y dX) / H^2, dI = (H dZ - Z dH) / F^2 (radians).
    d_lin = math.degrees((x * dy - y * dx) / h2)
    dh = (x * dx + y * dy) / math.sqrt(h2)
    i_lin = math.degrees((math.sqrt(h2) * dz - z * dh) / f2)
    assert d_shift[k] == pytest.approx(d_lin, rel=0.03)
    assert i_shift[k] == pytest.approx(i_lin, rel=0.03)
    assert abs(d_lin) > 0.05 and abs(i_lin) > 0.1  # a real shift, not noise

    # The same sign and size as the declination the observatory itself recorded.
    d_obs = np.degrees(np.arctan2(rec.y_nt[sel], rec.x_nt[sel]))
    d_obs_shift = d_obs[k] - math.degrees(math.atan2(y0, x0))
    assert np.sign(d_shift[k]) == np.sign(d_obs_shift)
    assert d_shift[k] == pytest.approx(d_obs_shift, rel=0.1)
    # README: declination swings about 0.32 degrees at KAK between 18 and 24 UTC.
    assert np.ptp(d_shift) == pytest.approx(0.32, abs=0.01)
    assert np.ptp(d_shift) == pytest.approx(np.ptp(d_obs), rel=0.03)

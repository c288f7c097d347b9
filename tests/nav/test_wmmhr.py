"""WMMHR-2025 (degree 133) as the navigator's map: NCEI's published test values, pygeomag's own
WMMHR, the exact slopes against differences, and NAV_MAP's choice and its date rule."""
from __future__ import annotations

import numpy as np
import pytest
from pygeomag import GeoMag

from companion.nav.field import load_wmm, model_for_setting
from companion.params import ParamError, validate_all

# NCEI's WMMHR2025_TEST_VALUES.txt (shipped with WMMHR2025COF.zip), rows 1-3, 6 and 8:
# year, height km, lat, lon, X, Y, Z (nT, rounded to 0.1)
NCEI = [
    (2025.0, 0.0, 80.0, 0.0, 6517.4, 144.8, 54701.3),
    (2025.0, 0.0, 0.0, 120.0, 39643.1, -100.3, -10580.7),
    (2025.0, 0.0, -80.0, 240.0, 6136.3, 15740.2, -52096.7),
    (2025.0, 100.0, -80.0, 240.0, 5916.0, 14762.5, -49580.3),
    (2027.5, 0.0, 0.0, 120.0, 39667.0, -159.1, -10383.9),
]
POINTS = [(30.5, 155.0, 0.0, 2025.5), (-38.0, 164.0, 0.0, 2026.2), (0.5, -30.0, 1000.0, 2027.0),
          (-89.9, 40.0, 0.0, 2025.1), (45.0, -75.0, 5000.0, 2028.0)]


@pytest.fixture(scope="module")
def wmmhr():
    return load_wmm("WMMHR2025")


@pytest.mark.parametrize("year, height_km, lat, lon, x, y, z", NCEI)
def test_wmmhr_matches_ncei_test_values(wmmhr, year, height_km, lat, lon, x, y, z):
    got = wmmhr.ned(lat, lon, height_km * 1000.0, year)
    assert np.allclose(got, (x, y, z), atol=0.05 + 1e-6)   # the published rounding


def test_wmmhr_matches_pygeomag_at_points(wmmhr):
    reference = GeoMag(coefficients_file="wmm/WMMHR_2025.COF", high_resolution=True)
    for lat, lon, alt, year in POINTS:
        r = reference.calculate(glat=lat, glon=lon, alt=alt / 1000.0, time=year)
        assert np.allclose(wmmhr.ned(lat, lon, alt, year), (r.x, r.y, r.z), atol=1e-3)   # measured 1e-6 nT
    lat, lon = np.array([p[0] for p in POINTS]), np.array([p[1] for p in POINTS])
    block = np.stack(wmmhr.ned(lat, lon, 0.0, 2026.0), axis=-1)
    assert np.allclose(block, [wmmhr.ned(float(a), float(b), 0.0, 2026.0) for a, b in zip(lat, lon)], atol=1e-9)


def test_wmmhr_slopes_are_the_fields_derivatives(wmmhr):
    step = 1e-5   # degrees: central differences' error ~1e-4 nT/rad here against slopes of ~1e4
    for lat, lon, alt, year in POINTS[:3]:
        value, d_lat, d_lon = wmmhr.ned_and_slopes(lat, lon, alt, year)
        assert np.allclose(value, wmmhr.ned(lat, lon, alt, year), atol=1e-9)
        fd_lat = (np.array(wmmhr.ned(lat + step, lon, alt, year)) - wmmhr.ned(lat - step, lon, alt, year))
        fd_lon = (np.array(wmmhr.ned(lat, lon + step, alt, year)) - wmmhr.ned(lat, lon - step, alt, year))
        assert np.allclose(d_lat, fd_lat / np.radians(2 * step), atol=0.5, rtol=1e-5)
        assert np.allclose(d_lon, fd_lon / np.radians(2 * step), atol=0.5, rtol=1e-5)


def test_wmmhr_differs_from_the_wmm_by_the_crust_it_holds(wmmhr):
    wmm = load_wmm("WMM2025")
    gaps = [np.linalg.norm(np.subtract(wmmhr.ned(lat, lon, 0.0, 2026.0), wmm.ned(lat, lon, 0.0, 2026.0)))
            for lat, lon, _, _ in POINTS]
    assert 5.0 < max(gaps) < 2000.0   # degrees 13-133: tens to hundreds of nT at the surface


def test_nav_map_picks_wmmhr_and_never_extrapolates_it():
    assert model_for_setting(2025.5, 0, 1).name == "WMMHR2025"
    assert model_for_setting(2025.5, 1, 0).name == "WMM2020" and model_for_setting(2024.36, 0, 0).name == "WMM2020"
    with pytest.raises(ValueError, match="WMMHR2025 covers 2024.87..2030.00, not NAV_YEAR 2024.36"):
        model_for_setting(2024.36, 0, 1)
    with pytest.raises(ParamError, match="NAV_MAP 1"):
        validate_all({"NAV_MAP": 1, "NAV_YEAR": 2024.36})
    assert validate_all({"NAV_MAP": 1, "NAV_YEAR": 2025.36})["NAV_MAP"] == 1

"""The route's crustal strength from the carried map (issue 46.7): the local model-error states
of the filter and of the pre-flight prediction scaled by it, the same value in both."""
from __future__ import annotations

import numpy as np
import pytest

from companion.nav.crust import local_error_scale, route_crust_rms_nt
from companion.nav.mission import Mission
from companion.nav.prediction import predict_route
from companion.nav.wmm import load_wmm
from companion.params import Controller, NavConfig, validate_all

PACIFIC = ((33.0, 152.0), (28.0, 158.0))
TASMAN = ((-40.0, 160.0), (-36.0, 168.0))


def _config(route, **extra) -> NavConfig:
    (start, dest) = route
    values = {"NAV_START_LAT": start[0], "NAV_START_LON": start[1], "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1],
              "NAV_CONTROLLER": Controller.FC, "NAV_YEAR": 2025.36, "NAV_MAP": 1, **extra}
    return NavConfig.from_values(validate_all(values))


def test_band_is_the_part_of_the_map_between_its_degrees():
    """WMMHR-2025 at its epoch is the sum of its degrees 1-15 and 16-133 (the crust's band)."""
    full = load_wmm("WMMHR2025")
    lat, lon = np.array([-40.0, -38.0, 30.0]), np.array([160.0, 164.0, 155.0])
    whole = np.array(full.ned(lat, lon, 0.0, full.epoch))
    parts = np.array(full.band(1, 15).ned(lat, lon, 0.0, 2031.0)) + np.array(full.band(16).ned(lat, lon, 0.0, 2019.0))
    assert parts == pytest.approx(whole, abs=1e-6)


def test_tasman_crust_scales_the_local_error_in_the_filter_and_the_prediction():
    """The map sees the Tasman route's crust 1.7 times the Pacific's (WMMHR-2025 degrees 16-133: 84
    against 48 nT rms). The truth's error against that map, measured along the routes (IGRF-14 +
    EMM2017 minus WMMHR-2025, 800 points), was 2.35 times the Pacific's in D, 2.2 in F, 1.3 in I:
    the scale must fall among them. The Pacific, on which FUS_GM_DEG / FUS_GM_NT were set, keeps 1."""
    assert route_crust_rms_nt(*PACIFIC[0], *PACIFIC[1], 0.0) == pytest.approx(48.1, abs=1.0)
    pacific, tasman = local_error_scale(_config(PACIFIC)), local_error_scale(_config(TASMAN))
    assert pacific == 1.0
    assert 1.3 <= tasman <= 2.35
    # switched off, or a date before WMMHR-2025 existed: no scaling
    assert local_error_scale(_config(TASMAN, FUS_GM_CRUST=0.0)) == 1.0
    assert local_error_scale(_config(TASMAN, NAV_YEAR=2024.36, NAV_MAP=0)) == 1.0
    # the filter's settings carry it (the filter is built from them at the first step)
    config = _config(TASMAN)
    bias = Mission(config).estimator.settings.bias
    assert bias.local_deg == pytest.approx(config.filter.bias.local_deg * tasman)
    assert bias.local_nt == pytest.approx(config.filter.bias.local_nt * tasman)
    assert bias.qd_deg_rkm == pytest.approx(config.filter.bias.qd_deg_rkm * tasman)
    # and the prediction, which flies the same mission, says so
    prediction = predict_route(config, compass_derived=True, has_ins=False)
    assert prediction.local_scale == tasman
    assert any(f"map error x{tasman:.2f}" in line for line in prediction.lines())

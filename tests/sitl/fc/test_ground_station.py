"""The world's ground station behind the simulated flight controller keeps the companion's NAV_KP and
NAV_SYMH up to date (sitl.fc.ground_station), over real loopback sockets."""
from __future__ import annotations

import math

import pytest

from sitl.fc.ground_station import FEED_PERIOD_S, FEED_READINGS, GCS_COMPID, GCS_SYSID
from tests.sitl.conftest import COMPANION, REPO


def test_the_storm_worlds_kp_and_symh_reach_the_companion_every_minute_from_the_ground_station(sitl, shared_data):
    server, client = sitl(scenario="paper_long_storm", space_weather_feed=FEED_READINGS, speedup=300.0, data_dir=str(shared_data))
    sets = client.collect("PARAM_SET", until_ms=int(3.5 * FEED_PERIOD_S * 1000), timeout=120.0)
    truth = server.vehicle.truth_full
    for msg in sets:
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (GCS_SYSID, GCS_COMPID)
        assert (msg.target_system, msg.target_component) == COMPANION
    kp = [m.param_value for m in sets if m.param_id == "NAV_KP"]
    symh = [m.param_value for m in sets if m.param_id == "NAV_SYMH"]
    assert len(kp) == len(symh) == 4 and len(sets) == 8   # both at 0, 60, 120 and 180 s
    for k in range(4):
        assert kp[k] == pytest.approx(round(truth.kp(k * FEED_PERIOD_S), 3), abs=1e-5)
        assert symh[k] == pytest.approx(round(truth.symh(k * FEED_PERIOD_S), 1), abs=1e-3)
    # as published at 18:00 UTC (the window's start): Kp of 12-15 UTC, SYM-H to 16:59 UTC (hourly, 30 min
    # late), the same value all four minutes; the 17:07 onset is not published yet
    assert len(set(kp)) == 1 and 0.0 <= kp[0] <= 9.0 and len(set(symh)) == 1 and math.isfinite(symh[0])


def test_a_quiet_world_feeds_a_quiet_days_kp_and_symh(sitl):
    """A world without a storm: Kp 0 and SYM-H 0 nT, what a service says of a field nothing disturbs."""
    _, client = sitl(scenario="paper_pacific", space_weather_feed=FEED_READINGS, speedup=300.0)
    sets = client.collect("PARAM_SET", until_ms=int(1.5 * FEED_PERIOD_S * 1000), timeout=120.0)
    assert sorted((m.param_id, m.param_value) for m in sets) == [("NAV_KP", 0.0)] * 2 + [("NAV_SYMH", 0.0)] * 2


def test_a_world_whose_space_weather_is_withheld_sends_nothing(sitl, tmp_path):
    """``[storm] kp_feed = false``, ``symh_feed = false``: no service reaches this vehicle."""
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text(encoding="utf-8")
    assert "[storm]\nenabled = false\n" in text
    path = tmp_path / "pacific_no_feed.toml"
    path.write_text(text.replace("[storm]\nenabled = false\n",
                                 "[storm]\nenabled = false\nkp_feed = false\nsymh_feed = false\n"), encoding="utf-8")
    _, client = sitl(scenario=str(path), space_weather_feed=FEED_READINGS, speedup=300.0)
    assert client.collect("PARAM_SET", until_ms=int(2.5 * FEED_PERIOD_S * 1000), timeout=120.0) == []


def test_a_ground_station_set_to_feed_sym_h_alone_sends_no_kp(sitl, shared_data):
    """``--space-weather-feed NAV_SYMH``: an operator with SYM-H and no Kp."""
    _, client = sitl(scenario="paper_long_storm", space_weather_feed=("NAV_SYMH",), speedup=300.0, data_dir=str(shared_data))
    sets = client.collect("PARAM_SET", until_ms=int(1.5 * FEED_PERIOD_S * 1000), timeout=120.0)
    assert [m.param_id for m in sets] == ["NAV_SYMH", "NAV_SYMH"]

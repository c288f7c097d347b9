"""The world's ground station behind the simulated flight controller keeps the companion's NAV_SYMH
up to date (sitl.fc.ground_station), over real loopback sockets."""
from __future__ import annotations

import math

import pytest

from sitl.fc.ground_station import FEED_PERIOD_S, GCS_COMPID, GCS_SYSID
from tests.sitl.conftest import COMPANION


def test_the_storm_worlds_symh_reaches_the_companion_every_minute_from_the_ground_station(sitl, shared_data):
    server, client = sitl(scenario="long_storm", symh_feed=True, speedup=300.0, data_dir=str(shared_data))
    sets = client.collect("PARAM_SET", until_ms=int(3.5 * FEED_PERIOD_S * 1000), timeout=120.0)
    assert len(sets) == 4   # at 0, 60, 120 and 180 s
    truth = server.vehicle.truth_full
    for k, msg in enumerate(sets):
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (GCS_SYSID, GCS_COMPID)
        assert (msg.target_system, msg.target_component) == COMPANION and msg.param_id == "NAV_SYMH"
        assert msg.param_value == pytest.approx(round(truth.symh(k * FEED_PERIOD_S), 1), abs=1e-3)
    assert all(math.isfinite(m.param_value) and m.param_value < 0.0 for m in sets)   # the storm's ring current


def test_a_world_without_symh_sends_nothing(sitl):
    _, client = sitl(scenario="pacific", symh_feed=True, speedup=300.0)
    assert client.collect("PARAM_SET", until_ms=int(2.5 * FEED_PERIOD_S * 1000), timeout=120.0) == []

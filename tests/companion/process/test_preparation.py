"""The mission built while READY (companion.process.preparation): kept while it serves, rebuilt when not.

Each READY tick asks for the mission again; one asking what the last did is answered without
building a configuration (a sixth of the companion's message handling went there). These tests
hold the answer to what it was: a parameter change, another element set or a start moved beyond
PREPARED_START_M builds a new mission, a start moved less keeps it.
"""
from __future__ import annotations

import pytest

from companion.app import State
from companion.process.preparation import PREPARED_START_M
from tests.companion.process.rig import _msg, make_rig

DEG_PER_M = 1.0 / 111_000.0     # of latitude, near enough for "within" and "beyond" 100 m


@pytest.fixture
def ready(tmp_path):
    app, fc = make_rig(tmp_path)
    app.machine.state = State.READY
    app.preparation.prepare(app.now)
    yield app
    app.close()
    fc.close()


def _set(app, name: str, value: float) -> None:
    app.params.set_value(name, value)
    app.settings.apply()


def test_a_tick_asking_the_same_keeps_the_mission(ready):
    built = ready.preparation.prepared
    assert built is not None and built.config.start_lat_deg == ready.settings.nav.start_lat_deg
    for _ in range(5):
        ready.preparation.prepare(ready.now)
    assert ready.preparation.prepared is built


def test_a_parameter_change_builds_a_mission_with_it(ready):
    built = ready.preparation.prepared
    _set(ready, "NAV_SPEED_KMH", 30.0)
    ready.preparation.prepare(ready.now)
    assert ready.preparation.prepared is not built
    assert ready.preparation.prepared.config.speed_mps == pytest.approx(30.0 / 3.6)
    again = ready.preparation.prepared
    ready.preparation.prepare(ready.now)          # and then keeps that one
    assert ready.preparation.prepared is again


@pytest.mark.parametrize("moved_m, kept", [(0.5 * PREPARED_START_M, True), (2.0 * PREPARED_START_M, False)])
def test_a_start_moved_within_the_distance_keeps_the_mission_and_beyond_it_rebuilds(ready, moved_m, kept):
    built = ready.preparation.prepared
    lat = ready.settings.nav.start_lat_deg + moved_m * DEG_PER_M
    _set(ready, "NAV_START_LAT", lat)
    ready.preparation.prepare(ready.now)
    assert (ready.preparation.prepared is built) == kept
    if not kept:
        assert ready.preparation.prepared.config.start_lat_deg == pytest.approx(lat)
    # the same start asked again from the kept mission's parameters: still kept (no drift to 100 m)
    ready.preparation.prepare(ready.now)
    assert (ready.preparation.prepared is built) == kept


def test_taking_the_mission_leaves_nothing_prepared_and_the_next_tick_builds_again(ready):
    built = ready.preparation.prepared
    assert ready.preparation.take_mission(built.config) is built
    assert ready.preparation.prepared is None
    ready.preparation.prepare(ready.now)
    assert ready.preparation.prepared is not None and ready.preparation.prepared is not built


def _gps(app, lat_deg: float, lon_deg: float) -> None:
    """A 3D fix from the flight controller, now."""
    app.handle(_msg("GPS_RAW_INT", time_usec=int(app.now * 1e6), fix_type=3, lat=round(lat_deg * 1e7),
                    lon=round(lon_deg * 1e7), alt=0, eph=100, epv=100, vel=0, cog=0, satellites_visible=12))


def test_a_gps_start_drifting_within_the_distance_keeps_the_mission_and_beyond_it_rebuilds(ready):
    """A boat at its mooring: the GPS start moves each fix without a parameter changing."""
    lat, lon = 32.0, 150.0
    _gps(ready, lat, lon)
    assert ready.preparation.start_position()[2] == "GPS"
    ready.preparation.prepare(ready.now)
    built = ready.preparation.prepared
    assert built.config.start_lat_deg == pytest.approx(lat, abs=1e-6)
    _gps(ready, lat + 0.5 * PREPARED_START_M * DEG_PER_M, lon)
    ready.preparation.prepare(ready.now)
    assert ready.preparation.prepared is built
    _gps(ready, lat + 2.0 * PREPARED_START_M * DEG_PER_M, lon)
    ready.preparation.prepare(ready.now)
    assert ready.preparation.prepared is not built
    assert ready.preparation.prepared.config.start_lat_deg == pytest.approx(lat + 2.0 * PREPARED_START_M * DEG_PER_M,
                                                                            abs=1e-6)

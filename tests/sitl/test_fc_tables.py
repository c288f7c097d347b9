"""ArduPilot's own field tables as the truth (sitl/world/fc_tables.py) and the preset built on them.

Oracles: pymavlink's own interpolation of the same tables (``mavextra.get_mag_field_ef``); the
intensity measured on the ArduPilot SITL binary in ../shared/ardupilot at three points of the Pacific
route (ArduPilot minus WMM2020: +114, +79, +193 nT; README "Flying with ArduPilot"); the steered
heading of the in-process vehicle for the sampled heading.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavextra

from companion.nav.field import model_for_date
from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import InProcessFlight, fly_batch, fly_in_process
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from sitl.world.fc_tables import ardupilot_tables


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-59.9, 59.9), lon=st.floats(-179.9, 179.9))
def test_tables_interpolate_as_ardupilot_does(lat, lon):
    decl, incl, gauss = mavextra.get_mag_field_ef(lat, lon)
    e = ardupilot_tables().elements(lat, lon)
    assert e.decl_deg == pytest.approx(decl, abs=1e-9)
    assert e.incl_deg == pytest.approx(incl, abs=1e-9)
    assert e.f_nt == pytest.approx(gauss * 1e5, abs=1e-6)
    assert math.hypot(e.h_nt, e.z_nt) == pytest.approx(e.f_nt)
    assert math.degrees(math.atan2(e.y_nt, e.x_nt)) == pytest.approx(decl, abs=1e-9)


@pytest.mark.parametrize("lat, lon, measured_nt", [(33.0, 152.0, 114.0), (30.5, 155.0, 79.0), (28.0, 158.0, 193.0)])
def test_tables_are_the_field_measured_on_the_firmware(lat, lon, measured_nt):
    wmm = model_for_date(2024.36).elements(lat, lon, 0.0, 2024.36)
    assert ardupilot_tables().elements(lat, lon).f_nt - float(wmm.f_nt) == pytest.approx(measured_nt, abs=2.0)


def test_arrays_and_scalars_agree():
    lats, lons = np.array([33.0, 28.0]), np.array([152.0, 158.0])
    many = ardupilot_tables().elements(lats, lons)
    for k in range(2):
        one = ardupilot_tables().elements(float(lats[k]), float(lons[k]))
        assert float(many.incl_deg[k]) == pytest.approx(one.incl_deg)


def test_the_ardupilot_world_measures_heading_and_gravity_inclination_as_the_companion():
    """In the ArduPilot preset (compass yaw through a 2-deg tilt bias) the sampled period's levelled
    heading is the steered heading, and the inclination the heading-free navigator gets is the
    gravity-referenced one (the FC-attitude I is off by the tilt bias)."""
    scenario = load_scenario("pacific_ardupilot")
    config = NavConfig.from_values({**validate_all({}), **scenario.nav_overrides(), "NAV_MAX_STEPS": 6})
    result = fly_in_process(config, scenario, 3, build_truth_field(scenario, seed=3), keep_commands=True)
    truth = ardupilot_tables()
    for k in range(3, len(result.elements)):
        avg, previous = result.elements[k], result.commands[k - 1]
        steered = math.degrees(previous.course_rad)              # plus the run's course bias, the same every step
        if k == 3:
            bias = (avg.mag_heading_deg + truth.elements(result.true_lat_deg[k], result.true_lon_deg[k]).decl_deg
                    - steered + 180.0) % 360.0 - 180.0
            assert abs(bias) < 6.0                               # 1.5 deg sigma: a draw within 4 sigma
        got = avg.mag_heading_deg + truth.elements(result.true_lat_deg[k], result.true_lon_deg[k]).decl_deg
        assert abs((got - steered - bias + 180.0) % 360.0 - 180.0) < 0.1
        true_incl = truth.elements(result.true_lat_deg[k], result.true_lon_deg[k]).incl_deg
        assert abs(avg.incl_grav_deg - true_incl) < 0.05


def test_magnetic_heading_source_resolves_auto_to_heading_free():
    """As the companion does with a compass-derived yaw: auto, and (D, I), become (I, F)."""
    scenario = replace(load_scenario("pacific_ardupilot"))
    config = NavConfig.from_values({**validate_all({}), **scenario.nav_overrides(), "NAV_MAX_STEPS": 3,
                                    "NAV_ELEMENTS": 1})
    flight = InProcessFlight(config, scenario, 0, build_truth_field(scenario, seed=0))
    fly_batch([flight])
    assert flight.mission.measured.names == ("incl_deg", "f_nt")
    assert math.isfinite(flight.result().elements[-1].incl_grav_deg)

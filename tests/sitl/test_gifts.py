"""Gift-free by default (issue 46, item 5): every bundled preset is realistic unless its name starts
with ``paper_``, and a paper world says what it hands the navigator that a vehicle would not have.

Realistic means, checked on each preset's built world: the flight controller's yaw comes from the
INS or the compass (never the true heading), the truth field is not the navigator's map, and the
vehicle starts a GPS error away from the start the navigator is given.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.nav.field import model_for_setting
from companion.nav.geo import geodesic_distance_m, geodesic_direct, geodesic_inverse
from companion.params import NavConfig, validate_all
from sitl.gifts import gift_line, gifts
from fcmpc.montecarlo.inprocess import InProcessFlight
from sitl.scenario import ALIASES, PAPER_PREFIX, SCENARIO_DIR, StormConfig, load_scenario
from sitl.sensors import make_error_models
from sitl.world.build import build_truth_field

REALISTIC = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml") if not p.stem.startswith(PAPER_PREFIX))
PAPER = sorted(p.stem for p in SCENARIO_DIR.glob(f"{PAPER_PREFIX}*.toml"))


def test_the_plain_names_are_realistic_and_the_paper_worlds_kept():
    assert {"pacific", "long_storm", "short_storm"} <= set(REALISTIC)
    assert {"paper_pacific", "paper_long_storm", "paper_short_storm"} <= set(PAPER)
    for old, new in ALIASES.items():            # the old names of the realistic presets still load them
        assert load_scenario(old) == load_scenario(new)


def _route_points(scenario, count: int = 5) -> list[tuple[float, float]]:
    distance = geodesic_distance_m(scenario.start_lat_deg, scenario.start_lon_deg, scenario.dest_lat_deg,
                                   scenario.dest_lon_deg)
    _, course = geodesic_inverse(scenario.start_lat_deg, scenario.start_lon_deg, scenario.dest_lat_deg,
                                 scenario.dest_lon_deg)
    return [geodesic_direct(scenario.start_lat_deg, scenario.start_lon_deg, course, distance * k / (count - 1))
            for k in range(count)]


@pytest.mark.parametrize("name", REALISTIC)
def test_no_default_preset_gives_the_true_heading_its_map_as_truth_or_the_exact_start(name):
    scenario = load_scenario(name)
    # the FC's yaw: from the INS or the compass, with its errors in the built world
    assert scenario.heading_source in ("ins", "magnetic")
    errors = make_error_models(scenario, np.random.default_rng(0), np.random.default_rng(1))
    assert errors.attitude is not None and errors.attitude.config.heading_source == scenario.heading_source
    # the truth (its quiet part: the storm is the same in either case) is not the navigator's map
    nav = NavConfig.from_values(validate_all(scenario.nav_overrides()))
    truth = build_truth_field(replace(scenario, storm=StormConfig(enabled=False)), seed=0)
    world_map = model_for_setting(nav.year, nav.wmm)
    # (everywhere by more than rounding; somewhere by tens of nT: the crust is weak in places, 14 nT at 40S 160E)
    largest = []
    for lat, lon in _route_points(scenario):
        true_ned = np.asarray(truth.field_ned_nt(np.array([lat]), np.array([lon]), scenario.alt_m, np.array([0.0])))
        mapped = world_map.elements(lat, lon, scenario.alt_m, nav.year)
        map_ned = np.array([mapped.h_nt * math.cos(math.radians(mapped.decl_deg)),
                            mapped.h_nt * math.sin(math.radians(mapped.decl_deg)), mapped.z_nt])
        largest.append(np.abs(true_ned.ravel() - map_ned).max())
        assert largest[-1] > 1.0, (name, lat, lon)
    assert max(largest) > 20.0, name
    # the vehicle starts a GPS error away from the start the navigator flies from
    assert not scenario.exact_start and scenario.sensors.gps_noise_m > 0.0
    flight = InProcessFlight(nav, scenario, 0, truth)
    offset = geodesic_distance_m(flight.state.lat_deg, flight.state.lon_deg, nav.start_lat_deg, nav.start_lon_deg)
    assert 0.0 < offset < 6.0 * scenario.sensors.gps_noise_m
    assert flight.mission.config.start_lat_deg == nav.start_lat_deg
    assert "true heading" not in gift_line(scenario) and "own map" not in gift_line(scenario)


def test_the_start_error_has_the_gps_spread_and_is_seeded():
    scenario = load_scenario("pacific")
    sigma = scenario.sensors.gps_noise_m
    starts = [scenario.true_start(np.random.default_rng(seed)) for seed in range(400)]
    offsets = [geodesic_distance_m(lat, lon, scenario.start_lat_deg, scenario.start_lon_deg) for lat, lon in starts]
    # the distance of a 2-D normal error is Rayleigh: mean sigma sqrt(pi/2), 400 draws: +-3.3 %
    assert np.mean(offsets) == pytest.approx(sigma * math.sqrt(math.pi / 2.0), rel=0.12)
    assert scenario.true_start(np.random.default_rng(3)) == starts[3]
    exact = replace(scenario, exact_start=True)
    assert exact.true_start(np.random.default_rng(3)) == (scenario.start_lat_deg, scenario.start_lon_deg)


@pytest.mark.parametrize("name", PAPER)
def test_a_paper_world_says_its_gifts(name):
    scenario = load_scenario(name)
    line = gift_line(scenario)
    assert line.startswith(f"{name} hands the navigator what a vehicle would not have: ")
    for words in ("the true heading", "its own map (WMM) as the truth field", "the exact start"):
        assert words in line
    # from the configuration, not the name: the same world under another name says the same
    assert gifts(replace(scenario, name="anything")) == gifts(scenario)
    honest = replace(scenario, exact_start=False, attitude=load_scenario("pacific").attitude)
    assert "the exact start (no GPS error)" not in gifts(honest) and "the true heading" not in gift_line(honest)

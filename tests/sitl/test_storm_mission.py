"""A seeded mission under the short storm completes, and the filter handles storms no worse than the fix alone."""
from __future__ import annotations

import pytest

from companion.params import NavConfig, validate_all
from sitl.inprocess import fly_in_process
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field


@pytest.fixture(scope="module")
def short_storm(shared_data):
    scenario = load_scenario("short_storm")
    return scenario, build_truth_field(scenario, shared_data)


def test_seeded_short_storm_mission_completes(short_storm):
    scenario, truth = short_storm
    nav = NavConfig.from_values(validate_all(scenario.nav_overrides()))
    result = fly_in_process(nav, scenario, seed=3, truth=truth)
    assert result.phase == "arrived", result.reason
    # reproducible: the same seed flies the same track
    again = fly_in_process(nav, scenario, seed=3, truth=truth)
    assert again.remaining_m == result.remaining_m and again.iterations == result.iterations


@pytest.mark.parametrize("name", ["short_storm", "long_storm"])
def test_storm_handling_is_no_worse_than_the_fix_alone(shared_data, name):
    """Same seed, the default navigator (the error-state filter with disturbance-gated bias
    states) against the paper's path (FUS_MODEL 1: the geomagnetic fix alone on this route): the
    storm must not cost the filter more than it costs the fix. Fails if the storm handling gets
    worse. Seed 3 (measured: short storm 23.8 vs 29.4 km, long storm 1.4 vs 18.3 km)."""
    scenario = load_scenario(name)
    truth = build_truth_field(scenario, shared_data)
    values = validate_all(scenario.nav_overrides())
    filtered = fly_in_process(NavConfig.from_values(values), scenario, seed=3, truth=truth)
    fix_alone = fly_in_process(NavConfig.from_values({**values, "FUS_MODEL": 1}), scenario, seed=3, truth=truth)
    assert filtered.process_model == "ins" and fix_alone.process_model == "table3"
    assert fix_alone.remaining_m > 10e3          # the storm does cost the fix: the comparison means something
    assert filtered.remaining_m <= fix_alone.remaining_m, (filtered.remaining_m, fix_alone.remaining_m)


def test_quiet_mission_with_the_filter_lands(short_storm):
    """The same seed with the storm off ends within 1.5 km (the filter's quiet miss is 0.2-0.5 km)."""
    scenario, _ = short_storm
    quiet_truth = build_truth_field(load_scenario("pacific"))
    nav = NavConfig.from_values(validate_all(scenario.nav_overrides()))
    quiet = fly_in_process(nav, scenario, seed=3, truth=quiet_truth)
    assert quiet.remaining_m < 1500.0

"""The storm worlds' space-weather feed, and the storm walk their navigators declare: derived from
the world's own disturbance (sitl.world.build.storm_component_rates), not tuned."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.params import NavConfig, validate_all
from sitl.inprocess import fly_in_process
from sitl.scenario import load_scenario
from sitl.storms import component_rates
from sitl.world.build import build_truth_field, storm_component_rates


@pytest.mark.parametrize("name", ["long_storm", "short_storm"])
def test_declared_storm_walk_is_the_worlds_own_rate(shared_data, name):
    """The [navigator] table's FUS_BQA_N/E/Z are the rms hourly change of the scenario's storm
    along its route in mission time, to the 0.1 nT/rt(h) they are written with."""
    scenario = load_scenario(name)
    declared = dict(scenario.navigator)
    rates = storm_component_rates(scenario, shared_data)
    assert [declared["FUS_BQA_N"], declared["FUS_BQA_E"], declared["FUS_BQA_Z"]] == \
        pytest.approx(rates, abs=0.051)


def test_component_rates_of_a_random_walk_recover_its_rate():
    """A disturbance that is a random walk of 30, 10, 5 nT per sqrt(hour) (1-minute steps, 400 h)
    gives those rates back within 5 %."""
    rng = np.random.default_rng(3)
    minutes = 400 * 60
    steps = rng.standard_normal((minutes + 1, 3)) * np.array([30.0, 10.0, 5.0]) / math.sqrt(60.0)
    walk = np.cumsum(steps, axis=0)
    rates = component_rates(lambda lat, lon, t: walk[np.round(t / 60.0).astype(int)], (30.0, 150.0), (29.0, 151.0),
                            minutes * 60.0)
    np.testing.assert_allclose(rates, [30.0, 10.0, 5.0], rtol=0.05)


def test_the_feed_gives_the_storms_kp_and_nothing_without_a_storm(shared_data):
    """10 May 2024 18-24 UTC was Kp 9- (8.667) throughout; the quiet world and a storm switched off
    have no feed (NaN: the navigator's innovations alone decide)."""
    storm = load_scenario("long_storm")
    truth = build_truth_field(storm, shared_data)
    assert truth.kp(0.0) == pytest.approx(8.667) and truth.kp(12 * 3600.0) == pytest.approx(8.667)
    off = build_truth_field(replace(storm, storm=replace(storm.storm, enabled=False)), shared_data)
    assert math.isnan(off.kp(0.0)) and math.isnan(build_truth_field(load_scenario("pacific")).kp(0.0))
    assert math.isnan(replace(truth, space_weather=None).kp(0.0))
    assert math.isnan(replace(truth, storm_scale=0.0).kp(0.0))


def test_the_feed_reaches_the_navigator_as_a_declared_storm(shared_data):
    """In-process, the storm world's Kp declares the storm from the first step: every command says
    disturbed; with the threshold above 9 nothing is declared and the first steps are quiet."""
    scenario = load_scenario("short_storm")
    truth = build_truth_field(scenario, shared_data)
    values = validate_all({**scenario.nav_overrides(), "NAV_MAX_STEPS": 6})
    declared = fly_in_process(NavConfig.from_values(values), scenario, 0, truth, keep_commands=True)
    assert all(c.disturbed for c in declared.commands[1:])
    undeclared = fly_in_process(NavConfig.from_values({**values, "FUS_KP_ON": 9.0}), scenario, 0, truth,
                                keep_commands=True)
    assert not undeclared.commands[1].disturbed

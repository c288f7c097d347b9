"""The in-process world's analytic measurement is the time average over the whole period.

The companion averages evenly spaced samples over its period, so what it measures describes the
period's midpoint. The analytic path (the ideal and storm presets) must do the same: averaging
only the sub-step ends put the measurement half a sub-step (15 s, ~200 m at 50 km/h) late, and
the navigator, which refers it to the midpoint, then sat ~200 m ahead along its track in every
run (the quiet Pacific's NEES 3.65 instead of ~2).

Oracle: on a noise-free straight leg the inclination varies linearly along the path, so the
averaged I sits halfway between I at the period's two ends (the true positions the run records).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import fly_in_process, trapezoid_weights
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field


def test_trapezoid_weights_average_a_linear_quantity_exactly():
    for count in (1, 2, 3, 13):
        weights = trapezoid_weights(count)
        assert weights.sum() == pytest.approx(1.0, abs=1e-15)
        ramp = np.linspace(4.0, 10.0, count)
        assert weights @ ramp == pytest.approx(ramp.mean(), abs=1e-12)


def test_analytic_average_sits_at_the_middle_of_the_period():
    scenario = load_scenario("paper_pacific")
    scenario = replace(scenario, sensors=replace(scenario.sensors, mag_noise_nt=0.0))   # the average alone
    truth = build_truth_field(scenario)
    nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), "NAV_CONTROLLER": 2, "NAV_MAX_STEPS": 60}))
    result = fly_in_process(nav, scenario, 0, truth)
    lat, lon = result.true_lat_deg, result.true_lon_deg
    incl_ends = np.array([truth.decl_incl_deg(np.array([a]), np.array([b]), nav.alt_m, 0.0)[1][0]
                          for a, b in zip(lat, lon)])
    measured = np.array([e.incl_deg for e in result.elements])
    change = np.diff(incl_ends)
    steps = np.flatnonzero(np.abs(change) > 1e-3)      # legs along which I moves measurably
    assert len(steps) >= 30
    # where between the period's start (0) and end (1) the average lies; end-weighted: 0.54
    where = (measured[steps + 1] - incl_ends[steps]) / change[steps]
    assert np.median(where) == pytest.approx(0.5, abs=0.01)

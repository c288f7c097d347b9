"""Missions flown side by side (fcmpc.montecarlo.inprocess.fly_batch, the Monte Carlo's way) are each the
mission flown alone, bit for bit; the stacked INS propagation is each model's own.

Oracle: the single-mission path (fly_in_process, InsErrorModel.propagate), which the Monte
Carlo's statistics were measured with.
"""
from __future__ import annotations

import numpy as np

from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import InProcessFlight, fly_batch, fly_in_process
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from sitl.world.ins import InsErrorConfig, InsErrorModel, propagate_together
from sitl.world.vehicle import VehicleState

FIELDS = ("true_lat_deg", "true_lon_deg", "est_lat_deg", "est_lon_deg", "est_cov_en_m2", "ins_error_m")


def test_stacked_ins_propagation_is_each_models_own_to_the_bit():
    rng = np.random.default_rng(3)
    dts = [30.0, 30.0, 45.0, 30.0, 45.0, 720.0]      # three groups of equal steps, one of many pieces
    alone = [InsErrorModel(InsErrorConfig(), np.random.default_rng(seed), 33.0) for seed in range(len(dts))]
    together = [InsErrorModel(InsErrorConfig(), np.random.default_rng(seed), 33.0) for seed in range(len(dts))]
    for _ in range(20):
        states = [VehicleState(float(rng.uniform(-70.0, 70.0)), 150.0, float(rng.uniform(0.0, 6.3)),
                               float(rng.uniform(0.0, 30.0))) for _ in dts]
        for model, dt, s in zip(alone, dts, states):
            model.propagate(dt, s.lat_deg, s.vel_east_mps, s.vel_north_mps)
        propagate_together(together, dts, states)
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a.state, b.state)
        assert a.rng.normal() == b.rng.normal()       # the same draws taken from each stream


def test_missions_flown_side_by_side_are_each_the_mission_flown_alone():
    """Mixed controllers, seeds and control periods (sub-step counts), some ending before others."""
    scenario = load_scenario("paper_pacific")
    truth = build_truth_field(scenario)
    runs = [({"NAV_CONTROLLER": 2, "NAV_MAX_STEPS": 12}, 0), ({"NAV_CONTROLLER": 1, "NAV_MAX_STEPS": 8}, 1),
            ({"NAV_CONTROLLER": 0, "NAV_MAX_STEPS": 10, "NAV_PERIOD_S": 180.0}, 2),
            ({"NAV_CONTROLLER": 2, "NAV_MAX_STEPS": 6, "NAV_PERIOD_S": 720.0}, 1)]
    navs = [(NavConfig.from_values(validate_all({**scenario.nav_overrides(), **values})), seed)
            for values, seed in runs]
    alone = [fly_in_process(nav, scenario, seed, truth) for nav, seed in navs]
    together = fly_batch([InProcessFlight(nav, scenario, seed, truth) for nav, seed in navs])
    assert [r.iterations for r in alone] == [12, 8, 10, 6]
    for a, b in zip(alone, together):
        assert (a.phase, a.reason, a.iterations, a.duration_s) == (b.phase, b.reason, b.iterations, b.duration_s)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_a_navigator_set_to_another_date_than_the_world_flies_its_own_model():
    """The ideal world hands the navigator the truth's own WMM only when it is the model the
    navigator picks for its NAV_YEAR. A navigator four and a half years off (NAV_YEAR 2029: WMM2025)
    raised before (WMM2020, the world's, refused 2029); now it flies with its own model, and the
    secular variation it did not expect puts it kilometres off where the matched one is not."""
    scenario = load_scenario("paper_pacific")
    truth = build_truth_field(scenario)
    matched = fly_in_process(NavConfig.from_values(validate_all(scenario.nav_overrides())), scenario, 0, truth)
    dated = fly_in_process(NavConfig.from_values(validate_all({**scenario.nav_overrides(), "NAV_YEAR": 2029.0})),
                           scenario, 0, truth)
    assert matched.arrived and dated.arrived
    assert matched.remaining_m < 1000.0 < dated.remaining_m, (matched.remaining_m, dated.remaining_m)

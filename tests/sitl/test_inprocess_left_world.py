"""A vehicle that leaves the simulated world (the route's crust grid) ends its run as a failure the
Monte Carlo counts, with the reason, instead of crashing the whole Monte Carlo."""
from __future__ import annotations

from dataclasses import replace

from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import InProcessFlight, fly_batch
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field


def test_a_vehicle_beyond_the_crust_grid_is_a_failed_run_with_its_reason():
    scenario = load_scenario("pacific")
    nav = NavConfig.from_values(validate_all(dict(scenario.nav_overrides())))
    truth = build_truth_field(scenario)
    stays, leaves = InProcessFlight(nav, scenario, 1, truth), InProcessFlight(nav, scenario, 2, truth)
    leaves.state = replace(leaves.state, lat_deg=60.0)   # carried 27 deg north: outside the route's grid
    stayed, left = fly_batch([stays, leaves])
    assert left.phase == "failed" and "leaves the crust grid" in left.reason
    assert left.remaining_m > 3e6
    assert stayed.phase == "arrived"    # the other run of the batch flies on to its end

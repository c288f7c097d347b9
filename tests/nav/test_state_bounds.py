"""The QP's state bounds S_min, S_max (eq. 34; ``companion.nav.mission.state_bounds``): from the
mission's own field by default, Table 4's values refused where they cannot hold the destination,
and a current state beyond them admitted (MPC_S_ADMIT) instead of failing the mission."""
from __future__ import annotations

import numpy as np
import pytest

from companion.nav.field import model_for_date
from companion.nav.mission import Mission, Phase
from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import fly_in_process
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from tests.nav.test_mission import fly_noiseless


def test_destination_outside_the_state_bounds_is_refused_at_start():
    """Table 4's S_min = [-10, 10] (MPC_S_AUTO 0) excludes the southern hemisphere (I < 0): a clear
    error naming the parameters instead of an infeasible QP in flight."""
    nav = NavConfig.from_values(validate_all({"NAV_START_LAT": -35.0, "NAV_START_LON": 149.0,
                                              "NAV_DEST_LAT": -36.0, "NAV_DEST_LON": 150.0, "MPC_S_AUTO": 0}))
    with pytest.raises(ValueError, match="MPC_S_MIN_I"):
        Mission(nav)
    wide = nav.replace(s_min_i=-90.0, s_min_d=-180.0, s_max_d=180.0)
    assert Mission(wide).s_dest[1] < 0.0


@pytest.mark.parametrize("start, dest", [((-35.0, 149.0), (-35.5, 150.0)), ((1.0, -30.0), (-0.5, -29.0))])
def test_any_route_flies_with_the_default_bounds(start, dest):
    """MPC_S_AUTO 1 (default): bounds from the mission's own field, so southern-hemisphere and
    equatorial missions fly and arrive (noiseless world) without touching MPC_S_MIN_*/MAX_*."""
    nav = NavConfig.from_values(validate_all({"NAV_START_LAT": start[0], "NAV_START_LON": start[1],
                                              "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1]}))
    model = model_for_date(nav.year)
    commands, world, mission = fly_noiseless(nav, model)
    assert commands[-1].phase == Phase.ARRIVED, commands[-1]
    assert world.miss_m() < 2.0 * nav.arrive_m
    assert np.all(mission.s_lower <= mission.s_dest) and np.all(mission.s_dest <= mission.s_upper)


@pytest.mark.parametrize("admit", [0, 1])
def test_a_start_beyond_the_bounds_is_admitted_and_the_mission_arrives(admit):
    """Table 4-style bounds (MPC_S_AUTO 0) whose S_min on D (-2 deg) holds the destination (-0.2)
    but not the start (-3.9): with the paper's hard bounds (MPC_S_ADMIT 0) the first cruise QP is
    infeasible and the mission fails 792 km out; admitted, it flies back inside and arrives as the
    same seed does with the automatic bounds (0.11 km)."""
    pacific = load_scenario("paper_pacific")
    nav = NavConfig.from_values(validate_all({**pacific.nav_overrides(), "NAV_CONTROLLER": 2, "MPC_S_AUTO": 0,
                                              "MPC_S_MIN_D": -2.0, "MPC_S_ADMIT": admit}))
    result = fly_in_process(nav, pacific, 0, build_truth_field(pacific))
    if admit:
        assert result.phase == Phase.ARRIVED and result.remaining_m < 500.0, (result.reason, result.remaining_m)
    else:
        assert result.phase == Phase.FAILED and result.reason.startswith("QP failed"), result.reason

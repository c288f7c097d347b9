"""The arrival rule (companion.nav.arrival): Algorithm 1's epsilon, and the destination inside the
estimate's own uncertainty after a final leg (NAV_ARRIVE_SIG)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.nav.arrival import BELOW_EPSILON, arrival_reason, is_final_leg, legs_reason
from companion.nav.field import model_for_date
from companion.nav.mission import Measurement, Mission, Phase
from tests.nav.test_mission import NoiselessWorld, fly_noiseless, nav_config

def test_the_rule_in_each_case():
    """Epsilon ends the mission at once; NAV_ARRIVE_LEGS final legs in a row end it wherever the
    estimate is; 0 legs is the paper's epsilon alone."""
    assert arrival_reason(400.0, 500.0, 0, 3) == BELOW_EPSILON
    assert arrival_reason(400.0, 500.0, 0, 0) == BELOW_EPSILON
    assert arrival_reason(900.0, 500.0, 2, 3) is None
    assert arrival_reason(900.0, 500.0, 3, 3) == legs_reason(3)
    assert arrival_reason(9e5, 500.0, 3, 3) == legs_reason(3)
    assert arrival_reason(900.0, 500.0, 500, 0) is None
    assert is_final_leg(5000.0, 50.0 / 3.6, 360.0) and not is_final_leg(5001.0, 50.0 / 3.6, 360.0)


class NoisyWorld(NoiselessWorld):
    """The noiseless world with white noise of ``noise_deg`` on D and I, declared as their
    standard errors: each fix is kilometres off, and the estimate kilometres uncertain."""

    def __init__(self, nav, model, noise_deg: float, seed: int) -> None:
        super().__init__(nav, model)
        self.noise_deg, self.rng = noise_deg, np.random.default_rng(seed)

    def measure(self) -> Measurement:
        m = super().measure()
        d, i = self.rng.normal(0.0, self.noise_deg, 2)
        return dataclasses.replace(m, decl_deg=m.decl_deg + d, incl_deg=m.incl_deg + i,
                                   decl_se_deg=self.noise_deg, incl_se_deg=self.noise_deg)


def fly_noisy(legs: int, seed: int, noise_deg: float = 0.01, dr_pos_m: float = 10000.0):
    model = model_for_date(2024.36)
    # (FUS_BH_DEG as when the seeds below were measured: this world has no heading-dependent error)
    nav = nav_config(None, FUS_MODEL=3, FUS_R_SRC=1, FUS_DR_POS_M=dr_pos_m, NAV_ARRIVE_LEGS=legs, FUS_BH_DEG=0.1)
    world, mission = NoisyWorld(nav, model, noise_deg, seed), Mission(nav, model)
    mission.set_start_fix(5.0)
    commands = [mission.step(world.measure())]
    while not commands[-1].done and len(commands) < 120:
        commands.append(mission.step(world.fly(commands[-1])))
    reach = nav.speed_mps * nav.period_s
    first_final = next(i for i, c in enumerate(commands) if c.phase == Phase.CRUISE and c.remaining_m <= reach)
    return commands, first_final, world


@pytest.mark.parametrize("seed", [1, 2])
def test_a_vehicle_that_has_flown_to_an_uncertain_destination_stops_instead_of_circling(seed):
    """With the paper's rule alone (NAV_ARRIVE_LEGS 0) the vehicle chases an estimate that moves by
    more than epsilon every period (seeds 1 and 2: 17 and 51 periods after its first final leg);
    with 3 it arrives after three final legs in a row (and the last leg to where the estimate then
    is)."""
    chased, chased_first, _ = fly_noisy(0, seed)
    stopped, stopped_first, world = fly_noisy(3, seed)
    assert len(chased) - chased_first >= 15, (len(chased), chased_first)
    last = stopped[-1]
    assert last.phase == Phase.ARRIVED and last.reason.startswith(legs_reason(3)), last
    assert len(stopped) - stopped_first <= 13, (len(stopped), stopped_first)
    reach = stopped[0].speed_mps * 360.0     # three final legs, then the last leg (NAV_FINAL_LEG)
    assert all(c.phase == Phase.CRUISE and c.remaining_m <= reach for c in stopped[-5:-1]), stopped[-5:]
    ee, _, nn = last.est_cov_en_m2
    assert world.miss_m() <= 3.0 * math.sqrt(ee + nn), (world.miss_m(), last.est_cov_en_m2)


def test_the_last_leg_ends_on_the_estimated_destination():
    """Exact measurements (the estimate is the truth up to linearisation), epsilon 3 km: stopping
    once within epsilon leaves the vehicle up to epsilon off (2.9 km); the last leg (NAV_FINAL_LEG
    1, the default) flies the remainder and ends within metres (22 m). NAV_SPEED_MODE 1 (a
    constant speed, the paper's) stops at once: its leg would overshoot by kilometres."""
    model = model_for_date(2024.36)
    misses = {}
    for final_leg, speed_mode in ((0, 0), (1, 0), (1, 1)):
        nav = nav_config(None, NAV_FINAL_LEG=final_leg, NAV_SPEED_MODE=speed_mode, NAV_ARRIVE_M=3000.0)
        commands, world, _ = fly_noiseless(nav, model)
        last = commands[-1]
        assert last.phase == Phase.ARRIVED, last
        misses[final_leg, speed_mode] = world.miss_m()
        if final_leg and not speed_mode:
            leg = commands[-2]
            assert last.reason == f"{BELOW_EPSILON}, then the last leg" and leg.phase == Phase.CRUISE
            assert leg.speed_mps == pytest.approx(leg.remaining_m / nav.period_s) and leg.remaining_m < nav.arrive_m
        else:
            assert last.reason == BELOW_EPSILON
    assert misses[1, 0] < 50.0 and misses[0, 0] > 1000.0 and misses[1, 1] == misses[0, 0], misses

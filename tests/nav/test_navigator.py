"""The one navigation step (companion.nav.navigator): the measurement it forms from a period's average,
a period it excludes, and what it says about the next period's samples."""
from __future__ import annotations

import math

import pytest

from companion.nav.elements import ElementSet
from companion.nav.mission import Mission
from companion.nav.navigator import Navigator, Period
from companion.nav.period import PeriodAverage
from companion.params import NavConfig, default_values


def _navigator(elements: int, **values) -> Navigator:
    mission = Mission(NavConfig.from_values({**default_values(), "NAV_ELEMENTS": elements, **values}))
    mission.set_start_fix(5.0)
    return Navigator(mission)


def _period(navigator: Navigator, time_s: float, f_extra_nt: float = 0.0, incl_grav_deg: float = math.nan) -> Period:
    """The map's field at the start (where a vehicle that has not moved far is), as a period's average."""
    c = navigator.mission.config
    e = navigator.mission.model.elements(c.start_lat_deg, c.start_lon_deg, c.alt_m, c.year)
    average = PeriodAverage(float(e.decl_deg), float(e.incl_deg), 3600, time_s - 180.0, time_s - 360.0, time_s,
                            f_nt=float(e.f_nt) + f_extra_nt, incl_grav_deg=incl_grav_deg, grav_count=3000,
                            decl_se_deg=0.01, incl_se_deg=0.01, f_se_nt=3.0, incl_grav_se_deg=0.02)
    return Period(time_s, average, 360.0 if time_s else 0.0)


@pytest.mark.parametrize("elements, gravity", [(ElementSet.HEADING_FREE, True), (ElementSet.PAPER, False)])
def test_a_heading_free_set_measures_the_gravity_referenced_inclination_and_h_z_from_it(elements, gravity):
    navigator = _navigator(elements)
    period = _period(navigator, 0.0, incl_grav_deg=47.5)
    meas = navigator.measurement(period)
    incl = 47.5 if gravity else period.average.incl_deg
    assert meas.incl_deg == incl and meas.incl_se_deg == (0.02 if gravity else 0.01)
    assert meas.h_nt == pytest.approx(period.average.f_nt * math.cos(math.radians(incl)), rel=1e-15)
    assert meas.z_nt == pytest.approx(period.average.f_nt * math.sin(math.radians(incl)), rel=1e-15)
    assert math.isfinite(meas.h_se_nt) and math.isfinite(meas.z_se_nt)


def test_an_implausible_period_is_excluded_and_the_last_command_flies_on():
    navigator = _navigator(ElementSet.PAPER)
    first = navigator.step(_period(navigator, 0.0))
    assert first.command is not None and first.judgement is None and first.settle
    assert navigator.plausibility.f_reference_nt == pytest.approx(0.0, abs=1e-6)   # learnt at the start
    steps = navigator.mission.k
    bad = navigator.step(_period(navigator, 360.0, f_extra_nt=3000.0))             # a 3000 nT offset appears
    assert bad.excluded and bad.judgement.kind == "f_band" and bad.verdict[0] == "WARNING"
    assert navigator.command is first.command and navigator.mission.k == steps   # the core did not step
    good = navigator.step(_period(navigator, 720.0))
    assert good.command is not None and good.judgement.ok and good.verdict[0] == "NOTICE"
    assert navigator.command is good.command and navigator.mission.k == steps + 1


@pytest.mark.parametrize("limit", [0, 2, 5])
def test_after_nav_excl_max_exclusions_in_a_row_the_next_period_is_taken(limit):
    """A wrong |F| reference (or estimate) makes every later period implausible: without a limit the
    vehicle would fly its first command on for good (realistic Pacific, seed 23, before NAV_EXCL_MAX)."""
    navigator = _navigator(ElementSet.PAPER, NAV_EXCL_MAX=limit)
    navigator.step(_period(navigator, 0.0))
    taken = []
    for k in range(1, 9):
        result = navigator.step(_period(navigator, 360.0 * k, f_extra_nt=3000.0))
        assert result.judgement.kind == "f_band" and not result.judgement.ok
        taken.append(not result.excluded)
        if not result.excluded:
            assert "excluded in a row: this one is taken" in result.verdict[1]
    expected = [False] * 8 if limit == 0 else [k % (limit + 1) == 0 for k in range(1, 9)]
    assert taken == expected
    assert navigator.plausibility.excluded == 8 - sum(expected)     # a period taken is not counted excluded


def test_an_excluded_period_after_the_leg_to_the_estimated_destination_ends_the_mission_there():
    """Once the last leg has carried the vehicle to its estimated destination, an excluded period
    ends the mission there (arrived, said as a warning) instead of flying that leg on, blind (the
    ArduPilot lockstep Pacific: 35 periods excluded after the final legs, stopped 77 km away)."""
    from companion.nav.arrival import is_final_leg
    from companion.nav.field import model_for_date
    from companion.nav.mission import Phase
    from tests.nav.test_mission import NoiselessWorld, nav_config

    nav = nav_config(None, distance_m=20e3, NAV_ELEMENTS=1)
    world = NoiselessWorld(nav, model_for_date(nav.year))
    mission = Mission(nav, world.model)
    mission.set_start_fix(5.0)
    navigator = Navigator(mission)

    def period(meas, f_extra_nt: float = 0.0) -> Period:
        average = PeriodAverage(meas.decl_deg, meas.incl_deg, 3600, meas.time_s - 180.0, meas.time_s - 360.0,
                                meas.time_s, f_nt=meas.f_nt + f_extra_nt, decl_se_deg=0.01, incl_se_deg=0.01,
                                f_se_nt=3.0)
        return Period(meas.time_s, average, 360.0 if meas.time_s else 0.0)

    command = navigator.step(period(world.measure())).command
    while not (command.phase == Phase.CRUISE and is_final_leg(command.remaining_m, nav.speed_mps, nav.period_s)):
        command = navigator.step(period(world.fly(command))).command
        assert command is not None and not command.done
    flown = world.fly(command)
    result = navigator.step(period(flown, 3000.0))                     # a 3000 nT offset appears at the end
    assert not result.judgement.ok and result.command is not None and result.command.done
    assert result.command.phase == Phase.ARRIVED and "dead reckoning" in result.command.reason
    assert result.verdict[0] == "WARNING" and "arrived" in result.verdict[1]
    assert result.command.remaining_m < nav.arrive_m and world.miss_m() < nav.arrive_m
    assert navigator.step(period(world.measure(), 3000.0)).command is result.command   # the mission stays ended

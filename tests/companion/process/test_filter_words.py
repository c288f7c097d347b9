"""The words the companion says when its filter's treatment of the field changes
(companion.process.filter_words), on a real Mission's filter driven through its monitor."""
from __future__ import annotations

import math

from companion.nav.field import model_for_date
from companion.nav.mission import Measurement, Mission
from companion.params import NavConfig, default_values
from companion.process.filter_words import FilterWords


def _started_mission() -> Mission:
    """A default (auto: (D, I, F), F while quiet) Fc-MPC mission after its first step at the start."""
    config = NavConfig.from_values(default_values())
    mission = Mission(config)
    mission.set_start_fix(10.0)
    el = model_for_date(config.year).elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    mission.step(Measurement(0.0, float(el.decl_deg), float(el.incl_deg), f_nt=float(el.f_nt)))
    return mission


def test_each_change_is_said_once_and_nothing_else():
    mission = _started_mission()
    monitor = mission.estimator.filter.monitor
    words = FilterWords()
    assert words.start_words(mission, math.nan, math.nan) == []      # no storm; F as the start words put it
    monitor.declare(False)
    assert words.step(mission, math.nan, math.nan) == []              # nothing changed: F still aside
    monitor.declare(False, index_quiet=True)
    assert [t for t, _ in words.step(mission, 1.0, -5.0)] == ["FcMPC: F weighed: a fresh space-weather reading says quiet"]
    assert words.step(mission, 1.0, -5.0) == []
    monitor.declare(True)
    said = [t for t, _ in words.step(mission, 6.0, -80.0)]
    assert said[0].startswith("FcMPC: storm declared: NAV_KP 6 >= FUS_KP_ON 5, ")
    assert said[1:] == ["FcMPC: F set aside: a storm is declared"]
    monitor.declare(False, index_quiet=True)                          # the storm over; the walk held by the innovations
    assert [t for t, _ in words.step(mission, 3.0, -20.0)] == [
        "FcMPC: storm no longer declared (NAV_KP 3, NAV_SYMH -20): the innovations release the bias walk",
        "FcMPC: F weighed: a fresh space-weather reading says quiet"]
    monitor.active = False
    assert [t for t, _ in words.step(mission, 3.0, -20.0)] == ["FcMPC: disturbance over: the biases walk at the quiet rate"]
    monitor.active = True                                             # found by the innovations alone
    assert [t for t, _ in words.step(mission, 3.0, -20.0)] == ["FcMPC: disturbance found by the innovations: the biases walk faster"]


def test_a_storm_declared_at_the_start_is_said_with_its_reading():
    mission = _started_mission()
    mission.estimator.filter.monitor.declare(True)
    said = FilterWords().start_words(mission, math.nan, -120.0)
    assert len(said) == 1 and said[0][0].startswith("FcMPC: storm declared: NAV_SYMH -120 <= FUS_SYMH_ON -50 nT, ")

"""The element sets (companion.nav.elements) in the navigation filter: which elements it measures.

Oracles: the field model itself (an F residual the filter weighs moves the estimate by the
field's own gradient; one it sets aside moves nothing), and the (D, I) filter's update, which a
weighted set with F set aside must equal to the last bit.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.elements import ElementSet, element_set, resolve_elements
from companion.nav.field import model_for_date
from companion.nav.geo import enu_offset
from companion.nav.mission import Mission
from companion.nav.navfilter import NavigationFilter
from companion.nav.process import DeadReckoningProcess, DeadReckoningSpec
from companion.params import NavConfig, validate_all
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from tests.nav.bare import bare_bias, bare_filter

YEAR, ALT = 2024.36, 0.0
START = (33.0, 152.0)


@pytest.fixture(scope="module")
def model():
    return model_for_date(YEAR)


def _filter(model, elements, settings):
    return NavigationFilter(DeadReckoningProcess(DeadReckoningSpec(), *START, pos_sigma_m=5000.0), elements,
                            settings, model, ALT, YEAR)


def test_weighted_set_measures_three_and_steers_on_two(model):
    weighted = element_set(ElementSet.WEIGHTED)
    assert weighted.names == ("decl_deg", "incl_deg", "f_nt")
    assert weighted.steering().names == ("decl_deg", "incl_deg")
    assert element_set(ElementSet.HORIZONTAL_VERTICAL).heading_free
    # the filter weighs F by its own noise: an F residual moves the estimate less than the
    # same residual in position terms would in D, once F's declared noise is made large
    loose = bare_filter(r_nt=1e4)
    flt = _filter(model, weighted, loose)
    s = weighted.values(model.elements(*START, ALT, YEAR))
    flt.update_elements(s + np.array([0.0, 0.0, 200.0]))
    assert math.hypot(*enu_offset(*START, *flt.position())) < 1.0


def test_a_declared_storm_sets_f_aside_and_keeps_d_and_i(model):
    """(D, I, F) with a storm declared measures D and I only (ElementSet.measured_rows): an F that
    a storm moved by 300 nT moves the estimate without the declaration, not with it, and the
    update is then the (D, I) filter's to the last bit."""
    weighted, pair = element_set(ElementSet.WEIGHTED), element_set(ElementSet.PAPER)
    assert weighted.measured_rows(True, False) == (0, 1) and pair.measured_rows(True, False) == (0, 1)
    assert element_set(ElementSet.HEADING_FREE).measured_rows(True, False) == (0, 1)   # a pair keeps both
    settings = bare_filter(bias=bare_bias(sigma0_nt=1.0))   # F's bias known: its residual is position
    truth = weighted.values(model.elements(*START, ALT, YEAR))
    stormy = truth + np.array([0.0, 0.0, 300.0])
    moved = {}
    for declared in (False, True):
        flt = NavigationFilter(DeadReckoningProcess(DeadReckoningSpec(), *START, pos_sigma_m=5000.0), weighted,
                               settings, model, ALT, YEAR)
        flt.monitor.declare(declared)
        flt.update_elements(stormy)
        moved[declared] = math.hypot(*enu_offset(*START, *flt.position()))
    assert moved[False] > 1000.0 and moved[True] < 1.0, moved
    d_and_i = NavigationFilter(DeadReckoningProcess(DeadReckoningSpec(), *START, pos_sigma_m=5000.0), pair,
                               settings, model, ALT, YEAR)
    d_and_i.monitor.declare(True)
    nis = d_and_i.update_elements(stormy[:2] + np.array([0.01, -0.005]))
    flt = NavigationFilter(DeadReckoningProcess(DeadReckoningSpec(), *START, pos_sigma_m=5000.0), weighted,
                           settings, model, ALT, YEAR)
    flt.monitor.declare(True)
    assert flt.update_elements(stormy + np.array([0.01, -0.005, 0.0])) == nis
    assert flt.position() == d_and_i.position()


def test_set_5_weighs_f_only_while_an_index_says_quiet(model):
    """Set 5 (auto with an independent heading): an F 300 nT off the model moves the estimate
    only while a fresh index says the field is quiet; without an index, or in a declared storm,
    F is set aside and the update is the (D, I) filter's to the last bit."""
    quiet_set, pair = element_set(ElementSet.WEIGHTED_WHEN_QUIET), element_set(ElementSet.PAPER)
    assert quiet_set.names == ("decl_deg", "incl_deg", "f_nt") and quiet_set.steering().names == pair.names
    settings = bare_filter(bias=bare_bias(sigma0_nt=1.0))   # F's bias known: its residual is position
    truth = quiet_set.values(model.elements(*START, ALT, YEAR))
    off = truth + np.array([0.01, -0.005, 300.0])
    moved, nis = {}, {}
    for declared, index_quiet in ((False, False), (False, True), (True, False)):
        flt = _filter(model, quiet_set, settings)
        flt.monitor.declare(declared, index_quiet)
        nis[declared, index_quiet] = flt.update_elements(off)
        moved[declared, index_quiet] = flt.position()
    d_and_i = _filter(model, pair, settings)
    assert d_and_i.update_elements(off[:2]) == nis[False, False] == nis[True, False]
    assert d_and_i.position() == moved[False, False]
    assert math.hypot(*enu_offset(*d_and_i.position(), *moved[False, True])) > 1000.0
    # a storm declared with a quiet reading beside it is a storm
    flt = _filter(model, quiet_set, settings)
    flt.monitor.declare(True, index_quiet=True)
    assert not flt.monitor.index_quiet


@pytest.mark.parametrize("changes, label", [({}, "(D, I, F)"), ({"NAV_ELEMENTS": 1}, "(D, I)"),
                                            ({"NAV_ELEMENTS": 4}, "(D, I, F)"),
                                            ({"NAV_ELEMENTS": 4, "FUS_MODEL": 1}, "(D, I, F)")])
def test_auto_is_f_weighed_while_quiet_and_the_paper_pair_is_asked_for(changes, label):
    """Auto (NAV_ELEMENTS 0) with an independent heading is set 5, (D, I, F) with F weighed only
    while an index says quiet; the paper's (D, I) and set 4 are asked for, and a compass-derived
    yaw makes (I, F) of any of them."""
    config = NavConfig.from_values(validate_all({"NAV_CONTROLLER": 2, **changes}))
    assert Mission(config).measured.label == label
    assert element_set(resolve_elements(config.elements, compass_derived=True)).label == "(I, F)"
    if not changes:
        assert Mission(config).measured.code == ElementSet.WEIGHTED_WHEN_QUIET


@pytest.mark.parametrize("feeds", [{}, {"kp_feed": False}, {"kp_feed": False, "symh_feed": False}])
def test_a_quiet_world_feeds_a_quiet_days_indices_unless_withheld(shared_data, feeds):
    """A world without a storm reports Kp 0 and SYM-H 0 nT (a field nothing disturbs) through its
    space-weather feed; ``[storm] kp_feed`` / ``symh_feed`` false withhold either (NaN)."""
    from dataclasses import replace
    scenario = load_scenario("paper_pacific")
    scenario = replace(scenario, storm=replace(scenario.storm, **feeds))
    truth = build_truth_field(scenario, shared_data)
    for elapsed_s in (0.0, 3600.0, 50000.0):
        assert (truth.kp(elapsed_s) == 0.0) == feeds.get("kp_feed", True)
        assert (truth.symh(elapsed_s) == 0.0) == feeds.get("symh_feed", True)
        assert math.isnan(truth.kp(elapsed_s)) != feeds.get("kp_feed", True)


def test_the_fix_gate_counts_the_elements_the_filter_measures(model):
    """The gate on a far fix is a chi-square with as many degrees of freedom as the elements the
    filter measures this step: set 5 without an index (F set aside) judges every fix of a scan
    from 20 to 200 km east exactly as the (D, I) filter does, and the scan crosses the band where
    a three-element gate would have taken fixes the two-element one rejects."""
    from scipy.stats import chi2

    from companion.nav.estimator import FIX_GATE_PROBABILITY, PositionEstimator
    from companion.nav.geo import offset_position
    from companion.nav.mission import Measurement

    # the paper world's navigator (no model-error states) with the biases known to 0.001 deg: the
    # position's 20 km is then what the innovation is judged in
    ideal = load_scenario("paper_pacific").nav_overrides()
    config = NavConfig.from_values(validate_all({**ideal, "NAV_CONTROLLER": 2, "FUS_MODEL": 3, "FUS_B0_DEG": 1e-3,
                                                 "FUS_B0_NT": 1.0}))

    def measure(lat, lon):
        el = model.elements(lat, lon, ALT, YEAR)
        return Measurement(0.0, float(el.decl_deg), float(el.incl_deg), f_nt=float(el.f_nt))

    judged, nis = {}, []
    for code in (ElementSet.WEIGHTED_WHEN_QUIET, ElementSet.PAPER):
        elements = element_set(code)
        estimator = PositionEstimator(config, model, elements)
        estimator.calibrate_start = False
        at_start = measure(*START)
        estimator.start(at_start, elements.values(at_start), 20e3)   # a start known to 20 km
        estimator.filter.monitor.declare(False)   # as a step without a space-weather index begins
        judged[code] = []
        for east_km in range(20, 201):
            point = offset_position(*START, east_km * 1e3, 0.0)
            far = measure(float(point[0]), float(point[1]))
            judged[code].append(estimator._implausible(elements.values(far), np.zeros(2), far))
            if code == ElementSet.PAPER:
                nis.append(estimator.filter.innovation_nis(elements.values(far), np.zeros(2)))
    assert judged[ElementSet.WEIGHTED_WHEN_QUIET] == judged[ElementSet.PAPER]
    two, three = chi2.ppf(FIX_GATE_PROBABILITY, 2), chi2.ppf(FIX_GATE_PROBABILITY, 3)
    assert any(two < v <= three for v in nis), (min(nis), max(nis))

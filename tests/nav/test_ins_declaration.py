"""The INS the navigator's error-state filter assumes: declared by the operator (``FUS_INS_*``), by
a scenario from its ``[ins]`` table, and kept by the error budget when it switches the INS off.

Oracles: Table 1's numbers (the registry's defaults are the filter's former fixed assumption);
the filter's own initial covariance; the chi-square NEES of a filter whose INS is declared against
one whose INS is not.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.nav.ins_error import DEG_PER_HOUR, InsErrorSpec
from companion.nav.process import InsProcess
from companion.params import NavConfig, validate_all
from companion.registry import SPEC_BY_NAME
from fcmpc.montecarlo.runs import apply_scenario_changes
from sitl.budget import only, with_errors
from fcmpc.montecarlo.inprocess import CHI2_95_2DOF, InProcessFlight, fly_batch, nees_per_step
from sitl.scenario import ins_declaration, load_scenario
from sitl.world.build import build_truth_field

INS_PARAMS = ("FUS_INS_TILT", "FUS_INS_AZ", "FUS_INS_VEL", "FUS_INS_POS", "FUS_INS_GB", "FUS_INS_GM",
              "FUS_INS_GM_TAU", "FUS_INS_VRW")


def test_the_defaults_are_table_1_as_the_filter_assumed_it():
    """With no declaration the filter assumes what it always did: Table 1, the misalignment read
    as arc-seconds, the horizontal velocity error split over the two axes."""
    assert NavConfig().filter.ins == InsErrorSpec()
    assert InsErrorSpec() == InsErrorSpec(50.0, 500.0, 10.0, 5000.0, 0.01, 0.005, 3600.0, 1e-4)
    assert InsErrorSpec().misalign_arcsec == (50.0, 50.0, 500.0)
    assert InsErrorSpec().vel_err_axis_mps == 10.0 / math.sqrt(2.0)


def test_a_declared_ins_reaches_the_filters_covariance():
    """FUS_INS_* values set in the registry are the 1-sigma of the INS process model's P_0."""
    declared = {"FUS_INS_TILT": 20.0, "FUS_INS_AZ": 300.0, "FUS_INS_VEL": 2.0, "FUS_INS_POS": 800.0,
                "FUS_INS_GB": 0.1, "FUS_INS_GM": 0.05, "FUS_INS_GM_TAU": 1800.0}
    spec = NavConfig.from_values(validate_all(declared)).filter.ins
    process = InsProcess(spec, 33.0)
    sigma = np.sqrt(np.diag(process.p0))
    arcsec = math.radians(1.0 / 3600.0)
    np.testing.assert_allclose(sigma[:3], np.array([20.0, 20.0, 300.0]) * arcsec, rtol=1e-12)
    np.testing.assert_allclose(sigma[3:5], 2.0 / math.sqrt(2.0), rtol=1e-12)
    np.testing.assert_allclose(sigma[9:12], 0.1 * DEG_PER_HOUR, rtol=1e-12)
    np.testing.assert_allclose(sigma[12:15], 0.05 * DEG_PER_HOUR, rtol=1e-12)
    assert spec.gyro_markov_tau_s == 1800.0 and process.q_c[12, 12] == pytest.approx(2.0 * (0.05 * DEG_PER_HOUR) ** 2 / 1800.0)
    with pytest.raises(ValueError, match="FUS_INS_GM_TAU"):
        validate_all({"FUS_INS_GM_TAU": 0.0})
    with pytest.raises(ValueError, match="FUS_INS_VRW"):   # a perfect INS, declared, has a covariance of zero
        validate_all({"FUS_INS_VRW": 0.0})


def test_the_companion_says_which_gyros_it_assumes():
    """The start-up STATUSTEXT (the estimator's reason) names the declared gyro drifts."""
    from companion.nav.elements import ELEMENT_SETS, ElementSet
    from companion.nav.estimator import PositionEstimator
    from companion.nav.field import model_for_date
    from companion.nav.step_io import Measurement

    model = model_for_date(2024.36)
    config = NavConfig.from_values(validate_all({"FUS_INS_GB": 0.2, "FUS_INS_GM": 0.07}))
    estimator = PositionEstimator(config, model, ELEMENT_SETS[ElementSet.PAPER])
    e = model.elements(33.0, 152.0, 0.0, 2024.36)
    estimator.start(Measurement(0.0, e.decl_deg, e.incl_deg, 33.0, 152.0, 360.0, e.f_nt),
                    np.array([e.decl_deg, e.incl_deg]), 2.5)
    assert estimator.reason.startswith("INS error model (gyros 0.2 + 0.07 deg/h)"), estimator.reason


def test_a_scenario_declares_its_ins_from_its_ins_table():
    """``[ins]`` gives the declaration: Table 1's scenarios declare exactly the registry's defaults
    (so the presets fly as before); a changed table declares the change; an installation with no
    INS (``onboard = false``) declares nothing."""
    pacific = load_scenario("paper_pacific")
    declared = pacific.nav_overrides()
    assert {name: declared[name] for name in INS_PARAMS[:-1]} == {name: SPEC_BY_NAME[name].default
                                                                   for name in INS_PARAMS[:-1]}
    worse = apply_scenario_changes(pacific, (("ins.gyro_bias_degph", 0.1), ("ins.pos_err_east_m", 7000.0)))
    assert worse.nav_overrides()["FUS_INS_GB"] == 0.1
    assert worse.nav_overrides()["FUS_INS_POS"] == pytest.approx(math.sqrt((7000.0 ** 2 + 5000.0 ** 2) / 2.0))
    assert not set(INS_PARAMS) & set(load_scenario("pacific_ardupilot").nav_overrides())
    # what the [navigator] table sets wins over the declaration
    assert replace(pacific, navigator=(("FUS_INS_GB", 0.02),)).nav_overrides()["FUS_INS_GB"] == 0.02


def test_the_budget_keeps_the_real_ins_declared_when_it_switches_the_ins_off():
    """A world whose INS happens to be perfect does not tell the navigator so: with the INS
    switched off (``--errors -ins``, the budget's rows) the navigator keeps the real INS's datasheet."""
    real = load_scenario("pacific")
    for scenario in (only(real, None), only(real, "crustal"), with_errors(real, {"ins": False}, real)):
        assert scenario.ins.gyro_bias_degph == 0.0
        overrides = scenario.nav_overrides()
        assert {name: overrides[name] for name in INS_PARAMS[:-1]} == ins_declaration(real.ins)


def test_a_worse_ins_is_honest_only_when_declared(shared_data):
    """The Pacific with gyros ten times worse than Table 1 (constant 0.1, Markov 0.05 deg/h), seeds
    0-7 in-process: declared (the scenario's [ins], as a sweep over it declares each cell), the
    filter stays consistent (mean NEES at most 3, at least 6 of 8 misses inside its own 95 %
    ellipse) and the median miss is under 1 km; with Table 1 declared instead it is overconfident
    (mean NEES above 20) and ends far off (median miss above 10 km). Measured on seeds 0-29: 0.34 km
    and NEES 1.89 declared, 85 km and NEES 115 with Table 1."""
    scenario = apply_scenario_changes(load_scenario("paper_pacific"), (("ins.gyro_bias_degph", 0.1),
                                                                 ("ins.gyro_markov_degph", 0.05)))
    truth = build_truth_field(scenario, shared_data)

    def fly(**changes):
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), **changes}))
        runs = fly_batch([InProcessFlight(nav, scenario, seed, truth) for seed in range(8)])
        nees = [nees_per_step(r) for r in runs]
        return (float(np.median([r.remaining_m for r in runs])) / 1e3, float(np.mean([np.nanmean(n) for n in nees])),
                sum(bool(n[-1] <= CHI2_95_2DOF) for n in nees))

    miss, nees, inside = fly()
    assert miss < 1.0 and nees <= 3.0 and inside >= 6, (miss, nees, inside)
    miss_t1, nees_t1, _ = fly(FUS_INS_GB=0.01, FUS_INS_GM=0.005)
    assert miss_t1 > 10.0 and nees_t1 > 20.0, (miss_t1, nees_t1)

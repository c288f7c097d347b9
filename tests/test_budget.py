"""Error sources switched on and off, the predicted fix error, and the budget script (sitl.budget).

Oracles: the scenario fields each switch must set; the navigator's own nonlinear geomagnetic
fix (Newton iteration on WMM) for the linear prediction |G^-1 e|; the budget script end to end
on missions cut to a few steps (its numbers are then meaningless, its table and JSON are not).
"""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from companion.nav.field import geomagnetic_fix, model_for_date
from companion.nav.geo import geodesic_distance_m
from fcmpc.montecarlo.cli import main
from sitl.budget import SOURCES, only, parse_errors, predicted_fix_error, with_errors
from sitl.scenario import load_scenario
from sitl.world.attitude import AttitudeErrorConfig
from sitl.world.build import build_truth_field, expected_mission_duration_s


def test_parse_errors_reads_signs_and_refuses_unknown_sources():
    assert parse_errors("-heading,+crustal") == {"heading": False, "crustal": True}
    assert parse_errors("none,+noise")["noise"] and not parse_errors("none,+noise")["crustal"]
    assert all(parse_errors("all").values()) and set(parse_errors("all")) == set(SOURCES)
    assert parse_errors("main-field") == {"main_field": True}
    with pytest.raises(ValueError, match="unknown error source"):
        parse_errors("-gravity")


def test_switches_set_exactly_their_part_of_the_scenario():
    real, ideal = load_scenario("pacific"), load_scenario("paper_pacific")
    off = with_errors(real, {"heading": False, "crustal": False}, real)
    assert off.attitude == AttitudeErrorConfig() and not off.field_model.crustal.enabled
    assert real.field_model.crust == "emm2017" and off.field_model.crust == "none"   # the real crust too
    assert off.field_model.main == "igrf14" and off.sensors == real.sensors and off.ins == real.ins
    on = with_errors(ideal, {"crustal": True, "calibration": True}, real)
    assert on.field_model.crustal == real.field_model.crustal and on.field_model.main == "wmm"
    assert ideal.field_model.crust == "none" and on.field_model.crust == "emm2017"
    assert on.sensors.mag_hard_iron_resid_nt == real.sensors.mag_hard_iron_resid_nt
    assert on.sensors.mag_noise_nt == ideal.sensors.mag_noise_nt and on.sensors.inprocess_samples
    nothing = only(real, None)
    assert nothing.sensors.mag_noise_nt == 0.0 and nothing.sensors.mag_hard_iron_resid_nt == 0.0
    assert nothing.ins.deterministic and nothing.ins.pos_err_east_m == 0.0 and nothing.field_model.main == "wmm"
    heading = only(real, "heading")          # the INS azimuth is this heading's error: INS on
    assert heading.attitude == real.attitude and heading.ins == real.ins and heading.field_model.main == "wmm"
    ins = only(real, "ins")
    assert ins.attitude == AttitudeErrorConfig() and ins.ins == real.ins
    assert only(real, "all") == real


def test_predicted_main_field_error_matches_the_navigators_own_fix():
    real = load_scenario("pacific")
    duration = expected_mission_duration_s(real)
    predicted = predicted_fix_error(real, "main_field", 0, duration, build_truth_field)
    # the IGRF (D, I) at the destination, fixed on WMM by the navigator's Newton iteration
    igrf = build_truth_field(only(real, "main_field"))
    d, i = (float(v) for v in igrf.decl_incl_deg(real.dest_lat_deg, real.dest_lon_deg, 0.0, 0.0))
    fix = geomagnetic_fix(model_for_date(real.year), d, i, real.dest_lat_deg, real.dest_lon_deg, 0.0, real.year)
    miss = geodesic_distance_m(fix.lat_deg, fix.lon_deg, real.dest_lat_deg, real.dest_lon_deg)
    assert predicted.fix_error_m == pytest.approx(miss, rel=0.05)
    assert miss > 1000.0                                        # a real cost, kilometres


def test_predicted_noise_error_has_the_averaged_noise_spread():
    real = load_scenario("pacific")
    draws = [predicted_fix_error(real, "noise", seed, 57600.0, build_truth_field) for seed in range(400)]
    nav = model_for_date(real.year).elements(real.dest_lat_deg, real.dest_lon_deg, 0.0, real.year)
    sigma_d, sigma_i = real.sensors.averaged_di_noise_deg(360.0, float(nav.h_nt), float(nav.f_nt))
    assert np.std([p.decl_deg for p in draws]) == pytest.approx(sigma_d, rel=0.15)
    assert np.std([p.incl_deg for p in draws]) == pytest.approx(sigma_i, rel=0.15)
    assert predicted_fix_error(real, "ins", 0, 57600.0, build_truth_field).fix_error_m == 0.0


def test_budget_script_writes_its_table(tmp_path, capsys):
    code = main(["--scenario", "pacific", "--budget", "--runs", "1", "--workers", "1", "--quiet",
                 "--param", "NAV_MAX_STEPS=3", "--out", str(tmp_path)])
    assert code == 0
    printed = capsys.readouterr().out
    rows = json.loads((tmp_path / "pacific" / "budget.json").read_text())["rows"]
    assert [r["source"] for r in rows] == ["none", "heading", "main_field", "crustal", "calibration", "noise", "motion",
                                           "ins", "all"]          # no storm in pacific
    for row in rows:
        assert f"| {row['source']} |" in printed and math.isfinite(row["median_km"])
    assert rows[0]["predicted_km"] == 0.0 and rows[-1]["predicted_km"] > 0.0


def test_the_ins_source_switches_the_ins_errors_not_whether_the_vehicle_carries_one():
    real = load_scenario("tasman_2025")
    without = replace(real, ins=replace(real.ins, onboard=False))
    for source in (None, *SOURCES, "all"):
        assert only(without, source).ins.onboard is False, source
        assert only(real, source).ins.onboard is True, source
    assert only(without, None).ins.gyro_bias_degph == 0.0 and only(without, "ins").ins == without.ins


def test_budget_of_a_vehicle_without_an_ins_flies_without_one(tmp_path, capsys):
    code = main(["--scenario", "tasman_2025", "--budget", "--no-ins", "--heading-source", "magnetic", "--runs", "1",
                 "--workers", "1", "--quiet", "--param", "NAV_MAX_STEPS=3", "--out", str(tmp_path)])
    assert code == 0
    saved = json.loads((tmp_path / "tasman_2025" / "budget.json").read_text())
    assert saved["ins_onboard"] is False and saved["heading_source"] == "magnetic"
    assert "(magnetic heading, no INS)" in capsys.readouterr().out


def test_errors_switch_reaches_the_runs(tmp_path, capsys):
    code = main(["--scenario", "paper_pacific", "--errors", "+main_field", "--runs", "1", "--workers", "1", "--quiet",
                 "--controllers", "fc", "--no-plots", "--param", "NAV_MAX_STEPS=3", "--out", str(tmp_path)])
    assert code == 0
    with pytest.raises(SystemExit):
        main(["--scenario", "paper_pacific", "--errors", "-gravity", "--runs", "1", "--quiet"])


@pytest.mark.slow
def test_main_field_alone_costs_what_the_budget_predicts():
    """The budget's one deterministic source: IGRF-14 truth against the navigator's WMM.

    The prediction |G^-1 e| is the error of one geomagnetic fix, which is what Table 3's fusion
    (FUS_MODEL 1) steers on: measured 8.26 km against 8.18 km predicted (README), here within
    25 %. The INS error-state filter (FUS_MODEL 2, what `auto` picks in this world) blends the
    biased fix with an INS that, with this source alone, is perfect: it must miss by less, never
    more. It declares the model error growing with distance (FUS_BQD_*, 2026-12-01), so over 800 km
    it leans on that INS: measured 0.48 km (6.01 km before the distance walk); here under a
    quarter of the predicted fix error.
    """
    from companion.params import NavConfig, validate_all
    from fcmpc.montecarlo.inprocess import fly_in_process

    real = load_scenario("pacific")
    scenario = only(real, "main_field")
    truth = build_truth_field(scenario)
    predicted = predicted_fix_error(real, "main_field", 0, expected_mission_duration_s(real), build_truth_field)
    misses = {}
    for fusion in (1, 2):
        values = {**validate_all(scenario.nav_overrides()), "NAV_CONTROLLER": 2, "FUS_MODEL": fusion}
        result = fly_in_process(NavConfig.from_values(values), scenario, 0, truth)
        assert result.arrived
        misses[fusion] = result.remaining_m
    assert misses[1] == pytest.approx(predicted.fix_error_m, rel=0.25)
    assert misses[2] < 0.25 * predicted.fix_error_m and misses[2] < misses[1]

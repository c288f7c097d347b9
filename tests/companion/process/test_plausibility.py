"""Magnetometer plausibility (issue 10, item 6): the checks on the field model, and in the control step."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from companion.io.records import read_steps_csv
from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.field import element_gradient, model_for_date
from companion.nav.geo import geodesic_distance_m, offset_position
from companion.nav.magnetometer import decl_incl_deg
from companion.nav.mission import Mission
from companion.nav.small import smallest_singular_value
from companion.params import NavConfig, default_values
from companion.nav.plausibility import (
    MIN_GRADIENT_SV,
    Judgement,
    MagPlausibility,
    PlausibilityLimits,
    element_noise,
    judge,
    navigator_bias,
)
from tests.companion.process.rig import _sent

YEAR, LAT, LON = 2020.5, 30.5, 155.0
MODEL = model_for_date(YEAR)
SETS = [ELEMENT_SETS[ElementSet.PAPER], ELEMENT_SETS[ElementSet.HEADING_FREE]]


def _judge_at(elements, lat, lon, f_extra_nt=0.0, sigma_m=800.0, flown_m=5000.0, bias=(0.0, 0.0)):
    """The field measured at (lat, lon) (plus an F offset), judged against the prediction (LAT, LON)."""
    here = MODEL.elements(lat, lon, 0.0, YEAR)
    return judge(MODEL, elements, YEAR, 0.0, elements.values(here) + np.asarray(bias), float(here.f_nt) + f_extra_nt,
                 np.asarray(bias), LAT, LON, sigma_m, flown_m)


@pytest.mark.parametrize("elements", SETS, ids=lambda e: e.label)
def test_the_predicted_field_is_plausible_and_implies_no_jump(elements):
    j = _judge_at(elements, LAT, LON)
    assert j.ok and j.jump_m < 1.0 and abs(j.f_offset_nt) < 1e-6


@pytest.mark.parametrize("elements", SETS, ids=lambda e: e.label)
@pytest.mark.parametrize("east_km, north_km", [(30.0, 0.0), (-20.0, 25.0), (0.0, -40.0)])
def test_a_measurement_from_far_away_is_a_fix_jump_of_about_that_distance(elements, east_km, north_km):
    lat, lon = (float(v) for v in offset_position(LAT, LON, east_km * 1e3, north_km * 1e3))
    true_m = geodesic_distance_m(LAT, LON, lat, lon)
    j = _judge_at(elements, lat, lon)
    assert not j.ok and j.kind == "fix_jump"
    assert j.jump_m == pytest.approx(true_m, rel=0.1)                 # the linearised fix is where it was measured
    near = offset_position(LAT, LON, east_km * 100.0, north_km * 100.0)   # a tenth of the way: within the bound
    assert _judge_at(elements, float(near[0]), float(near[1])).ok


@pytest.mark.parametrize("elements", SETS, ids=lambda e: e.label)
def test_an_intensity_offset_beyond_the_band_is_flagged(elements):
    limits = PlausibilityLimits()
    assert _judge_at(elements, LAT, LON, f_extra_nt=0.9 * limits.f_band_nt).kind != "f_band"
    j = _judge_at(elements, LAT, LON, f_extra_nt=3000.0)
    assert not j.ok and j.kind == "f_band" and j.f_offset_nt == pytest.approx(3000.0)
    assert "+3000 nT" in j.words()


# the standard errors of a 160 s period on PX4 SIH (1000 samples of I_g at ~7 deg each, tilt I and D
# alike, F at 2500 nT / sqrt(1600)): what the averager says there (companion.nav.inclination)
SIH_SE = {"decl_deg": 0.2, "incl_deg": 0.2, "f_nt": 60.0}
ALL_SETS = SETS + [ELEMENT_SETS[ElementSet.HORIZONTAL_VERTICAL]]


@pytest.mark.parametrize("elements", ALL_SETS, ids=lambda e: e.label)
def test_a_noisy_but_unbiased_measurement_is_judged_with_its_noise(elements):
    """A 1.5-sigma draw of the first element at SIH's noise implies a 55-90 km jump: excluded when
    the noise is not known, plausible with the period's standard errors in the bound."""
    here = MODEL.elements(LAT, LON, 0.0, YEAR)
    noise = element_noise(elements, float(here.incl_deg), float(here.f_nt), SIH_SE)
    measured = elements.values(here) + 1.5 * noise * np.array([1.0, 0.0])
    args = (MODEL, elements, YEAR, 0.0, measured, float(here.f_nt), np.zeros(2), LAT, LON, 800.0, 5000.0)
    blind, judged = judge(*args), judge(*args, noise=noise)
    assert not blind.ok and blind.kind == "fix_jump" and blind.jump_m > 50_000.0
    assert judged.ok and judged.jump_m == blind.jump_m
    assert judged.bound_m == pytest.approx(blind.bound_m + judged.noise_m)
    # 3 sigma of the fix: at least the first element's share (its 1-sigma jump is blind.jump_m / 1.5)
    assert judged.noise_m >= 3.0 * blind.jump_m / 1.5 * (1.0 - 1e-9)


@pytest.mark.parametrize("elements", ALL_SETS, ids=lambda e: e.label)
def test_the_noise_term_does_not_hide_a_sustained_3000_nt_offset(elements):
    """3000 nT across the field (|F| +112 nT: inside the F band; I 4.3 deg): still a fix jump, 450-840 km
    against a bound of 170-215 km at SIH's noise."""
    here = MODEL.elements(LAT, LON, 0.0, YEAR)
    ned = np.array([float(here.x_nt), float(here.y_nt), float(here.z_nt)])
    across = np.cross(ned, (0.0, 1.0, 0.0))
    off = ned + 3000.0 * across / np.linalg.norm(across)
    d, i = decl_incl_deg(*off)
    values = {"decl_deg": d, "incl_deg": i, "f_nt": float(np.linalg.norm(off)), "h_nt": math.hypot(off[0], off[1]),
              "z_nt": float(off[2])}
    noise = element_noise(elements, float(here.incl_deg), float(here.f_nt), SIH_SE)
    j = judge(MODEL, elements, YEAR, 0.0, np.array([values[n] for n in elements.names]), values["f_nt"],
              np.zeros(2), LAT, LON, 800.0, 5000.0, noise=noise)
    assert not j.ok and j.kind == "fix_jump" and j.jump_m > 2.0 * j.bound_m and j.noise_m > 100_000.0
    assert "noise" in j.words()


def test_element_noise_maps_f_and_i_into_h_and_z_and_knows_nothing_as_zero():
    hz = ELEMENT_SETS[ElementSet.HORIZONTAL_VERTICAL]
    f, incl, s_i = 50000.0, 60.0, math.radians(0.1)
    h, z = element_noise(hz, incl, f, {"incl_deg": 0.1, "f_nt": 30.0})
    assert h == pytest.approx(math.hypot(30.0 * math.cos(math.radians(incl)), f * math.sin(math.radians(incl)) * s_i))
    assert z == pytest.approx(math.hypot(30.0 * math.sin(math.radians(incl)), f * math.cos(math.radians(incl)) * s_i))
    assert element_noise(SETS[0], incl, f, {"decl_deg": math.nan}).tolist() == [0.0, 0.0]


def test_the_closed_form_singular_value_is_lapacks_and_the_gate_falls_alike():
    """The weak-gradient gate's smallest singular value in closed form: LAPACK's to 1e-9 relative
    over random, near-singular and real gradients, so the gate opens and closes as before."""
    rng = np.random.default_rng(0)
    model = model_for_date(2024.36)
    real = [element_gradient(model, e, lat, lon, 0.0, 2024.36) for e in SETS for lat, lon in
            zip(rng.uniform(-70.0, 70.0, 50), rng.uniform(-180.0, 180.0, 50))]
    random = [rng.normal(0.0, 1.0, (2, 2)) * 10.0 ** rng.uniform(-8, 2) for _ in range(300)]
    near = [np.outer(rng.normal(size=2), rng.normal(size=2)) * 1e-5 + rng.normal(0.0, 1.0, (2, 2)) * 10.0 ** -k
            for k in range(6, 16) for _ in range(20)]
    for g in real + random + near:
        exact = float(np.linalg.svd(g, compute_uv=False)[-1])
        assert smallest_singular_value(g) == pytest.approx(exact, rel=1e-9, abs=1e-12 * np.abs(g).max())
        if abs(exact / MIN_GRADIENT_SV - 1.0) > 1e-6:
            assert (smallest_singular_value(g) < MIN_GRADIENT_SV) == (exact < MIN_GRADIENT_SV)
    with pytest.raises(np.linalg.LinAlgError):   # a NaN gradient as before
        smallest_singular_value(np.array([[math.nan, 1.0], [0.0, 1.0]]))
    assert smallest_singular_value(np.ones((3, 2))) == pytest.approx(0.0, abs=1e-12)


def test_the_start_up_calibration_is_taken_out_before_judging():
    elements = ELEMENT_SETS[ElementSet.HEADING_FREE]
    assert _judge_at(elements, LAT, LON, f_extra_nt=2500.0, bias=(0.0, 2500.0)).ok   # a calibrated 2500 nT bias
    assert not _judge_at(elements, LAT, LON, f_extra_nt=2500.0).ok


def test_the_filters_bias_states_are_taken_out_before_the_fix_but_not_before_the_band():
    """With the error-state filter the fix is judged as the filter will see it: a storm it is
    tracking in its bias states (here 0.3 deg of I, 40-60 km of fix on this route) is no jump. The
    |F| band still judges the sensor against its own start, so an F offset the bias states have
    absorbed is caught there all the same."""
    elements = ELEMENT_SETS[ElementSet.PAPER]
    here = MODEL.elements(LAT, LON, 0.0, YEAR)
    storm = np.array([0.0, 0.3])
    measured = elements.values(here) + storm
    calibration_only = judge(MODEL, elements, YEAR, 0.0, measured, float(here.f_nt), np.zeros(2), LAT, LON,
                             800.0, 5000.0)
    assert calibration_only.kind == "fix_jump"
    tracked = judge(MODEL, elements, YEAR, 0.0, measured, float(here.f_nt), np.zeros(2), LAT, LON, 800.0, 5000.0,
                    fix_bias=storm)
    assert tracked.ok and tracked.jump_m < 100.0
    heading_free = ELEMENT_SETS[ElementSet.HEADING_FREE]
    absorbed = np.array([0.0, 3000.0])
    offset = judge(MODEL, heading_free, YEAR, 0.0, heading_free.values(here) + absorbed, float(here.f_nt) + 3000.0,
                   np.zeros(2), LAT, LON, 800.0, 5000.0, fix_bias=absorbed)
    assert offset.kind == "f_band"


@pytest.mark.parametrize("fus_model", [1, 2])
def test_the_mission_says_which_bias_a_measurement_carries(fus_model):
    """Table 3's path: the start-up calibration, exact. The filter: its bias states and their 1-sigma
    (before its first step, its prior: nothing known)."""
    config = NavConfig.from_values({**default_values(), "FUS_MODEL": fus_model})
    mission = Mission(config)
    assert mission.measured.label == "(D, I, F)"     # auto: the steering pair's bias is judged
    mission.set_bias((0.1, -0.2, 40.0))
    bias, sigma = navigator_bias(mission)
    if fus_model == 1:
        assert bias.tolist() == [0.1, -0.2] and sigma.tolist() == [0.0, 0.0]
    else:
        assert bias.tolist() == [0.0, 0.0] and sigma.tolist() == [config.filter.bias.sigma0_deg] * 2


def test_the_bound_grows_with_the_uncertainty_and_the_distance_flown():
    elements = SETS[0]
    lat, lon = (float(v) for v in offset_position(LAT, LON, 30_000.0, 0.0))
    assert not _judge_at(elements, lat, lon, sigma_m=800.0, flown_m=5000.0).ok
    assert _judge_at(elements, lat, lon, sigma_m=5000.0, flown_m=5000.0).ok        # 3 sigma: 12 km more
    assert _judge_at(elements, lat, lon, sigma_m=800.0, flown_m=40_000.0).ok


def test_exclusions_in_a_row_are_a_sustained_offset_and_recovery_is_said():
    p = MagPlausibility(PlausibilityLimits(sustained_steps=2))
    bad, good = Judgement(False, "f_band", f_offset_nt=3000.0), Judgement(True)
    assert p.verdict(good) is None
    assert p.verdict(bad)[0] == "WARNING"
    severity, text = p.verdict(bad)
    assert severity == "CRITICAL" and "sustained" in text and "3000 nT" in text
    assert p.verdict(bad)[0] == "WARNING"                                 # said once as sustained
    severity, text = p.verdict(good)
    assert severity == "NOTICE" and "after 3 excluded steps" in text and p.excluded == 3
    assert p.verdict(good) is None


def test_the_control_step_excludes_an_offset_measurement_and_keeps_flying(rig):
    """A real core: after the first step, a period with F 3000 nT off is not given to it."""
    app, fc = rig
    config = NavConfig.from_values(default_values())
    app.mission_state.mission = Mission(config)
    start = model_for_date(config.year).elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    ned = np.array([float(start.x_nt), float(start.y_nt), float(start.z_nt)])
    app.mag.averager.add(0.5, float(start.decl_deg), float(start.incl_deg), tuple(ned))
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    first = app.mission_state.command
    assert first.phase == "probe1" and app.mission_state.mission.k == 1
    _sent(fc)
    offset = ned * (1.0 + 3000.0 / float(start.f_nt))                     # |F| 3000 nT more, same direction
    app.mag.averager.add(200.0, float(start.decl_deg), float(start.incl_deg), tuple(offset))
    app.phases.step(app.now, 361.0)
    assert app.mission_state.mission.k == 1 and app.mission_state.command is first                   # the core never saw it
    assert app.mission_state.next_step_m == pytest.approx(361.0 + app.mission_state.mission.config.period_s)
    texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
    # the prediction flew the probe (east, 5 km): the model's F there differs by a few nT
    assert re.search(r"implausible magnetometer step: \|F\| \+30\d\d nT off the model, excluded", texts), texts
    assert app.plausibility.excluded == 1 and app.summary()["mag_excluded_steps"] == 1
    assert math.isfinite(first.course_rad)
    # the record says what was measured, so a reader can tell why it was excluded
    [row] = [r for r in read_steps_csv(app.log_dir / "steps.csv") if r["event"] == "excluded"]
    assert row["f_nt"] == pytest.approx(float(start.f_nt) + 3000.0, abs=1.0)
    assert row["incl_deg"] == pytest.approx(float(start.incl_deg)) and math.isfinite(row["est_lat_deg"])


def test_a_constant_intensity_level_from_the_start_is_not_an_offset(rig):
    """PX4 SIH's |F| sat ~7000 nT below WMM's from power-on: a level present at the start (a scale
    residual, a coarser simulator field) is judged about, so the mission flies; a change still is not."""
    app, fc = rig
    config = NavConfig.from_values({**default_values(), "FUS_MODEL": 1})   # the calibrated constant bias
    app.mission_state.mission = Mission(config)
    start = model_for_date(config.year).elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    ned = np.array([float(start.x_nt), float(start.y_nt), float(start.z_nt)])
    low = ned * (1.0 - 7000.0 / float(start.f_nt))                        # the level from the start on
    app.mag.averager.add(0.5, float(start.decl_deg), float(start.incl_deg), tuple(low))
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    assert app.plausibility.f_reference_nt == pytest.approx(-7000.0, abs=1.0)
    app.mag.averager.add(200.0, float(start.decl_deg), float(start.incl_deg), tuple(low))
    app.phases.step(app.now, 361.0)
    assert app.mission_state.mission.k == 2 and app.plausibility.excluded == 0          # the core flew on the level
    judged = app.stepper.judgement                                        # kept for steps.csv
    assert judged.ok and judged.noise_m == 0.0 and judged.jump_m < judged.bound_m   # one sample: no scatter known
    jumped = ned * (1.0 - 4000.0 / float(start.f_nt))                     # 3000 nT off the level: excluded
    app.mag.averager.add(400.0, float(start.decl_deg), float(start.incl_deg), tuple(jumped))
    app.phases.step(app.now, 722.0)
    assert app.mission_state.mission.k == 2 and app.plausibility.excluded == 1
    _sent(fc)


def test_the_level_is_learnt_with_the_calibration_the_core_subtracts(rig):
    """Table 3's path subtracts a constant start-up calibration: the |F| level is judged net of it,
    not with it subtracted twice (PX4 SIH, +590 nT calibrated, when auto fell back to Table 3 inside
    the first step: later periods were judged ~1000 nT off and excluded)."""
    app, fc = rig
    config = NavConfig.from_values({**default_values(), "NAV_ELEMENTS": 2, "FUS_MODEL": 1})   # (I, F), Table 3
    app.mission_state.mission = Mission(config)
    start = model_for_date(config.year).elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    ned = np.array([float(start.x_nt), float(start.y_nt), float(start.z_nt)])
    level = 700.0
    high = ned * (1.0 + level / float(start.f_nt))                       # the calibrated level, from the start on
    app.mission_state.mission.set_bias(tuple(level if n == "f_nt" else 0.0 for n in app.mission_state.mission.measured.names))
    app.mag.averager.add(0.5, float(start.decl_deg), float(start.incl_deg), tuple(high))
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    assert app.mission_state.mission.estimator is None                                 # Table 3's path, its bias subtracted
    assert app.plausibility.f_reference_nt == pytest.approx(0.0, abs=1.0)
    app.mag.averager.add(200.0, float(start.decl_deg), float(start.incl_deg), tuple(high))
    app.phases.step(app.now, 361.0)
    assert app.mission_state.mission.k == 2 and app.plausibility.excluded == 0
    assert app.stepper.judgement.f_offset_nt == pytest.approx(0.0, abs=50.0)   # the probe's few km: a few nT
    _sent(fc)


def test_an_excluded_period_is_recorded_with_its_verdict(rig):
    """A period whose field belongs 150 km away is excluded as a fix jump, and its row in steps.csv
    carries the verdict (jump, bound, noise term) in the same columns as a step flown."""
    app, fc = rig
    config = NavConfig.from_values({**default_values(), "FUS_MODEL": 1})   # the calibrated constant bias
    app.mission_state.mission = Mission(config)
    model = model_for_date(config.year)
    start = model.elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    app.mag.averager.add(0.5, float(start.decl_deg), float(start.incl_deg),
                         (float(start.x_nt), float(start.y_nt), float(start.z_nt)))
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    far = model.elements(*(float(v) for v in offset_position(config.start_lat_deg, config.start_lon_deg,
                                                              0.0, -150_000.0)), config.alt_m, config.year)
    scale = float(start.f_nt) / float(far.f_nt)       # |F| as at the start: the band passes, the fix jumps
    app.mag.averager.add(200.0, float(far.decl_deg), float(far.incl_deg),
                         (float(far.x_nt) * scale, float(far.y_nt) * scale, float(far.z_nt) * scale))
    app.phases.step(app.now, 361.0)
    assert app.mission_state.mission.k == 1 and app.stepper.judgement.kind == "fix_jump"
    [row] = [r for r in read_steps_csv(app.log_dir / "steps.csv") if r["event"] == "excluded"]
    assert row["jump_m"] == pytest.approx(app.stepper.judgement.jump_m) and row["jump_m"] > 100_000.0
    assert row["bound_m"] == pytest.approx(app.stepper.judgement.bound_m) and row["jump_m"] > row["bound_m"]
    assert row["noise_m"] == pytest.approx(app.stepper.judgement.noise_m)


def _jump(east_m: float, north_m: float, noise_m: float = 0.0) -> Judgement:
    return Judgement(False, "fix_jump", jump_m=math.hypot(east_m, north_m), bound_m=30e3, noise_m=noise_m,
                     offset_en_m=(east_m, north_m))


def test_agreeing_fix_jumps_give_a_shift_and_anything_else_ends_the_run():
    p = MagPlausibility()
    period_m = 13.9 * 360.0
    assert p.agreed_shift(_jump(140e3, 20e3), period_m, 3) is None
    assert p.agreed_shift(_jump(142e3, 19e3), period_m, 3) is None
    assert p.agreed_shift(Judgement(False, "f_band", f_offset_nt=3000.0), period_m, 3) is None   # the sensor
    assert p.agreed_shift(_jump(141e3, 21e3), period_m, 3) is None                  # a new run: one of three
    assert p.agreed_shift(_jump(139e3, 20e3), period_m, 3) is None
    shift, sigma = p.agreed_shift(_jump(140e3, 22e3, noise_m=3000.0), period_m, 3)
    np.testing.assert_allclose(shift, [140e3, 22e3])
    assert 2000.0 < sigma < 5000.0 and p.reanchored == 1 and p.in_a_row == 0
    assert "3 excluded fixes agree: estimate re-anchored 141.7 km" in p.reanchor_words(shift)
    assert all(p.agreed_shift(_jump(140e3, 20e3), period_m, 0) is None for _ in range(5))   # NAV_REANCHOR_N 0


def test_scattered_fix_jumps_are_a_sensor_not_a_wrong_estimate():
    p = MagPlausibility()
    jumps = [_jump(140e3, 0.0), _jump(-60e3, 90e3), _jump(30e3, -120e3), _jump(140e3, 5e3), _jump(-60e3, 85e3)]
    assert all(p.agreed_shift(j, 5000.0, 3) is None for j in jumps)


def test_the_control_step_re_anchors_a_wrong_estimate_on_agreeing_exclusions(rig):
    """A real core whose estimate is 150 km south of the truth (knocked before its second step):
    the companion excludes the next two good periods as fix jumps, the third agrees with them, so
    the core is re-anchored and its estimate is back within a few km; it is said and recorded."""
    app, fc = rig
    config = NavConfig.from_values({**default_values(), "NAV_REANCHOR_N": 3, "FUS_MODEL": 1})
    app.mission_state.mission = Mission(config)
    model = model_for_date(config.year)
    truth = [config.start_lat_deg, config.start_lon_deg]

    def measure(t: float) -> None:
        here = model.elements(truth[0], truth[1], config.alt_m, config.year)
        app.mag.averager.add(t - 0.5, float(here.decl_deg), float(here.incl_deg),
                             (float(here.x_nt), float(here.y_nt), float(here.z_nt)))

    def fly(seconds: float) -> None:
        c = app.mission_state.command
        moved = c.speed_mps * seconds
        truth[:] = (float(v) for v in offset_position(truth[0], truth[1], moved * math.sin(c.course_rad),
                                                      moved * math.cos(c.course_rad)))

    period = config.period_s
    measure(1.0)
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    app.mission_state.mission.reanchor(np.array([0.0, -150e3]), 500.0)      # what one accepted outlier leaves behind
    t = 1.0
    for _ in range(5):
        fly(period)
        t += period
        measure(t)
        app.phases.step(app.now, t)
    texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
    assert "excluded fixes agree: estimate re-anchored 1" in texts, texts
    assert app.plausibility.excluded == 2 and app.plausibility.reanchored == 1
    est = app.mission_state.command
    assert geodesic_distance_m(est.est_lat_deg, est.est_lon_deg, *truth) < 5000.0
    rows = read_steps_csv(app.log_dir / "steps.csv")
    [row] = [r for r in rows if r["event"] == "reanchored"]
    assert 140e3 < row["jump_m"] < 160e3 and 0.0 < row["est_sigma_m"] < 5000.0

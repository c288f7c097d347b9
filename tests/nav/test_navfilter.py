"""The navigation filter (companion.nav.navfilter, process, estimator) and the element sets.

Oracles: one predict + update written out with numpy from the filter's equations (not taken
from the filter); a constant bias observed at a GPS-known start; the chi-square distribution
of a consistent filter's NEES over a seeded Monte Carlo; the field model itself for the
element-set fixes (the fix of the model's own elements at a point is that point).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from companion.nav.disturbance import ACTIVE_ON, ONSET_STEPS, REACTIVE_ON, DisturbanceMonitor
from companion.nav.elements import ELEMENT_SETS, ElementSet, element_set, hz_standard_errors
from companion.nav.field import element_fix, element_gradient, model_for_date
from companion.nav.geo import geodesic_distance_m, offset_position
from companion.nav.mission import Mission
from companion.nav.navfilter import NavigationFilter
from companion.nav.period import PeriodAverage, PeriodAverager
from companion.nav.process import DeadReckoningProcess, DeadReckoningSpec, InsProcess
from companion.params import NavConfig, validate_all
from fcmpc.montecarlo.inprocess import CHI2_95_2DOF, fly_in_process, nees_per_step
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from tests.nav.bare import bare_bias, bare_filter

YEAR, ALT = 2024.36, 0.0
START = (33.0, 152.0)


@pytest.fixture(scope="module")
def model():
    return model_for_date(YEAR)


def test_one_step_matches_the_hand_computation(model):
    """Dead-reckoning filter on (D, I): predict over 360 s, update with one measurement, by hand."""
    settings = bare_filter()
    dr = DeadReckoningSpec()
    process = DeadReckoningProcess(dr, *START, pos_sigma_m=50.0)
    flt = NavigationFilter(process, ELEMENT_SETS[ElementSet.PAPER], settings, model, ALT, YEAR)
    dt, vel = 360.0, np.array([10.0, -9.0])
    # by hand: state (de, dn, dce, dcn, bD, bI)
    b = settings.bias
    p = np.diag([50.0 ** 2] * 2 + [dr.current_sigma_mps ** 2] * 2 + [b.sigma0_deg ** 2] * 2)
    f = np.eye(6)
    f[0, 2] = f[1, 3] = dt
    qc = dr.current_q_mps_rth ** 2 / 3600.0
    step_m = float(np.hypot(*vel)) * dt
    q = np.zeros((6, 6))
    q[0, 0] = q[1, 1] = qc * dt ** 3 / 3.0 + dr.pos_sigma_m ** 2 + (dr.speed_frac * step_m) ** 2
    q[0, 2] = q[2, 0] = q[1, 3] = q[3, 1] = qc * dt ** 2 / 2.0
    q[2, 2] = q[3, 3] = qc * dt
    q[4, 4] = q[5, 5] = b.q_deg_rth ** 2 * dt / 3600.0
    p = f @ p @ f.T + q
    lat, lon = (float(v) for v in offset_position(*START, *(vel * dt)))
    flt.predict(dt, vel, START[0])
    assert flt.position() == pytest.approx((lat, lon), abs=1e-12)
    np.testing.assert_allclose(flt.kf.P, p, rtol=1e-9, atol=1e-12)
    # a measurement 0.01 deg off in D and -0.02 deg in I from the model at the predicted position
    s_model = ELEMENT_SETS[ElementSet.PAPER].values(model.elements(lat, lon, ALT, YEAR))
    measured = s_model + np.array([0.01, -0.02])
    g = element_gradient(model, ELEMENT_SETS[ElementSet.PAPER], lat, lon, ALT, YEAR)
    h = np.hstack([g, np.zeros((2, 2)), np.eye(2)])
    r = np.eye(2) * settings.r_deg ** 2
    y = measured - s_model
    s = h @ p @ h.T + r
    k = p @ h.T @ np.linalg.inv(s)
    x = k @ y
    i_kh = np.eye(6) - k @ h
    p = i_kh @ p @ i_kh.T + k @ r @ k.T
    nis = flt.update_elements(measured)
    assert nis == pytest.approx(float(y @ np.linalg.solve(s, y)), rel=1e-9)
    np.testing.assert_allclose(flt.kf.P, p, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(flt.bias, x[4:6], rtol=1e-9, atol=1e-15)
    # error-state reset: the position error is folded into the nominal position
    assert flt.position() == pytest.approx(tuple(offset_position(lat, lon, x[0], x[1])), abs=1e-12)
    np.testing.assert_allclose(process.current, x[2:4], rtol=1e-9)
    assert np.all(flt.x[:4] == 0.0)


@pytest.mark.parametrize("seed", range(4))
def test_a_constant_bias_is_observed_at_a_gps_start(model, seed):
    """INS filter, GPS-known start: a constant D bias of 0.2 deg (and none in I) measured there
    is estimated to within 3 of the filter's own sigma, and that sigma is the measurement's
    noise, not the 0.5 deg prior."""
    rng = np.random.default_rng(seed)
    settings = bare_filter()
    ins_lat, ins_lon = offset_position(*START, 3000.0, -4000.0)          # INS 5 km off
    flt = NavigationFilter(InsProcess(settings.ins, START[0]), ELEMENT_SETS[ElementSet.PAPER], settings, model,
                           ALT, YEAR)
    flt.update_position(*START, 5.0, ins_lat, ins_lon)
    assert geodesic_distance_m(*flt.position(ins_lat, ins_lon), *START) < 15.0
    truth = np.array([0.2, 0.0])
    s_true = ELEMENT_SETS[ElementSet.PAPER].values(model.elements(*START, ALT, YEAR))
    noise = rng.normal(0.0, settings.r_deg, 2)
    flt.calibrate(s_true + truth + noise, ins_lat, ins_lon)
    sigma = flt.bias_sigma
    assert np.all(np.abs(flt.bias - truth) <= 3.0 * sigma), (flt.bias, sigma)
    assert sigma[0] < 1.5 * settings.r_deg


def test_local_model_error_is_gauss_markov_in_the_distance_travelled(model):
    """With FUS_GM_* the filter carries one local model-error state per element beside the bias
    state: the start-up calibration gives the local states the stationary variance and the bias
    states the rest of the innovation (by hand); over a predict the local mean decays by
    exp(-d / L) with d the distance travelled, not the time (standing still keeps it), and its
    variance relaxes toward the stationary one; the bias states and the reported total (bias
    plus local) follow."""
    spec = bare_bias(local_deg=0.05, local_nt=50.0, local_length_m=25_000.0)
    settings = bare_filter(bias=spec)
    process = DeadReckoningProcess(settings.dead_reckoning, *START, pos_sigma_m=5.0)
    elements = ELEMENT_SETS[ElementSet.HEADING_FREE]                                  # (I, F)
    flt = NavigationFilter(process, elements, settings, model, ALT, YEAR)
    k = process.n
    assert flt.kf.x.shape == (k + 4, 1)
    s_true = elements.values(model.elements(*START, ALT, YEAR))
    y = np.array([0.2, 300.0])
    flt.calibrate(s_true + y)
    r2 = np.array([settings.r_deg, settings.r_nt]) ** 2
    local2 = np.array([0.05, 50.0]) ** 2
    np.testing.assert_allclose(np.diag(flt.kf.P)[k + 2:], local2 * (1 - local2 / (local2 + (y ** 2 - r2 - local2) + r2)),
                               rtol=1e-3)   # the 5 m position prior adds ~1e-4 to S
    np.testing.assert_allclose(flt.bias, y, rtol=0.02)      # the total is the innovation
    local, bias_only, p_before = flt.x[k + 2:].copy(), flt.x[k:k + 2].copy(), flt.kf.P.copy()
    assert np.all(local > 0.0) and np.all(bias_only > local)
    flt.predict(3600.0, np.zeros(2), START[0])                # an hour standing still
    np.testing.assert_allclose(flt.x[k + 2:], local, rtol=1e-12)
    np.testing.assert_allclose(np.diag(flt.kf.P)[k + 2:], np.diag(p_before)[k + 2:], rtol=1e-12)
    flt.predict(2500.0, np.array([6.0, 8.0]), START[0])       # 25 km: one correlation length
    decay = math.exp(-1.0)
    np.testing.assert_allclose(flt.x[k + 2:], local * decay, rtol=1e-12)
    np.testing.assert_allclose(flt.x[k:k + 2], bias_only, rtol=1e-12)
    np.testing.assert_allclose(np.diag(flt.kf.P)[k + 2:], np.diag(p_before)[k + 2:] * decay ** 2
                               + local2 * (1 - decay ** 2), rtol=1e-9)
    np.testing.assert_allclose(flt.bias, bias_only + local * decay, rtol=1e-12)


def test_bias_random_walk_per_distance_travelled(model):
    """FUS_BQD_*: the bias states' variance grows by qd^2 per km travelled on top of the time walk:
    standing an hour adds q^2 only, 28.8 km in an hour adds q^2 + 28.8 qd^2 (by hand)."""
    spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qd_deg_rkm=0.0075, qd_nt_rkm=7.5)
    settings = bare_filter(bias=spec)
    process = DeadReckoningProcess(settings.dead_reckoning, *START, pos_sigma_m=5.0)
    flt = NavigationFilter(process, ELEMENT_SETS[ElementSet.HEADING_FREE], settings, model, ALT, YEAR)
    k = process.n
    before = np.diag(flt.kf.P)[k:k + 2].copy()
    flt.predict(3600.0, np.zeros(2), START[0])
    np.testing.assert_allclose(np.diag(flt.kf.P)[k:k + 2] - before, [0.002 ** 2, 2.0 ** 2], rtol=1e-9)
    before = np.diag(flt.kf.P)[k:k + 2].copy()
    flt.predict(3600.0, np.array([0.0, 8.0]), START[0])
    np.testing.assert_allclose(np.diag(flt.kf.P)[k:k + 2] - before,
                               [0.002 ** 2 + 28.8 * 0.0075 ** 2, 2.0 ** 2 + 28.8 * 7.5 ** 2], rtol=1e-9)


@pytest.mark.parametrize("source, states", [(0, []), (1, [0, 1]), (2, [0, 1, 2])])
def test_elements_measured_with_the_ins_attitude_carry_its_misalignment(model, source, states):
    """FUS_ATT_INS: with the INS's tilt (1) or tilt and heading (2) turning the magnetometer, the
    elements the filter predicts carry misalignment_columns times the estimated misalignment
    (phi_e, phi_n; phi_u), so a measurement that is the model plus exactly that has no innovation;
    with 0, or a dead-reckoning filter, the misalignment is in no element."""
    from companion.nav.disturbance import field_jacobian
    from companion.nav.ins_error import misalignment_columns

    elements = ELEMENT_SETS[ElementSet.WEIGHTED]
    settings = bare_filter(attitude_from_ins=source)
    flt = NavigationFilter(InsProcess(settings.ins, START[0]), elements, settings, model, ALT, YEAR)
    phi = np.radians(np.array([30.0, -50.0, 200.0]) / 3600.0)
    flt.kf.x[0:3, 0] = phi
    centre = flt.window_centre(None, *START)
    ned = np.array(model.ned(*centre, ALT, YEAR))
    carried = misalignment_columns(field_jacobian(elements.names, *ned), ned)[:, states] @ phi[states]
    measured = elements.values(model.elements(*centre, ALT, YEAR)) + carried
    assert flt.innovation_nis(measured, None, *START) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(flt.bias, carried, rtol=1e-12, atol=1e-15)
    dead_reckoning = NavigationFilter(DeadReckoningProcess(DeadReckoningSpec(), *START, 50.0), elements, settings,
                                      model, ALT, YEAR)
    dead_reckoning.innovation_nis(measured, None)
    assert np.all(dead_reckoning.bias == 0.0)


@pytest.mark.parametrize("source, words", [(2, "its attitude levels and turns the magnetometer"),
                                           (1, "its tilt levels the magnetometer"), (0, "")])
def test_the_estimator_says_whose_attitude_turns_the_magnetometer(model, source, words):
    """The companion's start-up STATUSTEXT names the process model and, with the INS, FUS_ATT_INS."""
    from companion.nav.estimator import PositionEstimator
    from companion.nav.step_io import Measurement

    config = NavConfig.from_values(validate_all({"FUS_ATT_INS": source}))
    estimator = PositionEstimator(config, model, ELEMENT_SETS[ElementSet.PAPER])
    e = model.elements(*START, ALT, YEAR)
    estimator.start(Measurement(0.0, e.decl_deg, e.incl_deg, *START, 360.0, e.f_nt), np.array([e.decl_deg, e.incl_deg]),
                    2.5)
    assert estimator.reason.startswith("INS error model")
    assert estimator.reason.endswith(words) and (words or "magnetometer" not in estimator.reason)


@pytest.mark.slow
def test_local_model_error_states_make_the_realistic_world_filter_honest(shared_data):
    """pacific (IGRF-14 + crust against the navigator's WMM, calibration residuals), six
    seeded missions with the INS filter: with the defaults' local model-error states the median
    of the runs' mean NEES is at most 6.5 and under 0.6 of the same runs' without them
    (FUS_GM_* 0 and a still bias, FUS_BQ_DEG 0.0002). Measured: 4.5 against 9.0 (50 seeds:
    mean NEES 7.2 against 27.4, median miss 22.0 against 40.3 km). Both without the heading
    states (FUS_BH_* 0, which came later and are judged in tests/nav/test_heading_residual.py):
    with them on both sides the local states' share is smaller (2.6 against 3.7). The filter is judged
    alone: without its heading states the plausibility check (since 2026-12-06 in the Monte Carlo too)
    excludes the periods whose heading-turned residual it cannot explain, and the runs it leaves are not
    the filter's."""
    from dataclasses import replace

    from fcmpc.montecarlo.inprocess import InProcessFlight, fly_batch

    scenario = load_scenario("pacific")
    truth = build_truth_field(scenario, shared_data)

    def unjudged(flight: InProcessFlight) -> InProcessFlight:
        plausibility = flight.navigator.plausibility
        plausibility.limits = replace(plausibility.limits, f_band_nt=math.inf, margin_m=math.inf)
        return flight

    def median_nees(**changes) -> float:
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), "FUS_BH_DEG": 0.0, "FUS_BH_NT": 0.0,
                                                  **changes}))
        runs = fly_batch([unjudged(InProcessFlight(nav, scenario, seed, truth, keep_commands=True))
                          for seed in range(6)])
        assert all(r.process_model == "ins" for r in runs)
        return float(np.median([np.nanmean(nees_per_step(r)) for r in runs]))

    with_states = median_nees()
    without = median_nees(FUS_GM_DEG=0.0, FUS_GM_NT=0.0, FUS_BQ_DEG=0.0002, FUS_BQ_NT=0.2, FUS_BQD_DEG=0.0,
                          FUS_BQD_NT=0.0)
    assert with_states <= 6.5 and with_states < 0.6 * without, (with_states, without)


@pytest.mark.slow
def test_the_ins_attitude_in_the_measurement_makes_the_realistic_world_filter_more_honest(shared_data):
    """pacific, whose INS's attitude levels and turns the magnetometer: seeds 0-11 in-process,
    the runs' mean NEES with FUS_ATT_INS 2 (the misalignment in the measured elements; what the
    scenario's installation declares) is at most 3 and under 0.85 of the same runs' with 0.
    Measured: 2.49 against 3.42 (50 seeds each half: mean NEES 3.06 / 3.14 against 3.41 / 3.38,
    median miss 13.46 / 14.55 against 14.62 / 15.98 km)."""
    from fcmpc.montecarlo.inprocess import InProcessFlight, fly_batch

    scenario = load_scenario("pacific")
    truth = build_truth_field(scenario, shared_data)
    assert scenario.nav_overrides()["FUS_ATT_INS"] == 2

    def mean_nees(source: int) -> float:
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), "FUS_ATT_INS": source}))
        runs = fly_batch([InProcessFlight(nav, scenario, seed, truth) for seed in range(12)])
        return float(np.mean([np.nanmean(nees_per_step(r)) for r in runs]))

    carried, not_carried = mean_nees(2), mean_nees(0)
    assert carried <= 3.0 and carried < 0.85 * not_carried, (carried, not_carried)


@pytest.mark.slow
def test_without_an_ins_in_ardupilots_world_the_default_filter_arrives():
    """pacific_ardupilot (ArduPilot SITL's field tables, its compass yaw through a 2-deg tilt bias, the
    boat's speed and drift as measured on the firmware, no INS), seeds 0-7, auto: the dead-reckoning
    filter on the measured heading with the model error growing with distance. Its median miss is
    within issue 16's 15 km (measured 8.9 km, 16 seeds 8.9 km), its NEES consistent (mean of the runs'
    means at most 3; measured 1.0) and at least 6 of 8 misses inside its own 95 % ellipse (measured
    8); dead reckoning on the commanded course instead ends farther off (measured 24.6 km)."""
    scenario = load_scenario("pacific_ardupilot")
    truth = build_truth_field(scenario)

    def runs(**changes):
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), **changes}))
        return [fly_in_process(nav, scenario, seed, truth, keep_commands=True) for seed in range(8)]

    default = runs()
    assert all(r.process_model == "dead_reckoning" and r.arrived for r in default)
    miss = np.median([r.remaining_m for r in default]) / 1000.0
    nees = [np.nanmean(nees_per_step(r)) for r in default]
    inside = sum(n[-1] <= CHI2_95_2DOF for n in (nees_per_step(r) for r in default))
    assert miss <= 15.0 and np.mean(nees) <= 3.0 and inside >= 6, (miss, np.mean(nees), inside)
    commanded = np.median([r.remaining_m for r in runs(NAV_DR_HDG=0)]) / 1000.0
    assert commanded > 1.5 * miss, (commanded, miss)


def test_disturbance_needs_a_sustained_rise_of_the_innovations():
    """Calibrated innovations (exactly the variance the filter states, which the measured
    standard errors give) switch the bias noise up in at most 2 % of 200-step missions with
    two elements (designed for 0.4 %) and 1 % with three; innovations twice the threshold's
    size switch it up after ONSET_STEPS steps."""
    rng = np.random.default_rng(0)
    for m, limit in ((2, 0.02), (3, 0.01)):
        false_alarms = 0
        for _ in range(500):
            monitor = DisturbanceMonitor()
            false_alarms += any(monitor.observe(rng.normal(size=m)) for _ in range(200))
        assert false_alarms / 500 <= limit, (m, false_alarms)
    loud = DisturbanceMonitor()
    flags = [loud.observe(np.full(2, 2.0 * math.sqrt(ACTIVE_ON))) for _ in range(ONSET_STEPS + 3)]
    assert flags.index(True) >= ONSET_STEPS - 1 and all(flags[ONSET_STEPS + 1:])
    # after a release, a rise that the first onset would not notice switches it on again
    while loud.active:
        loud.observe(np.zeros(2))
    between = 0.5 * (ACTIVE_ON + REACTIVE_ON)
    assert any(loud.observe(np.full(2, math.sqrt(between))) for _ in range(20))
    assert not any(DisturbanceMonitor().observe(np.full(2, math.sqrt(between))) for _ in range(20))


@pytest.mark.parametrize("requested", [ElementSet.PAPER, 0], ids=["(D, I)", "auto: (D, I, F), a quiet index fed"])
def test_nees_and_nis_of_a_seeded_monte_carlo_are_chi_square(shared_data, requested):
    """Six seeded Pacific missions (Fc-MPC, the INS filter, R from the measured standard
    errors), on the paper's (D, I) and on auto's (D, I, F) (set 5: the world feeds a quiet day's
    index, so F is weighed): the final-step NEES summed over the
    runs lies inside the 99 % interval of chi-square with 2 x 6 degrees of freedom, the mean
    NEES over all steps is near 2 (1.6-2.5: the filter's covariance within about 20 % of its
    errors; measured 1.76 / 1.81 on these seeds and 1.73-1.95 / 1.72-1.81 on each of four groups
    of six, 0-23; with the quiet bias walk the preset declared before 2026-12-04, 1.46 here and
    1.40-1.81 on (D, I): a covariance that outgrew the errors), so is the mean over the last
    quarter of the mission (steps from 120 of about 161: at least 1.5; measured 1.87 / 1.92, and
    1.35 with that walk), and most steps put the truth inside the 95 % ellipse.

    NIS: the mean NIS / m of the cruise updates (from step 3: the start and the two probing steps
    are left out, their NIS / m is about 2, not explained yet) lies inside the 99 % interval of
    chi-square with m x (steps) degrees of freedom over m x steps, its low end lowered by 15 %:
    the floor FUS_RMIN_DEG adds 6-11 % to R here, so the calibrated NIS is expected near 0.92
    (measured 0.85 / 0.85 on these seeds, 0.85-0.93 / 0.85-0.89 on the four groups; with the
    declared FUS_R_DEG it is 0.75 on (D, I), outside). No mission switches the disturbance on (no
    false alarm)."""
    scenario = load_scenario("paper_pacific")
    truth = build_truth_field(scenario, shared_data)
    nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), "NAV_ELEMENTS": requested}))
    m = len(Mission(nav).measured.names)
    assert m == (2 if requested else 3)
    runs = [fly_in_process(nav, scenario, seed, truth, keep_commands=True) for seed in range(6)]
    assert all(r.process_model == "ins" and r.arrived for r in runs)
    assert not any(c.disturbed for r in runs for c in r.commands)
    nis = np.concatenate([[c.nis for c in r.commands[3:]] for r in runs])
    nis = nis[np.isfinite(nis)]
    dof = m * len(nis)
    low, high = chi2.ppf([0.005, 0.995], dof) / dof
    assert 0.85 * low <= nis.mean() / m <= high, nis.mean() / m
    nees = [nees_per_step(r) for r in runs]
    final = sum(float(n[-1]) for n in nees)
    low, high = chi2.ppf([0.005, 0.995], 2 * len(runs))
    assert low <= final <= high, final
    every = np.concatenate([n[np.isfinite(n)] for n in nees])
    assert 1.6 <= every.mean() <= 2.5, every.mean()
    late = np.concatenate([n[120:][np.isfinite(n[120:])] for n in nees])
    assert 1.5 <= late.mean() <= 2.8, late.mean()
    assert np.mean(every <= CHI2_95_2DOF) >= 0.8


@pytest.mark.parametrize("code", [1, 2, 3])
def test_element_fix_inverts_the_field_model(model, code):
    """For each pair, the fix of the model's own elements at a point, started 30 km away, is
    that point (the field model's inverse)."""
    elements = element_set(code)
    point = (30.5, 155.0)
    target = elements.values(model.elements(*point, ALT, YEAR))
    prior = offset_position(*point, 20e3, -22e3)
    fix = element_fix(model, elements, target, float(prior[0]), float(prior[1]), ALT, YEAR)
    assert geodesic_distance_m(fix.lat_deg, fix.lon_deg, *point) < 1.0


def _period_samples(rng, noise_nt: float, count: int = 3600) -> PeriodAverage:
    """One period of NED field samples at the Pacific start with white noise per axis, averaged."""
    ned = np.array([27000.0, -1500.0, 30000.0]) + noise_nt * rng.standard_normal((count, 3))
    averager, nan = PeriodAverager(), np.full((count, 3), np.nan)
    averager.add_samples(np.arange(count) * 0.1, ned, nan[:, 0], nan, nan, nan)
    return averager.take(360.0)


def test_measured_standard_errors_scale_with_the_noise_and_describe_the_mean():
    """Periods with 10x the magnetometer noise measure 10x the standard error of each average
    (within 5 %, five periods each), and the measured standard error is the scatter of the period mean itself:
    over 300 periods the averages' standard deviation and the mean measured error agree within 10 %."""
    rng = np.random.default_rng(3)
    quiet = [_period_samples(rng, 60.0) for _ in range(5)]
    loud = [_period_samples(rng, 600.0) for _ in range(5)]
    for name in ("decl_se_deg", "incl_se_deg", "f_se_nt"):
        # each a MAD estimate good to 2 % (1.17 / sqrt(3600)); five periods each: the ratio to 1.3 %
        ratio = np.mean([getattr(p, name) for p in loud]) / np.mean([getattr(p, name) for p in quiet])
        assert ratio == pytest.approx(10.0, rel=0.05), name
    periods = [_period_samples(rng, 600.0, 900) for _ in range(300)]
    for value, se in (("decl_deg", "decl_se_deg"), ("incl_deg", "incl_se_deg"), ("f_nt", "f_se_nt")):
        scatter = np.std([getattr(p, value) for p in periods], ddof=1)
        assert np.mean([getattr(p, se) for p in periods]) == pytest.approx(scatter, rel=0.10), value


def test_measurement_noise_comes_from_the_measured_standard_errors(model):
    """FUS_R_SRC 1: R = diag(se^2 + floor^2), so 10x the standard error gives 10x the sigma
    (with the floor off; 9-10x with the default floor); a missing standard error falls back to
    the declared noise; FUS_R_SRC 0 always takes the declared noise."""
    def noise(settings, se):
        process = DeadReckoningProcess(DeadReckoningSpec(), *START, pos_sigma_m=50.0)
        flt = NavigationFilter(process, ELEMENT_SETS[ElementSet.WEIGHTED], settings, model, ALT, YEAR)
        return np.sqrt(np.diag(flt.measurement_noise(None if se is None else np.asarray(se, dtype=float))))

    se = np.array([0.002, 0.0015, 2.0])
    bare = bare_filter(r_min_deg=0.0, r_min_nt=0.0)
    np.testing.assert_allclose(noise(bare, 10.0 * se) / noise(bare, se), 10.0, rtol=1e-12)
    ratio = noise(bare_filter(), 10.0 * se) / noise(bare_filter(), se)
    assert np.all((ratio > 9.0) & (ratio <= 10.0)), ratio
    declared = bare_filter(r_source=0)
    np.testing.assert_allclose(noise(declared, 10.0 * se), [declared.r_deg, declared.r_deg, declared.r_nt])
    np.testing.assert_allclose(noise(bare, [math.nan, 0.0015, 2.0]), [bare.r_deg, 0.0015, 2.0])
    np.testing.assert_allclose(noise(bare, None), [bare.r_deg, bare.r_deg, bare.r_nt])


def test_heading_free_standard_errors_follow_from_f_and_i():
    """H = F cos I, Z = F sin I: their standard errors from those of F and I, against a
    Monte Carlo of the same first-order model (within 3 %)."""
    rng = np.random.default_rng(5)
    f, incl, se_f, se_i = 45000.0, 48.0, 5.0, 0.004
    fs = f + se_f * rng.standard_normal(20000)
    incls = np.radians(incl + se_i * rng.standard_normal(20000))
    se_h, se_z = hz_standard_errors(f, incl, se_f, se_i)
    assert se_h == pytest.approx(np.std(fs * np.cos(incls)), rel=0.03)
    assert se_z == pytest.approx(np.std(fs * np.sin(incls)), rel=0.03)


@pytest.mark.parametrize("adapt", [False, True])
def test_covariance_matching_scales_the_active_bias_noise_between_quiet_and_active(model, adapt):
    """FUS_BQA_ADAPT: while a disturbance is active, innovations far smaller than the filter
    predicts (the bias walk so loose that it absorbs every measurement) lower the active noise's
    scale by (NIS / m)^ADAPT_GAIN of the averaged NIS a step, down to the quiet walk and never
    below; innovations far larger hold it at the configured FUS_BQA_* and never above; the
    predict then walks the biases at the scaled noise (by hand). Without it the scale stays 1."""
    spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qa_deg_rth=0.05, qa_nt_rth=40.0, qa_adapt=adapt)
    settings = bare_filter(bias=spec)
    process = DeadReckoningProcess(settings.dead_reckoning, *START, pos_sigma_m=5.0)
    elements = ELEMENT_SETS[ElementSet.PAPER]
    flt = NavigationFilter(process, elements, settings, model, ALT, YEAR)
    k = process.n
    s_true = elements.values(model.elements(*START, ALT, YEAR))
    flt.monitor.active, flt.monitor.activations, flt.monitor.average = True, 1, 1.0   # a storm under way
    scales = []
    for _ in range(12):                     # standing still, measuring the model exactly: NIS ~ 0
        flt.predict(360.0, np.zeros(2), START[0])
        flt.update_elements(s_true, None, standard_errors=np.array([0.002, 0.002]))
        scales.append(flt.qa_scale)
    floor = 0.002 / 0.05
    if not adapt:
        assert scales == [1.0] * 12
        return
    assert all(b <= a for a, b in zip(scales, scales[1:])) and scales[0] < 1.0
    assert scales[-1] == pytest.approx(floor) and min(scales) >= floor
    before = np.diag(flt.kf.P)[k:k + 2].copy()
    flt.predict(3600.0, np.zeros(2), START[0])     # an hour: the biases walk at the scaled active noise
    np.testing.assert_allclose(np.diag(flt.kf.P)[k:k + 2] - before, (np.array([0.05, 0.05]) * floor) ** 2,
                               rtol=1e-9)
    for _ in range(6):                      # then far too loud: back up, but not above FUS_BQA_*
        flt.predict(360.0, np.zeros(2), START[0])
        flt.update_elements(s_true + np.array([0.3, -0.3]), None, standard_errors=np.array([0.002, 0.002]))
        scales.append(flt.qa_scale)
    assert scales[-1] == 1.0 and max(scales) == 1.0
    # a rewind (the estimator's snapshot) takes the scale back with everything else
    state = flt.snapshot()
    flt.qa_scale = 0.5
    flt.restore(state)
    assert flt.qa_scale == 1.0

"""The disturbance model of the bias states (companion/nav/disturbance.py): when a disturbance is
active (the innovations, or a declared Kp), and how a declared storm walks the bias states along
the field components."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.nav.disturbance import (ACTIVE_ON, ONSET_STEPS, RELEASE_STEPS, STORM_SCALE_MAX, DisturbanceMonitor,
                                       StormWalk,
                                       component_walk_covariance, field_jacobian, gauss_markov_step,
                                       stationary_variance, storm_declared)
from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.field import model_for_date
from companion.nav.navfilter import NavigationFilter
from companion.nav.process import DeadReckoningProcess
from tests.nav.bare import bare_bias, bare_filter

YEAR, ALT = 2024.36, 0.0
START = (33.0, 152.0)
NAMES = ("decl_deg", "incl_deg", "f_nt", "h_nt", "z_nt")


def _elements(ned: np.ndarray) -> np.ndarray:
    n, e, z = ned
    h = math.hypot(n, e)
    return np.array([math.degrees(math.atan2(e, n)), math.degrees(math.atan2(z, h)), math.hypot(h, z), h, z])


@settings(max_examples=200, deadline=None)
@given(st.floats(-60000, 60000), st.floats(-60000, 60000), st.floats(-70000, 70000))
def test_field_jacobian_is_the_derivative_of_the_elements(n, e, z):
    """Against central differences of D, I, F, H, Z over 0.01 nT, wherever the field is magnetic
    (|H| at least 1000 nT: the navigator's range; near a magnetic pole D has no meaning)."""
    if math.hypot(n, e) < 1000.0:
        return
    ned = np.array([n, e, z])
    jac = field_jacobian(NAMES, n, e, z)
    step = 0.01
    def central(unit: np.ndarray) -> np.ndarray:
        diff = _elements(ned + step * unit) - _elements(ned - step * unit)
        diff[0] = (diff[0] + 180.0) % 360.0 - 180.0     # D wraps at +-180 deg
        return diff / (2 * step)
    numeric = np.stack([central(unit) for unit in np.eye(3)], axis=1)
    np.testing.assert_allclose(jac, numeric, rtol=1e-5, atol=1e-9)


def test_field_jacobian_refuses_a_field_without_horizontal_part():
    with pytest.raises(ValueError, match="no horizontal field"):
        field_jacobian(("decl_deg",), 0.0, 0.0, 50000.0)


def test_component_walk_is_j_q_jt_per_hour_by_hand():
    """One field (30000, 0, 40000) nT, (I, F), dN walking 60 and dZ 20 nT per sqrt(hour), over
    half an hour, written out: dI/dN = -Z/F^2, dI/dZ = H/F^2 (rad), dF/dN = N/F, dF/dZ = Z/F."""
    jac = field_jacobian(("incl_deg", "f_nt"), 30000.0, 0.0, 40000.0)
    cov = component_walk_covariance(jac, np.array([60.0, 0.0, 20.0]), 1800.0)
    rad = 180.0 / math.pi
    di_dn, di_dz = -40000.0 / 50000.0 ** 2 * rad, 30000.0 / 50000.0 ** 2 * rad
    df_dn, df_dz = 0.6, 0.8
    by_hand = 0.5 * np.array([[di_dn ** 2 * 3600 + di_dz ** 2 * 400, di_dn * df_dn * 3600 + di_dz * df_dz * 400],
                              [0.0, df_dn ** 2 * 3600 + df_dz ** 2 * 400]])
    by_hand[1, 0] = by_hand[0, 1]
    np.testing.assert_allclose(cov, by_hand, rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


@pytest.mark.parametrize("kp, kp_on, expected", [(8.667, 5.0, True), (5.0, 5.0, True), (4.667, 5.0, False),
                                                 (math.nan, 5.0, False), (-1.0, 0.0, False), (0.0, 0.0, True)])
def test_a_kp_declares_a_storm_at_or_above_the_threshold(kp, kp_on, expected):
    """NaN and -1 (NAV_KP's 'unknown') declare nothing, whatever the threshold."""
    assert storm_declared(kp, kp_on) is expected


def test_a_declared_storm_is_on_at_once_and_the_innovations_cannot_end_it():
    monitor = DisturbanceMonitor()
    assert monitor.declare(True) and monitor.activations == 1
    quiet = np.zeros(2)
    assert all(monitor.observe(quiet) for _ in range(3 * RELEASE_STEPS))     # quiet innovations: still on
    assert monitor.declare(False)                                           # Kp falls: the innovations decide,
    assert not monitor.observe(quiet)        # and they have been quiet for longer than RELEASE_STEPS: over
    assert monitor.declare(True) and monitor.activations == 2               # a new declared storm
    state = monitor.snapshot()
    monitor.declare(False)
    monitor.restore(state)
    assert monitor.declared and monitor.active


def test_undeclared_the_innovations_still_decide():
    """Kp below the threshold (declared False) leaves today's innovation test: loud steps switch on."""
    monitor = DisturbanceMonitor()
    monitor.declare(False)
    loud = np.full(2, 2.0 * math.sqrt(ACTIVE_ON))
    flags = [monitor.observe(loud) for _ in range(ONSET_STEPS + 2)]
    assert not flags[0] and flags[-1]


def _filter(model, mode: int, names_code: int = ElementSet.WEIGHTED) -> NavigationFilter:
    spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qa_deg_rth=0.05, qa_nt_rth=40.0, qa_mode=mode,
                    qa_n_nt_rth=60.0, qa_e_nt_rth=10.0, qa_z_nt_rth=10.0)
    settings_ = bare_filter(bias=spec)
    process = DeadReckoningProcess(settings_.dead_reckoning, *START, pos_sigma_m=5.0)
    return NavigationFilter(process, ELEMENT_SETS[names_code], settings_, model, ALT, YEAR)


@pytest.fixture(scope="module")
def model():
    return model_for_date(YEAR)


def test_a_declared_storm_walks_the_biases_along_the_field_components(model):
    """(D, I, F), a storm declared, standing still for an hour: the bias states' covariance grows
    by the quiet walk plus J diag(q^2) J^T at the model's field there, so I and F move together
    (dN lowers H: I up, F down) and D hardly at all; undeclared (the innovations' disturbance)
    they walk per element, independently."""
    flt = _filter(model, mode=1)
    k = flt.process.n
    flt.monitor.declare(True)
    before = flt.kf.P[k:k + 3, k:k + 3].copy()
    flt.predict(3600.0, np.zeros(2), START[0], START)
    grown = flt.kf.P[k:k + 3, k:k + 3] - before
    field = model.elements(*START, ALT, YEAR)
    jac = field_jacobian(flt.elements.names, float(field.x_nt), float(field.y_nt), float(field.z_nt))
    quiet = np.diag([0.002 ** 2, 0.002 ** 2, 2.0 ** 2])
    np.testing.assert_allclose(grown, quiet + jac @ np.diag([3600.0, 100.0, 100.0]) @ jac.T, rtol=1e-9)
    corr = grown[1, 2] / math.sqrt(grown[1, 1] * grown[2, 2])
    assert corr < -0.9                                           # I up where F goes down
    assert math.sqrt(grown[0, 0]) < 0.5 * math.sqrt(grown[1, 1])  # D walks slower than I

    per_element = _filter(model, mode=1)
    per_element.monitor.active, per_element.monitor.activations = True, 1   # found by the innovations
    before = per_element.kf.P[k:k + 3, k:k + 3].copy()
    per_element.predict(3600.0, np.zeros(2), START[0], START)
    np.testing.assert_allclose(per_element.kf.P[k:k + 3, k:k + 3] - before, np.diag([0.05 ** 2, 0.05 ** 2, 40.0 ** 2]),
                               rtol=1e-9, atol=1e-15)


def test_quiet_the_walk_does_not_depend_on_the_storm_form(model):
    """No disturbance: the two forms predict the same covariance, bit for bit (a quiet mission is
    not changed by how a storm would walk)."""
    a, b = _filter(model, mode=0), _filter(model, mode=1)
    for flt in (a, b):
        flt.predict(360.0, np.array([10.0, -9.0]), START[0], START)
    assert np.array_equal(a.kf.P, b.kf.P)


def test_the_component_walk_needs_a_position(model):
    flt = _filter(model, mode=1)
    flt.monitor.declare(True)
    with pytest.raises(ValueError, match="needs a position"):
        flt.predict(360.0, np.zeros(2), START[0])


def test_gauss_markov_step_keeps_the_stationary_variance():
    """Driving noise and decay of one step leave the stationary variance q^2 tau / 2 where it is,
    for any step; over a step short against tau the process wanders like a random walk at q."""
    q, tau_s = np.array([30.0]), np.array([1.5 * 3600.0])
    for dt in (1.0, 360.0, 7200.0):
        decay, driven = gauss_markov_step(q, tau_s, dt)
        stationary = stationary_variance(q, tau_s)
        np.testing.assert_allclose(decay ** 2 * stationary + driven, stationary, rtol=1e-12)
    _, driven = gauss_markov_step(q, tau_s, 1.0)
    np.testing.assert_allclose(driven, q ** 2 / 3600.0, rtol=1e-3)


def test_correlated_components_walk_as_j_c_jt_by_hand():
    """The same field and walk as above plus dE at 30 nT per sqrt(hour), the changes correlated
    N-E -0.5, N-Z 0.7, E-Z -0.8: the bias walk is J diag(q) R diag(q) J^T dt / 1 h, written out;
    uncorrelated it is the independent walk to the last bit."""
    jac = field_jacobian(("incl_deg", "f_nt"), 30000.0, 0.0, 40000.0)
    q = np.array([60.0, 30.0, 20.0])
    r = np.array([[1.0, -0.5, 0.7], [-0.5, 1.0, -0.8], [0.7, -0.8, 1.0]])
    walk = StormWalk(tuple(q), corr=(-0.5, 0.7, -0.8))
    by_hand = jac @ (np.outer(q, q) * r) @ jac.T * 0.5
    np.testing.assert_allclose(walk.bias_noise(jac, 1800.0), by_hand, rtol=1e-12)
    independent = StormWalk(tuple(q))
    assert np.array_equal(independent.bias_noise(jac, 1800.0), component_walk_covariance(jac, q, 1800.0))
    assert not np.allclose(walk.bias_noise(jac, 1800.0), independent.bias_noise(jac, 1800.0), rtol=0.05)


@pytest.mark.parametrize("corr", [(0.9, 0.9, -0.9), (1.0, -1.0, 1.0), (-1.0, -1.0, -1.0)])
def test_a_correlation_no_matrix_has_is_taken_at_the_nearest_that_is(corr):
    """Three correlations that no correlation matrix has (the parameters are set one at a time, so
    a ground station can pass through such a set) give a positive semi-definite matrix with a unit
    diagonal, so the filter's process noise stays a covariance; a valid set is kept exactly."""
    r = StormWalk((60.0, 30.0, 20.0), corr=corr).correlation
    assert np.linalg.eigvalsh(r).min() >= -1e-12
    np.testing.assert_allclose(np.diag(r), 1.0, rtol=1e-12)
    assert np.all(np.abs(r) <= 1.0 + 1e-12)
    valid = (-0.53, 0.70, -0.79)
    kept = StormWalk((60.0, 30.0, 20.0), corr=valid).correlation
    assert (kept[0, 1], kept[0, 2], kept[1, 2]) == valid


def test_correlated_gauss_markov_and_walking_components_are_driven_together(model):
    """With the changes correlated, a Gauss-Markov east (a state) and the walking north and down
    (on the bias states) are driven together: over a step far shorter than the correlation time
    the elements' bias covariance grows as with all three walking, correlated the same way; the
    cross terms between the storm state and the bias states carry it (without them it does not)."""
    corr = (-0.5, 0.7, -0.8)
    walking = _declared_step_growth(_walk_filter(model, (0.0, 0.0, 0.0), corr))
    np.testing.assert_allclose(_declared_step_growth(_walk_filter(model, (0.0, 1e6, 0.0), corr)), walking, rtol=1e-6)
    uncorrelated = _declared_step_growth(_walk_filter(model, (0.0, 0.0, 0.0)))
    assert not np.allclose(uncorrelated, walking, rtol=0.05)


def _declared_step_growth(flt: NavigationFilter) -> np.ndarray:
    """How much the elements' covariance beyond the position grows over one 360 s step, standing
    still under a declared storm."""
    flt.monitor.declare(True)
    before = flt.beyond_position_covariance()
    flt.predict(360.0, np.zeros(2), START[0], START)
    return flt.beyond_position_covariance() - before


def _walk_filter(model, tau_h: tuple[float, float, float],
                 corr: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> NavigationFilter:
    spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qa_mode=1, qa_n_nt_rth=60.0, qa_e_nt_rth=30.0, qa_z_nt_rth=10.0,
                    qa_tn_h=tau_h[0], qa_te_h=tau_h[1], qa_tz_h=tau_h[2], qa_rne=corr[0], qa_rnz=corr[1], qa_rez=corr[2])
    settings_ = bare_filter(bias=spec)
    process = DeadReckoningProcess(settings_.dead_reckoning, *START, pos_sigma_m=5.0)
    return NavigationFilter(process, ELEMENT_SETS[ElementSet.WEIGHTED], settings_, model, ALT, YEAR)


def test_a_gauss_markov_component_is_a_state_that_walks_like_the_random_walk_over_a_short_step(model):
    """The east with a correlation time is one more state; over a step far shorter than it, the
    elements' bias covariance (bias states plus the storm state through J) grows as with the
    east a random walk on the bias states."""
    walk, markov = _walk_filter(model, (0.0, 0.0, 0.0)), _walk_filter(model, (0.0, 1e6, 0.0))
    assert markov.ns == 1 and walk.ns == 0 and markov.kf.x.shape[0] == walk.kf.x.shape[0] + 1
    np.testing.assert_allclose(_declared_step_growth(markov), _declared_step_growth(walk), rtol=1e-6)


def test_a_declared_storm_starts_its_gauss_markov_states_stationary_and_they_fade_after(model):
    """Calibrated under a declared storm, the east state starts at its stationary q^2 tau / 2 (the
    storm is on then too) and the bias takes what is left of the innovation: a D innovation within
    the storm's spread (0.02 deg against 26 nT x 0.0019 deg/nT = 0.05 deg) is the storm's east,
    not a bias carried through the mission; one far beyond it (1 deg) is a bias. Once the storm is
    no longer declared the state decays with no noise: its variance falls by decay^2 a step."""
    taken = {}
    for offset in (0.02, 1.0):
        flt = _walk_filter(model, (0.0, 1.5, 0.0))
        flt.monitor.declare(True)
        s_true = flt.elements.values(model.elements(*START, ALT, YEAR))
        flt.calibrate(s_true + np.array([offset, 0.0, 0.0]), standard_errors=np.array([0.002, 0.002, 2.0]))
        state = flt.kf.P.shape[0] - 1
        east = flt.x[state] * flt._total[0, state]          # the storm's share of the D innovation, deg
        taken[offset] = (east / offset, flt.x[flt.process.n] / offset)
    assert taken[0.02][0] > 0.9 and abs(taken[0.02][1]) < 0.1       # small: the storm's east
    assert taken[1.0][1] > 0.9                                         # large: a bias
    flt.monitor.declare(False)
    flt.monitor.active = False
    before = flt.kf.P[state, state]
    flt.predict(3600.0, np.zeros(2), START[0], START)
    assert flt.kf.P[state, state] == pytest.approx(before * math.exp(-2.0 / 1.5), rel=1e-9)


@pytest.mark.parametrize("adapt", [0, 1])
def test_a_declared_storm_walk_follows_innovations_larger_than_it_predicts(model, adapt):
    """FUS_BQA_SADAPT: while an index declares a storm, innovations far larger than the filter predicts
    (a storm faster than the fitted walks) raise the walk's scale by (NIS / m)^ADAPT_GAIN of the
    averaged NIS a step, up to STORM_SCALE_MAX; a storm that then stands still brings it back down
    towards the declared walk, never below (the floor: the doctest of BiasWalk.storm_matched); the predict
    then walks the biases along the components at the scale squared (by hand); once no index declares
    the storm it is 1 again, and a rewind takes it back. With 0 the scale stays 1."""
    spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qa_mode=1, qa_n_nt_rth=6.0, qa_e_nt_rth=6.0, qa_z_nt_rth=3.0,
                     storm_adapt=adapt)
    settings_ = bare_filter(bias=spec)
    flt = NavigationFilter(DeadReckoningProcess(settings_.dead_reckoning, *START, pos_sigma_m=5.0),
                           ELEMENT_SETS[ElementSet.PAPER], settings_, model, ALT, YEAR)
    k = flt.process.n
    s_true = flt.elements.values(model.elements(*START, ALT, YEAR))
    se = np.array([0.002, 0.002])
    flt.monitor.declare(True)
    scales = []
    for step in range(8):                   # a storm 0.1 deg a step off the model: far louder than 6 nT/rt(h)
        flt.predict(360.0, np.zeros(2), START[0], START)
        flt.update_elements(s_true + 0.1 * (step + 1) * np.array([0.5, -1.0]), None, standard_errors=se)
        scales.append(flt.storm_scale)
    if not adapt:
        assert scales == [1.0] * 8
        return
    assert scales[-1] > 10.0 and max(scales) <= STORM_SCALE_MAX
    assert all(b >= a for a, b in zip(scales[:3], scales[1:4]))
    scale = flt.storm_scale
    before = flt.kf.P[k:k + 2, k:k + 2].copy()
    flt.predict(360.0, np.zeros(2), START[0], START)
    field = model.elements(*START, ALT, YEAR)
    jac = field_jacobian(flt.elements.names, float(field.x_nt), float(field.y_nt), float(field.z_nt))
    quiet = np.diag([0.002 ** 2, 0.002 ** 2]) * 0.1
    walk = jac @ np.diag([36.0, 36.0, 9.0]) @ jac.T * 0.1 * scale ** 2
    np.testing.assert_allclose(flt.kf.P[k:k + 2, k:k + 2] - before, quiet + walk, rtol=1e-9, atol=1e-12)
    state = flt.snapshot()
    for _ in range(30):                     # then the storm stands still: down towards the declared walk, never below
        flt.predict(360.0, np.zeros(2), START[0], START)
        flt.update_elements(s_true + 0.8 * np.array([0.5, -1.0]), None, standard_errors=se)
        scales.append(flt.storm_scale)
    assert scales[-1] < 0.05 * STORM_SCALE_MAX and min(scales) >= 1.0
    flt.restore(state)
    assert flt.storm_scale == scale
    flt.monitor.declare(False)
    flt.update_elements(s_true, None, standard_errors=se)
    assert flt.storm_scale == 1.0


def test_the_declared_storm_variance_factor_scales_only_the_reported_covariance(model):
    """FUS_BQA_SADAPT 3: the monitor keeps mean(NIS / m) of the updates while an index declares a
    storm (not before, at least 1); the filter reports its position covariance times it, its own P
    untouched; with any other value the covariance is P's."""
    monitor = DisturbanceMonitor()
    monitor.observe(np.array([3.0, 3.0]))                  # quiet: not counted
    assert monitor.variance_factor() == 1.0
    monitor.declare(True)
    for w in ([2.0, 2.0], [1.0, 1.0], [0.0, 0.0]):        # NIS / m 4, 1, 0
        monitor.observe(np.array(w))
    assert monitor.variance_factor() == pytest.approx(5.0 / 3.0)
    flts = {}
    for adapt in (0, 3):
        spec = bare_bias(q_deg_rth=0.002, q_nt_rth=2.0, qa_mode=1, storm_adapt=adapt)
        settings_ = bare_filter(bias=spec)
        flts[adapt] = NavigationFilter(DeadReckoningProcess(settings_.dead_reckoning, *START, pos_sigma_m=5.0),
                                       ELEMENT_SETS[ElementSet.PAPER], settings_, model, ALT, YEAR)
        flts[adapt].monitor.declare(True)
        flts[adapt].monitor.storm_nis = (9.0, 3)
    np.testing.assert_allclose(flts[3].covariance_en(START[0]), 3.0 * flts[0].covariance_en(START[0]), rtol=1e-12)
    assert np.array_equal(flts[3].kf.P, flts[0].kf.P)

"""Simulated world: INS error model, vehicle kinematics, scenario files (sitl.world, sitl.scenario).

Oracles: Table 1's initial errors read back through geographiclib, the Schuler period
2 pi sqrt(R/g) of inertial-navigation theory, the kinematic limits themselves, and geodesics
between the positions the vehicle model produces.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from geographiclib.geodesic import Geodesic
from hypothesis import given, settings
from hypothesis import strategies as st

from companion import wrap_pi
from sitl.scenario import ScenarioError, load_scenario
from sitl.world.ins import ARCMIN, InsErrorConfig, InsErrorModel
from sitl.world.vehicle import NO_MOTION_ERRORS, MotionErrors, VehicleLimits, VehicleState, _tracked, step_vehicle

WGS84 = Geodesic.WGS84
EARTH_RADIUS_M = 6371.0e3
G_MPS2 = 9.7803


# --- INS error model -------------------------------------------------------------------------------
def _fly_ins(seed: int, config: InsErrorConfig = InsErrorConfig(), steps: int = 20) -> np.ndarray:
    ins = InsErrorModel(config, np.random.default_rng(seed), 33.0)
    track = [ins.state.copy()]
    for _ in range(steps):
        ins.propagate(360.0, 32.8, 10.0, -9.0)
        track.append(ins.state.copy())
    return np.array(track)


def test_ins_errors_are_seeded_and_reproducible():
    a, b, c = _fly_ins(7), _fly_ins(7), _fly_ins(8)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[0], c[0])            # different initial draws
    assert not np.allclose(a[-1], c[-1])
    # deterministic mode draws nothing (initial errors as given, no Markov noise): seed-independent
    det = replace(InsErrorConfig(), deterministic=True)
    assert np.array_equal(_fly_ins(1, det), _fly_ins(2, det))


def test_deterministic_mode_applies_table_1_initial_errors_exactly():
    ins = InsErrorModel(InsErrorConfig(deterministic=True), np.random.default_rng(0), 33.0)
    east, north = ins.position_error_m(33.0)
    assert east == pytest.approx(5000.0, abs=1e-6) and north == pytest.approx(5000.0, abs=1e-6)
    # read back independently: geodesic distances between the true and the indicated position
    lat, lon = ins.indicated_position(33.0, 152.0)
    assert WGS84.Inverse(33.0, 152.0, lat, 152.0)["s12"] == pytest.approx(5000.0, abs=1.0)   # north
    assert WGS84.Inverse(33.0, 152.0, 33.0, lon)["s12"] == pytest.approx(5000.0, abs=1.0)    # east
    assert lat > 33.0 and lon > 152.0
    np.testing.assert_allclose(ins.state[0:3], np.array([50.0, 50.0, 500.0]) * ARCMIN, rtol=1e-12)
    assert math.hypot(ins.state[3], ins.state[4]) == pytest.approx(10.0, rel=1e-12)   # Table 1: 10 m/s
    assert ins.state[5] == 0.0 and ins.state[8] == 0.0                                 # vertical: 0
    ve, vn = ins.indicated_velocity(1.0, 2.0)
    assert (ve - 1.0, vn - 2.0) == pytest.approx((ins.state[3], ins.state[4]))


def test_schuler_oscillation_of_the_north_velocity_error():
    """Only an initial tilt about east: dv_n oscillates at the Schuler period 2 pi sqrt(R/g)."""
    config = InsErrorConfig(misalign_arcmin=(1.0, 0.0, 0.0), vel_err_mps=0.0, pos_err_east_m=0.0,
                            pos_err_north_m=0.0, gyro_bias_degph=0.0, gyro_markov_degph=0.0, deterministic=True)
    ins = InsErrorModel(config, np.random.default_rng(0), 33.0)
    dt, hours = 30.0, 6.0
    times, vn = [], []
    for k in range(1, int(hours * 3600 / dt) + 1):
        ins.propagate(dt, 33.0, 0.0, 0.0)
        times.append(k * dt)
        vn.append(ins.state[4])
    times, vn = np.array(times), np.array(vn)
    crossings = [times[i] - vn[i] * dt / (vn[i + 1] - vn[i]) for i in range(len(vn) - 1) if vn[i] * vn[i + 1] < 0]
    assert len(crossings) >= 7
    # two crossings per period; average over all of them (Earth-rate coupling shifts single ones)
    period = 2.0 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    expected = 2.0 * math.pi * math.sqrt(EARTH_RADIUS_M / G_MPS2)
    assert expected / 60.0 == pytest.approx(84.4, abs=0.2)  # the textbook 84.4 min
    assert period == pytest.approx(expected, rel=0.02)
    # the amplitude is bounded (an oscillation, not a drift): g * tilt / omega_s
    assert np.max(np.abs(vn)) == pytest.approx(G_MPS2 * ARCMIN / (2 * math.pi / expected), rel=0.15)


def test_ins_propagation_is_the_exact_exponential_to_rounding():
    """expm(F dt) x by the 8-term Taylor series on 30 s pieces, against a 60-term series of the
    same F in extended precision (long double): within 1e-14 of |Phi| |x| per component
    (measured 4e-16) over latitudes, velocities and steps of 1 s to 6 min. scipy's Pade expm of
    this badly scaled F (what propagated the INS before) is itself off by up to 1.1e-6 of the same
    scale (measured, on the Markov drift states), so as a second, independent reference it is
    checked to 1e-5."""
    from scipy.linalg import expm

    from sitl.world.ins import expm_times

    rng = np.random.default_rng(5)

    def series(a: np.ndarray, x: np.ndarray, terms: int) -> np.ndarray:
        y = x
        for k in range(terms, 0, -1):
            y = x + (a @ y) / k
        return y

    for _ in range(40):
        ins = InsErrorModel(InsErrorConfig(), rng, 33.0)
        f = ins._dynamics(float(rng.uniform(-85.0, 85.0)), *(float(v) for v in rng.uniform(-100.0, 100.0, 2)))
        for dt in (1.0, 30.0, 45.0, 120.0, 360.0):
            got = expm_times(f, dt, ins.state)
            a, x = (f * dt).astype(np.longdouble), ins.state.astype(np.longdouble)
            exact = series(a, x, 60)
            scale = np.abs(series(np.abs(a), np.abs(x), 60))
            assert np.all(np.abs(got - exact) <= 1e-14 * scale), dt
            moving = scale > 0.0       # scipy leaves ~1e-20 in the held vertical channel
            pade = expm(f * dt) @ ins.state
            assert np.all(np.abs(got - pade)[moving] <= 1e-5 * scale.astype(float)[moving]), dt
            assert np.all(got[~moving] == 0.0)


# --- vehicle kinematics -----------------------------------------------------------------------------
LIMITS = VehicleLimits(max_speed_mps=20.0, accel_mps2=0.5, turn_rate_radps=math.radians(6.0))


def test_speed_follows_the_command_at_the_acceleration_limit():
    state = VehicleState(33.0, 152.0)
    for k in range(1, 61):
        state = step_vehicle(state, 1.0, 0.0, 100.0, LIMITS)
        assert state.speed_mps == pytest.approx(min(0.5 * k, 20.0))   # capped at max speed
    for _ in range(10):
        state = step_vehicle(state, 1.0, 0.0, 15.0, LIMITS)
    assert state.speed_mps == pytest.approx(15.0)
    state = step_vehicle(state, 1.0, 0.0, -5.0, LIMITS)                  # negative: towards zero
    assert state.speed_mps == pytest.approx(14.5)


def test_course_follows_the_command_at_the_turn_limit_the_short_way():
    state = VehicleState(33.0, 152.0, course_rad=math.radians(10.0), speed_mps=10.0)
    courses = []
    for _ in range(30):
        state = step_vehicle(state, 1.0, math.radians(350.0), 10.0, LIMITS)
        courses.append(math.degrees(state.course_rad))
    # 10 -> 350 deg is 20 deg to port: 6 deg/s gives 4, 358 (wrapped), 352, then holds 350
    assert courses[:4] == pytest.approx([4.0, 358.0, 352.0, 350.0])
    assert all(c == pytest.approx(350.0) for c in courses[3:])
    assert all(0.0 <= c < 360.0 for c in courses)


def test_random_commands_never_exceed_the_limits():
    rng = np.random.default_rng(5)
    state = VehicleState(33.0, 152.0)
    for _ in range(500):
        dt = rng.uniform(0.1, 30.0)
        command_speed = rng.uniform(-5.0, 40.0)
        new = step_vehicle(state, dt, rng.uniform(-10.0, 10.0), command_speed, LIMITS)
        assert 0.0 <= new.speed_mps <= LIMITS.max_speed_mps + 1e-12
        assert abs(new.speed_mps - state.speed_mps) <= LIMITS.accel_mps2 * dt + 1e-9
        assert abs(wrap_pi(new.course_rad - state.course_rad)) <= LIMITS.turn_rate_radps * dt + 1e-9
        assert 0.0 <= new.course_rad < 2.0 * math.pi
        # the path is the speed profile's integral (ramp at the limit, then hold), the chord no longer
        target = min(max(command_speed, 0.0), LIMITS.max_speed_mps)
        ramp = min(abs(target - state.speed_mps) / LIMITS.accel_mps2, dt)
        path = 0.5 * (state.speed_mps + new.speed_mps) * ramp + new.speed_mps * (dt - ramp)
        assert new.distance_m - state.distance_m == pytest.approx(path, rel=1e-9, abs=1e-9)
        chord = WGS84.Inverse(state.lat_deg, state.lon_deg, new.lat_deg, new.lon_deg)["s12"]
        assert chord <= path * (1.0 + 1e-3) + 0.01
        state = new


@pytest.mark.parametrize("speed, new_speed, turn_deg", [(6.6, 0.0, 0.0), (13.9, 0.5, 150.0), (0.0, 13.9, -90.0),
                                                          (13.9, 13.9, 3.0), (13.9, 13.9, 0.0)])
def test_one_long_step_goes_where_many_short_ones_do(speed, new_speed, turn_deg):
    """The in-process world steps 30 s at a time: a stop, a slow-down with a turn, a start, a
    cruise course change in one step end within 0.5 m of the same 30 s in 3000 steps of 10 ms
    (before the step was split where speed and course reach the command, a stop from 6.6 m/s went
    106 m in one step against the 44 m it goes: v^2 / 2a)."""
    start = VehicleState(33.0, 152.0, math.radians(132.0), speed)
    course = math.radians(132.0 + turn_deg)
    coarse = step_vehicle(start, 30.0, course, new_speed, LIMITS)
    fine = start
    for _ in range(3000):
        fine = step_vehicle(fine, 0.01, course, new_speed, LIMITS)
    assert WGS84.Inverse(coarse.lat_deg, coarse.lon_deg, fine.lat_deg, fine.lon_deg)["s12"] < 0.5
    assert coarse.distance_m == pytest.approx(fine.distance_m, abs=1e-6)
    assert coarse.speed_mps == fine.speed_mps and coarse.course_rad == pytest.approx(fine.course_rad, abs=1e-12)
    if speed == 6.6:
        assert coarse.distance_m == pytest.approx(speed ** 2 / (2.0 * LIMITS.accel_mps2))


@settings(max_examples=300, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(-180.0, 180.0), st.floats(0.0, 2.0 * math.pi, exclude_max=True),
       st.floats(0.0, 16.0), st.floats(0.0, 120.0), st.floats(0.0, 1e6), st.booleans())
def test_a_step_holding_course_and_speed_is_the_split_steps_bit_for_bit(lat, lon, course, speed, dt, flown, drift):
    """A vehicle already at its commanded course and speed takes step_vehicle's short way (one
    straight piece); the general split (_tracked) gives the same state to the last bit, with and
    without motion errors."""
    state = VehicleState(lat, lon, course, speed, flown)
    motion = MotionErrors((0.3, -0.2), 1.0, 0.0) if drift else NO_MOTION_ERRORS
    assert step_vehicle(state, dt, course, speed, LIMITS, motion) == _tracked(state, dt, course, speed, 0.0,
                                                                             LIMITS, motion)


@pytest.mark.parametrize("course_deg", [0.0, 45.0, 133.0, 270.0, 301.0])
def test_vehicle_moves_along_the_commanded_course(course_deg):
    state = VehicleState(33.0, 152.0, course_rad=math.radians(course_deg), speed_mps=12.0)
    end = state
    for _ in range(10):
        end = step_vehicle(end, 30.0, math.radians(course_deg), 12.0, LIMITS)
    geo = WGS84.Inverse(state.lat_deg, state.lon_deg, end.lat_deg, end.lon_deg)
    assert geo["s12"] == pytest.approx(3600.0, rel=1e-3)                 # 12 m/s for 300 s
    assert (geo["azi1"] - course_deg + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=0.1)
    assert end.distance_m == pytest.approx(3600.0, rel=1e-9)


@pytest.mark.parametrize("course,speed", [(math.nan, 10.0), (1.0, math.nan), (math.inf, 10.0)])
def test_a_non_finite_command_stops_the_vehicle_on_its_course(course, speed):
    state = VehicleState(33.0, 152.0, course_rad=math.radians(70.0), speed_mps=10.0)
    for k in range(1, 21):
        state = step_vehicle(state, 1.0, course, speed, LIMITS)
        assert state.speed_mps == pytest.approx(max(0.0, 10.0 - 0.5 * k))
        assert math.degrees(state.course_rad) == pytest.approx(70.0)
    stopped = step_vehicle(state, 100.0, course, speed, LIMITS)
    assert (stopped.lat_deg, stopped.lon_deg, stopped.speed_mps) == (state.lat_deg, state.lon_deg, 0.0)


# --- scenario files -----------------------------------------------------------------------------
GOOD = """name = "t"
[mission]
start = [33.0, 152.0]
destination = [28.0, 158.0]
[vehicle]
max_speed_kmh = 60.0
[ins]
misalign = [50.0, 50.0, 500.0]
misalign_unit = "arcsec"
"""


def write(tmp_path, text: str):
    path = tmp_path / "scenario.toml"
    path.write_text(text)
    return path


def test_bundled_and_good_scenarios_load():
    for name in ("paper_pacific", "paper_long_storm", "paper_short_storm"):
        assert load_scenario(name).name == name
    pacific = load_scenario("paper_pacific")
    assert pacific.vehicle.max_speed_mps == pytest.approx(60.0 / 3.6)
    assert pacific.ins.misalign_arcmin == pytest.approx((50.0 / 60.0, 50.0 / 60.0, 500.0 / 60.0))


def test_good_file_loads(tmp_path):
    scenario = load_scenario(write(tmp_path, GOOD))
    assert (scenario.start_lat_deg, scenario.dest_lon_deg) == (33.0, 158.0)
    assert scenario.vehicle.max_speed_mps == pytest.approx(60.0 / 3.6)


@pytest.mark.parametrize("text,words", [
    ("name = 't'\n[mission\nstart = [1, 2]\n", ["scenario.toml"]),                        # bad TOML
    (GOOD.replace("max_speed_kmh = 60.0", "max_speed_kmh = 60.0\ntop_speed = 3.0"), ["[vehicle]", "top_speed"]),
    (GOOD + "[sensors]\nmag_noise = 1.0\n", ["[sensors]", "mag_noise"]),
    (GOOD + "[storm]\nenable = true\n", ["[storm]", "enable"]),
    (GOOD + "[[faults]]\nkind = \"mag_explode\"\nat_s = 10.0\n", ["fault #1", "mag_explode"]),
    (GOOD + "[[faults]]\nkind = \"mag_off\"\nat_s = 1.0\n[[faults]]\nkind = \"mag_off\"\nwhen = 2.0\n",
     ["faults #2", "when"]),
    (GOOD.replace('misalign_unit = "arcsec"', 'misalign_unit = "deg"'), ["misalign_unit"]),
    (GOOD + "[storm]\ntime_map = \"warp\"\n", ["time_map"]),
    (GOOD.replace("destination = [28.0, 158.0]\n", ""), ["[mission]", "destination"]),
    ("vehicle = 3\n" + GOOD.replace("[vehicle]\nmax_speed_kmh = 60.0\n", ""), ["[vehicle]", "table"]),
    (GOOD + "[navigator]\nFUS_GM_DEGS = 0.0\n", ["[navigator]", "FUS_GM_DEGS"]),
    (GOOD + "[navigator]\nFUS_GM_NT = -1.0\n", ["[navigator]", "FUS_GM_NT"]),
    (GOOD + "[sensors]\nmag_noise_nt = -5.0\n", ["[sensors]", "mag_noise_nt", "not negative"]),
    (GOOD + "[sensors]\nmag_rate_hz = 0\n", ["[sensors]", "mag_rate_hz", "positive"]),
    (GOOD.replace('misalign_unit = "arcsec"\n', 'misalign_unit = "arcsec"\ngyro_markov_tau_s = 0.0\n'),
     ["[ins]", "gyro_markov_tau_s"]),
    (GOOD.replace('misalign_unit = "arcsec"\n', 'misalign_unit = "arcsec"\nvel_err_mps = -10.0\n'),
     ["[ins]", "vel_err_mps"]),
])
def test_bad_scenario_names_the_file_and_the_key(tmp_path, text, words):
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert str(path) in message
    for word in words:
        assert word in message, message


def test_navigator_table_reaches_the_simulated_worlds_but_not_real_firmware(tmp_path):
    """The ideal presets declare the navigator of the paper's world (no local model error); the
    realistic ones keep the registry's (a real vehicle's) values; a flight on real firmware takes
    the mission from a scenario but never its [navigator] table."""
    from companion.params import default_values

    ideal, real = load_scenario("paper_pacific"), load_scenario("pacific")
    assert ideal.nav_overrides()["FUS_GM_NT"] == 0.0 < default_values()["FUS_GM_NT"]
    assert "FUS_GM_NT" not in real.nav_overrides()
    assert "FUS_GM_NT" not in ideal.nav_overrides(navigator=False)
    assert ideal.nav_overrides(navigator=False)["NAV_DEST_LON"] == 158.0
    lower = load_scenario(write(tmp_path, GOOD + "[navigator]\nfus_gm_km = 10\n"))
    assert lower.nav_overrides()["FUS_GM_KM"] == 10.0


def test_unknown_scenario_name_lists_the_bundled_ones():
    with pytest.raises(ScenarioError, match="no scenario 'atlantis'.*pacific"):
        load_scenario("atlantis")


def test_unknown_mission_key_is_refused(tmp_path):
    path = write(tmp_path, GOOD.replace("destination = [28.0, 158.0]", "destination = [28.0, 158.0]\nyaer = 2020.5"))
    with pytest.raises(ScenarioError, match="yaer"):
        load_scenario(path)


def test_unknown_top_level_table_is_refused(tmp_path):
    path = write(tmp_path, GOOD + "[vehical]\nmax_speed_kmh = 10.0\n")
    with pytest.raises(ScenarioError, match="vehical"):
        load_scenario(path)


def test_motion_errors_move_the_track_off_the_command():
    """A 0.3 m/s eastward current, 2 % more speed and a 1 deg course bias: after an hour on a
    northward command at 10 m/s the vehicle is where those put it, not where it was commanded."""
    from sitl.world.vehicle import MotionErrors

    motion = MotionErrors((0.3, 0.0), 1.02, math.radians(1.0))
    start = VehicleState(30.0, 150.0, 0.0, 10.2)
    state = start
    for _ in range(3600):
        state = step_vehicle(state, 1.0, 0.0, 10.0, LIMITS, motion)
    line = Geodesic.WGS84.Inverse(start.lat_deg, start.lon_deg, state.lat_deg, state.lon_deg)
    north, east = line["s12"] * math.cos(math.radians(line["azi1"])), line["s12"] * math.sin(math.radians(line["azi1"]))
    assert north == pytest.approx(10.2 * 3600.0 * math.cos(math.radians(1.0)), rel=2e-3)
    assert east == pytest.approx((0.3 + 10.2 * math.sin(math.radians(1.0))) * 3600.0, rel=2e-2)
    assert state.vel_east_mps == pytest.approx(0.3 + 10.2 * math.sin(math.radians(1.0)), rel=1e-6)
    assert math.degrees(state.course_rad) == pytest.approx(1.0, abs=1e-6)        # the heading steered


def test_no_motion_errors_are_the_old_kinematics_bit_for_bit():
    from sitl.world.vehicle import MotionErrors

    a = b = VehicleState(33.0, 152.0, 0.3, 5.0)
    for k in range(200):
        a = step_vehicle(a, 7.0, 0.01 * k, 13.9, LIMITS)
        b = step_vehicle(b, 7.0, 0.01 * k, 13.9, LIMITS, MotionErrors())
    assert a == b


def test_the_realistic_scenarios_draw_motion_errors_and_the_ideal_ones_none():
    from sitl.scenario import load_scenario
    from sitl.world.vehicle import MotionErrors

    assert not load_scenario("paper_pacific").motion.active
    real = load_scenario("pacific").motion
    draws = [MotionErrors.draw(real, np.random.default_rng(s)) for s in range(400)]
    assert np.std([d.current_en_mps[0] for d in draws]) == pytest.approx(real.current_mps, rel=0.15)
    assert np.std([math.degrees(d.course_bias_rad) for d in draws]) == pytest.approx(real.course_bias_deg, rel=0.15)

"""One control step against a prepared or a real core: what is sent, and navigation failures."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.app import State
from companion.io.link import mavlink
from companion.nav.mission import Mission
from companion.params import NavConfig, default_values
from companion.registry import READINGS
from tests.companion.process.rig import GOOD, FakeMission, _msg, _run_step, _sent


@pytest.mark.parametrize("bad,why", [
    (replace(GOOD, course_rad=math.nan), "non-finite command"),
    (replace(GOOD, speed_mps=math.inf), "non-finite command"),
    (replace(GOOD, solver_ok=False, reason="QP failed: max iterations"), "solver failure"),
    (replace(GOOD, fix_lat_deg=33.5), "diverged"),                    # 111 km from the estimate
])
def test_navigation_failure_holds_and_restarts(rig, bad, why):
    app, fc = rig
    _run_step(app, bad)
    sent = _sent(fc)
    assert app.state == State.STARTUP and app.mission_state.restarts == 1 and app.mission_state.mission is None
    assert app.mission_state.restart_from == pytest.approx((32.5, 152.5))           # from the last estimate
    texts = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert "FAILSAFE" in texts and why in texts
    holds = [m for m in sent if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE]
    assert holds and holds[0].param2 == 4                              # ArduPilot Rover HOLD
    app.tick()
    assert not [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]


def test_good_step_streams_and_publishes(rig):
    app, fc = rig
    app.params.set_value("COMP_POS_PUB", 0)      # EXTERNAL_POSITION_ESTIMATE (the default is GPS_INPUT)
    app.settings.apply()
    _run_step(app, GOOD)
    app.next_tick = -math.inf
    app.tick()
    sent = _sent(fc)
    [sp] = [m for m in sent if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert sp.vx == pytest.approx(13.0 * math.cos(2.3), abs=1e-4) and sp.yaw == pytest.approx(2.3)
    names = {m.name for m in sent if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert {"FC_D", "FC_I", "FC_ERR", "FC_REM", "FC_SOLV", "FC_STEP"} <= names
    [est] = [m for m in sent if m.get_type() == "COMMAND_INT"]
    assert est.command == mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE and est.x == 325_000_000
    assert est.param3 == pytest.approx(800.0) and math.isnan(est.z)


def test_a_steps_new_command_is_streamed_in_the_tick_that_made_it(rig):
    # streamed only before the step, the new course waited a tick (1 / COMP_SP_RATE_HZ); the
    # old one still goes out first, keeping the stream's cadence whatever the step costs
    app, fc = rig
    app.mission_state.mission = FakeMission(GOOD)
    # the course flown so far (no estimate: the stand-in core has nothing to judge against)
    app.mission_state.command = replace(GOOD, course_rad=0.4, step=4, est_lat_deg=math.nan)
    app.mag.averager.add(0.5, 1.0, 50.0)
    app.mission_state.next_step_m = app.mission_time()                              # a step is due now
    app.next_tick = -math.inf
    app.tick()
    old, new = [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert old.yaw == pytest.approx(0.4) and new.yaw == pytest.approx(GOOD.course_rad) and app.mission_state.command is GOOD


def test_a_step_that_ends_the_mission_streams_no_setpoint_after_it(rig):
    app, fc = rig
    app.mission_state.mission = FakeMission(replace(GOOD, done=True, phase="arrived", speed_mps=0.0))
    app.mission_state.command = replace(GOOD, est_lat_deg=math.nan)
    app.mag.averager.add(0.5, 1.0, 50.0)
    app.mission_state.next_step_m = app.mission_time()
    app.next_tick = -math.inf
    app.tick()
    assert app.state == State.DONE
    [before] = [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]   # the stream's, before the step
    assert before.yaw == pytest.approx(GOOD.course_rad)


def test_odometry_when_selected(rig):
    app, fc = rig
    app.params.set_value("COMP_POS_PUB", 1)
    app.settings.apply()
    app.handle(_msg("GLOBAL_POSITION_INT", time_boot_ms=1000, lat=325000000, lon=1525000000, alt=0, relative_alt=0,
                    vx=0, vy=0, vz=0, hdg=0))
    app.handle(_msg("LOCAL_POSITION_NED", time_boot_ms=1000, x=1000.0, y=-500.0, z=0.0, vx=0.0, vy=0.0, vz=0.0))
    _run_step(app, GOOD)
    [odo] = [m for m in _sent(fc) if m.get_type() == "ODOMETRY"]
    # the estimate is the FC's own position here, so it sits at the FC's local (x, y)
    assert odo.x == pytest.approx(1000.0, abs=0.5) and odo.y == pytest.approx(-500.0, abs=0.5)
    assert odo.pose_covariance[0] == pytest.approx(800.0 ** 2) and odo.frame_id == mavlink.MAV_FRAME_LOCAL_NED


def test_real_mission_first_step_probes_east(rig):
    app, fc = rig
    app.mission_state.mission = Mission(NavConfig.from_values(default_values()))
    h, z = 45000.0 * math.cos(math.radians(48.0)), 45000.0 * math.sin(math.radians(48.0))   # F 45,000 nT
    app.mag.averager.add(0.5, -1.5, 48.0, (h * math.cos(math.radians(-1.5)), h * math.sin(math.radians(-1.5)), z))
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    assert app.mission_state.command.phase == "probe1" and app.mission_state.command.course_rad == pytest.approx(math.pi / 2)


def test_a_gap_inside_the_estimates_own_uncertainty_is_not_a_divergence(rig):
    """60 km between estimate and fix (beyond COMP_DIVERGE_KM, 50 km): a filter whose covariance
    says 40 km per axis flies on; one that claims 5 km has diverged."""
    app, fc = rig
    far = replace(GOOD, fix_lat_deg=32.5 + 60e3 / 111e3)
    _run_step(app, replace(far, est_cov_en_m2=(40e3 ** 2, 0.0, 40e3 ** 2)))
    assert app.state == State.RUNNING and app.mission_state.restarts == 0
    _sent(fc)
    app.mission_state.command = None                       # judged as a first step again: the stand-in core has no field model
    _run_step(app, replace(far, est_cov_en_m2=(5e3 ** 2, 0.0, 5e3 ** 2)))
    assert app.mission_state.restarts == 1 and "diverged: 60.0 km" in "".join(
        m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")


def test_a_gap_inside_the_fixs_own_uncertainty_is_not_a_divergence(rig):
    """The same 60 km gap against an estimate sure to 5 km: when the fix itself is uncertain by
    40 km per axis (the heading states' bias at a new heading, through an (I, F) G^-1) the gap is
    judged with it and the vehicle flies on (ArduPilot SITL, 2026-12-02: the first cruise step's
    fix 70.8 km off stopped the GPS-lost test); with a fix sure to 5 km it has diverged."""
    app, fc = rig
    far = replace(GOOD, fix_lat_deg=32.5 + 60e3 / 111e3, est_cov_en_m2=(5e3 ** 2, 0.0, 5e3 ** 2))
    _run_step(app, replace(far, fix_cov_en_m2=(40e3 ** 2, 0.0, 40e3 ** 2)))
    assert app.state == State.RUNNING and app.mission_state.restarts == 0
    _sent(fc)
    app.mission_state.command = None
    _run_step(app, replace(far, fix_cov_en_m2=(5e3 ** 2, 0.0, 5e3 ** 2)))
    assert app.mission_state.restarts == 1 and "diverged: 60.0 km" in "".join(
        m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")


def test_a_new_course_starts_the_trims_record_again(rig):
    """The first command (motion starts) and a turn of 29 deg each restart the FC-yaw-error record
    (:meth:`YawOffsetTracker.new_course`): 3 s after each, the offset is that of the samples since,
    not a mix with the 30 s before; the same command again does not restart it."""
    app, fc = rig
    tracker = app.mag.yaw_offset
    mag, force = (20000.0 * 0.5, -20000.0 * 0.8660254, 40000.0), (0.0, 0.0, -9.81)   # 60 deg magnetic

    def feed(t0: float, seconds: float, error_deg: float) -> float:
        for k in range(int(seconds * 50)):
            tracker.add(t0 + 0.02 * (k + 1), math.radians(60.0 + error_deg), mag, force)
        return t0 + seconds

    cmd = replace(GOOD, est_lat_deg=math.nan, est_lon_deg=math.nan)   # nothing to judge the next steps against
    now = app.now
    feed(now - 30.0, 30.0, 5.0)                        # standing: +5
    _run_step(app, cmd)
    t = feed(now, 3.0, -3.0)
    assert math.degrees(tracker.offset_rad(t)) == pytest.approx(-3.0, abs=1e-6)
    _run_step(app, cmd)                                # the same command: the record goes on
    t = feed(t, 3.0, 5.0)
    assert -3.0 + 1.0 < math.degrees(tracker.offset_rad(t)) < 5.0 - 1.0
    app.link.clock.now_s = t
    _run_step(app, replace(cmd, course_rad=cmd.course_rad + 0.5))
    t = feed(t, 3.0, 9.0)
    assert math.degrees(tracker.offset_rad(t)) == pytest.approx(9.0, abs=1e-6)


class _SeeingMission:
    """The prepared core, keeping each measurement it was given (what the step took as Kp)."""

    def __init__(self, command) -> None:
        from tests.companion.process.rig import FakeMission
        self._inner = FakeMission(command)
        self.config = self._inner.config
        self.measured = self.elements = self._inner.measured
        self.k = command.step
        self.seen = []

    def step(self, meas):
        self.seen.append(meas)
        return self._inner.command

    def reconfigure(self, new):
        return []

    def snapshot(self) -> dict:
        return {}


def test_nav_kp_is_a_reading_used_only_while_the_ground_station_renews_it(rig):
    """NAV_KP from the .parm file is no Kp at all (a value from another day would declare or deny a
    storm all flight); set over the link (a ground station's PARAM_SET) it is the step's Kp until
    its lifetime (3.5 h) of message time passes without a renewal."""
    app, fc = rig
    KP_MAX_AGE_S = READINGS["NAV_KP"]
    mission = _SeeingMission(GOOD)
    app.mission_state.mission = mission
    app.params.values["NAV_KP"] = 6.0                                  # as if loaded from the .parm file

    def step_at(t_s: float) -> float:
        for ms in range(int(app.now * 1000) + 5000, int(t_s * 1000), 5000):   # the FC's clock ticking there
            app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=ms))
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=int(t_s * 1000)))
        assert app.now == t_s
        app.mag.averager.add(app.mission_time() - 0.5, 1.0, 50.0)
        app.mission_state.command = None    # each step as the first: no plausibility judgement (the core is prepared)
        app.phases.step(app.now, app.mission_time())
        return mission.seen[-1].kp

    assert math.isnan(step_at(10.0))                                   # the file's value: none
    param_set = mavlink.MAVLink_param_set_message(1, app.link.component, b"NAV_KP", 7.0, mavlink.MAV_PARAM_TYPE_REAL32)
    param_set.pack(mavlink.MAVLink(None, 255, 190))                    # from the ground station
    app.handle(param_set)
    assert app.params.age_s("NAV_KP", app.now) == pytest.approx(0.0)
    assert not app.settings.dirty              # a reading: no configuration is rebuilt for it
    assert step_at(20.0) == 7.0                                        # set over the link: the step's Kp
    assert step_at(10.0 + KP_MAX_AGE_S - 60.0) == 7.0                  # within an index period and the delay
    _sent(fc)
    assert math.isnan(step_at(10.0 + KP_MAX_AGE_S + 60.0))             # not renewed: none again, and said once
    said = [m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT"]
    assert [t for t in said if "NAV_KP not renewed for 210 min" in t] and not [t for t in said if "NAV_SYMH" in t]
    assert math.isnan(step_at(10.0 + KP_MAX_AGE_S + 120.0))
    assert not [m for m in _sent(fc) if m.get_type() == "STATUSTEXT" and "NAV_KP" in m.text]


def test_a_step_records_its_latency_and_the_parts_the_benchmark_splits_it_into(rig):
    """Each step that reaches the core records its wall time and that of its average, judgement and
    core (``fcmpc-bench`` prints their medians); the parts fit inside the whole."""
    app, _ = rig
    _run_step(app, GOOD)
    s = app.stepper
    assert len(s.step_latency_s) == len(s.average_latency_s) == len(s.judge_latency_s) == len(s.core_latency_s) == 1
    parts = s.average_latency_s[0] + s.judge_latency_s[0] + s.core_latency_s[0]
    assert 0.0 < parts <= s.step_latency_s[0]
    assert all(v > 0.0 for v in (s.average_latency_s[0], s.judge_latency_s[0], s.core_latency_s[0]))


def test_a_rejected_period_is_said_counted_and_the_last_command_flies_on(rig):
    """The navigator's answer to a period it rejected (phase HOLD, the last command flown on):
    over the socket, a WARNING naming the reason, the counts as FC_REJ / FC_FIXREJ, and the
    setpoint stream going on at the last command's course and speed; no failsafe."""
    app, fc = rig
    _run_step(app, GOOD)
    _sent(fc)
    held = replace(GOOD, phase="hold", est_sigma_m=math.nan, fix_lat_deg=math.nan, fix_lon_deg=math.nan,
                   reason="measurement rejected: ValueError: latitude 115.94 deg outside [-90, 90]")
    mission = FakeMission(held)
    mission.rejected_measurements, mission.rejected_fixes = 1, 7
    app.mission_state.command = None                       # judged as a first step: the stand-in core has no field model
    app.mission_state.mission = mission
    app.mag.averager.add(1.5, 1.0, 50.0)
    app.phases.step(app.now, 2.0)
    app.next_tick = -math.inf
    app.tick()
    sent = _sent(fc)
    [said] = [m for m in sent if m.get_type() == "STATUSTEXT" and "phase hold" in m.text]
    texts = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")   # (sent in chunks)
    assert "measurement rejected: ValueError" in texts and said.severity == mavlink.MAV_SEVERITY_WARNING
    counts = {m.name: m.value for m in sent if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert counts["FC_REJ"] == 1.0 and counts["FC_FIXREJ"] == 7.0
    setpoints = [m for m in sent if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert setpoints and all(m.yaw == pytest.approx(GOOD.course_rad) for m in setpoints)
    assert math.hypot(setpoints[-1].vx, setpoints[-1].vy) == pytest.approx(GOOD.speed_mps, rel=1e-6)
    assert app.state == State.RUNNING and app.mission_state.restarts == 0
    assert app.summary()["nav_rejected"] == {"periods": 1, "fixes": 7}

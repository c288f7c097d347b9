"""Phase transitions driven by the flight controller: a reboot, a pilot's mode change, our own late HOLD."""
from __future__ import annotations

import math

import pytest
from pymavlink import mavutil

from companion.app import AppOptions, CompanionApp, State
from companion.io.link import mavlink
from companion.io.sensors.base import SampleKind
from companion.process.machine import Event
from companion.process.mode_commands import MODE_CONFIRM_S
from companion.process.phases import Transition
from tests.companion.process.rig import ARMED_GUIDED, GOOD, _msg, _run_step, _sent
from tests.ports import free_port


def test_flight_controller_reboot_continues_the_mission(rig):
    """A reboot under a running mission: said, the streams asked for again, and once the FC is armed
    in GUIDED again the same mission goes on at its step and step clock (no start-up average, no
    navigation restart). It used to restart the mission as a navigation failure."""
    app, fc = rig
    _run_step(app, GOOD)
    mission, number = app.mission_state.mission, app.mission_state.mission_no
    for ms in range(2_000, 30_001, 4_000):                                       # the clock ticks on to 30 s
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=ms))
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2_000))          # one frame 28 s back: no reboot
    assert app.state == State.RUNNING and app.link.clock.far_past == 1
    to_go = app.mission_state.next_step_m - app.mission_time()                                 # until the next step
    _sent(fc)
    for ms in (2_100, 2_200, 2_300):                                               # the new base ticks on ...
        app.handle(_msg("ATTITUDE", time_boot_ms=ms, roll=0, pitch=0, yaw=0, rollspeed=0, pitchspeed=0,
                        yawspeed=0))
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "base_mode": 1, "custom_mode": 16}))   # ... disarmed, booting
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2_400))          # and its SYSTEM_TIME: a reboot
    assert app.state == State.READY and app.mission_state.restarts == 0 and app.mission_state.mission is mission
    assert app.resume.pending is not None and app.resume.pending.command.step == GOOD.step
    sent = _sent(fc)
    said = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert "rebooted" in said and "goes on from its last estimate" in said
    assert [m for m in sent if m.get_type() == "COMMAND_LONG"
            and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL], "the streams were not asked for again"
    # the FC is armed in GUIDED again (by us: COMP_ARM_ENABLE, or by the operator): the mission goes on
    app.handle(_msg("HEARTBEAT", **ARMED_GUIDED))
    for ms in range(2_600, 4_201, 400):                                           # healthy for over 1 s
        app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}
        app.next_tick = -math.inf
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=ms))
    assert app.state == State.RUNNING and app.mission_state.mission is mission and app.mission_state.mission_no == number and app.mission_state.restarts == 0
    assert app.mission_state.command.step == GOOD.step and app.resume.resumed_from == f"mission {number} step {GOOD.step}"
    assert app.mission_state.next_step_m - app.mission_time() == pytest.approx(to_go, abs=0.5)   # the step clock kept


def test_operator_mode_change_is_respected(rig):
    """A mode change the companion did not command pauses the mission; it does not fight back."""
    app, fc = rig
    app.params.set_value("COMP_ARM_ENABLE", 1)
    _run_step(app, GOOD)
    app.next_tick = -math.inf
    app.tick()
    _sent(fc)
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "custom_mode": 0}))        # the pilot selects MANUAL
    app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}
    app.next_tick = -math.inf
    app.tick()
    sent = _sent(fc)
    assert "FC left GUIDED (now MANUAL)" in "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert not [m for m in sent if m.get_type() == "COMMAND_LONG"]               # no GUIDED, no arm
    assert math.isfinite(app.clock.paused_since)                                       # mission clock stopped


# --- issue 10 item 5: the companion's own mode commands are told from a pilot's --------------------
GUIDED, HOLD = 15, 4          # ArduPilot Rover custom_mode


def _at(app, t_s: float, custom_mode: int = GUIDED, mag_fresh: bool = True) -> None:
    """The FC at message time ``t_s`` in ``custom_mode``, then one control tick."""
    app.next_tick = math.inf                                          # the tick below, not one on receipt
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=int(t_s * 1000)))
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "custom_mode": custom_mode}))
    app.intake.last_valid[SampleKind.ATTITUDE] = app.now
    if mag_fresh:
        app.intake.last_valid[SampleKind.MAG] = app.now
    app.next_tick = -math.inf
    app.tick()


def _mode_commands(sent: list) -> list[int]:
    return [int(m.param2) for m in sent if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE]


def _failsafe_then_recovered(app, fc) -> None:
    """A magnetometer failsafe (HOLD sent, the FC stays in GUIDED: the HOLD is still on its way),
    then healthy again: the mission resumes in GUIDED."""
    app.params.set_value("COMP_ARM_ENABLE", 1)
    _run_step(app, GOOD)
    _at(app, 2.0)
    _at(app, 5.0, mag_fresh=False)                                    # mag 3 s old > COMP_MAG_TMO_S
    assert app.failsafe_active and _mode_commands(_sent(fc)) == [HOLD]
    _at(app, 6.0)
    _at(app, 7.5)                                                     # healthy for 1.5 s
    assert not app.failsafe_active and not math.isfinite(app.clock.paused_since)
    assert "healthy again" in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")


def test_a_late_hold_of_ours_is_taken_back_not_read_as_a_pilots(rig):
    """The probe's stall: the failsafe's HOLD reaches the FC after the companion resumed."""
    app, fc = rig
    _failsafe_then_recovered(app, fc)
    _at(app, 9.0, HOLD)                                               # the late HOLD arrives
    sent = _sent(fc)
    texts = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert "mission paused" not in texts and "FC left" not in texts
    assert _mode_commands(sent) == [GUIDED]                           # taking it back at once
    assert not app.modes.pending or list(app.modes.pending) == [GUIDED]
    _at(app, 10.0, GUIDED)
    _at(app, 11.0, GUIDED)
    assert app.state == State.RUNNING and not math.isfinite(app.clock.paused_since)   # flying the mission again
    assert [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]


def test_a_hold_after_our_command_expired_is_the_pilots(rig):
    """Past the deadline our HOLD was lost; a HOLD now is somebody else's and is respected."""
    app, fc = rig
    _failsafe_then_recovered(app, fc)
    _at(app, 5.0 + MODE_CONFIRM_S + 1.0)
    _at(app, 5.0 + MODE_CONFIRM_S + 2.0, HOLD)
    sent = _sent(fc)
    assert "FC left GUIDED (now HOLD): mission paused" in "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert not _mode_commands(sent) and math.isfinite(app.clock.paused_since)
    assert app.modes.expired >= 1


def test_our_hold_seen_only_when_heartbeats_return_is_still_ours(rig):
    """heartbeat_off: the FC streams on without heartbeats while it takes our HOLD; its mode shows
    only when heartbeats return, long after MODE_CONFIRM_S of message time."""
    app, fc = rig
    app.params.set_value("COMP_ARM_ENABLE", 1)
    _run_step(app, GOOD)
    _at(app, 2.0)
    # no heartbeat: message time runs on (in 2 s stamps: the clock takes a jump of 10 s only on evidence)
    for t in sorted({3.0, 6.0, 6.0 + MODE_CONFIRM_S, 8.0 + 2 * MODE_CONFIRM_S,
                     *(float(v) for v in range(4, int(8.0 + 2 * MODE_CONFIRM_S), 2))}):
        app.next_tick = math.inf
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=int(t * 1000)))
        app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}
        app.next_tick = -math.inf
        app.tick()
    assert app.failsafe_active and HOLD in _mode_commands(_sent(fc))
    _at(app, 9.0 + 2 * MODE_CONFIRM_S, HOLD)                         # heartbeats back: the FC is in HOLD
    _at(app, 10.5 + 2 * MODE_CONFIRM_S, HOLD)
    sent = _sent(fc)
    assert "mission paused" not in "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert GUIDED in _mode_commands(sent)                              # taken back once healthy


@pytest.mark.parametrize("fus_model", [2, 3])
def test_filter_calibrates_at_a_nav_start_start(rig, monkeypatch, fus_model):
    """Without GPS the mission starts from NAV_START, which the error-state filter takes as a position
    measurement (FUS_GPS_M); it observes its bias states there too (NAV_CALIBRATE 1). Before, it did so
    only at a GPS start, and closed loop against the stand-in (no GPS) its bias states were first pinned
    a step later against a 2.5 km INS prior: 0.9 km off at the end of the short mission, 0.3 km in-process."""
    app, _ = rig
    app.machine.state = State.READY
    app.params.set_value("FUS_MODEL", fus_model)
    app.settings.apply()
    monkeypatch.setattr(app.stepper, "step", lambda *a, **k: None)   # the mission's set-up, not its first step
    for t in range(10):
        app.mag.averager.add(0.1 * t, -3.9, 44.3)
    assert app.preparation.start_position()[2] == "NAV_START"
    app.phases.take(Transition(Event.ENGAGED), app.now)                 # ready -> running: the mission starts
    mission = app.mission_state.mission
    assert mission.estimator is not None and mission.estimator.calibrate_start
    assert mission.start_sigma_m == app.settings.nav.gps_sigma_m


def test_px4s_messages_read_before_its_first_heartbeat_do_not_start_the_companion_as_ardupilot(tmp_path):
    """PX4 already streaming when the companion starts listening: its ATTITUDE and SCALED_IMU wait
    in the socket before its first HEARTBEAT, one read takes them all, and the heartbeat pins the
    FC while the batch is parsed. Nothing before that heartbeat is kept, so the companion starts on
    PX4's conventions (CI, 2026-12-02: it said "ArduPilot FC sysid 3 detected", asked for the wrong
    magnetometer messages and excluded every step)."""
    from pymavlink import mavutil

    from companion.app import AppOptions, CompanionApp

    port = free_port()
    app = CompanionApp(AppOptions(connect=f"udpin:127.0.0.1:{port}", params=str(tmp_path / "p.parm"),
                                  log_dir=str(tmp_path / "log"), quiet=True, tlog=False))
    app.open()
    fc = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=3, source_component=1)
    try:
        for k in range(5):
            fc.mav.attitude_send(20_000 + 20 * k, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
            fc.mav.scaled_imu_send(20_000 + 20 * k, 0, 0, -1000, 0, 0, 0, 200, 20, 400)
        fc.mav.heartbeat_send(mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_PX4, 1, 4 << 16 | 3 << 24, 3)
        fc.mav.system_time_send(0, 20_200)
        app.link.wait_readable(5.0)           # all of it is queued: the companion's first read holds it
        for _ in range(20):
            app.spin(0.05)
            if app.state != State.WAIT_FC:
                break
        assert app.state != State.WAIT_FC, "the PX4 heartbeat was not taken"
        detected = [e for e in app.voice.events if "detected" in e]
        assert len(detected) == 1 and "PX4 FC sysid 3 detected" in detected[0], detected
        assert app.link.fc.conventions.name == "PX4" and app.fc_view.family == app.link.fc.conventions.family
        assert app.link.stats.before_heartbeat >= 1, "the batch did not hold messages before the heartbeat"
    finally:
        fc.close()
        app.close()


def test_the_streams_are_asked_for_at_the_first_heartbeat_before_any_timed_message(tmp_path):
    """A flight controller whose port streams nothing timed (every stream group off, as ArduPilot
    4.7's MAVn_* allow): the companion's clock starts on a timed message, so it asks for its streams
    at the FC's first heartbeat rather than wait for one that never comes."""
    port = free_port()
    fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    app = CompanionApp(AppOptions(connect=f"udpout:127.0.0.1:{port}", params=str(tmp_path / "p.parm"),
                                  log_dir=str(tmp_path / "log"), quiet=True, tlog=False))
    app.open()
    try:
        app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "base_mode": 1, "custom_mode": 4}))
        assert not app.link.clock.started and app.state == State.WAIT_FC
        asked = {int(m.param1) for m in _sent(fc)
                 if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL}
        assert {mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, mavlink.MAVLINK_MSG_ID_ATTITUDE} <= asked
    finally:
        app.close()
        fc.close()

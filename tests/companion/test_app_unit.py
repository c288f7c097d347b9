"""The companion's failsafe decisions, driven message by message (no simulator).

A pymavlink receiver plays the flight controller's socket, so what the companion sends is
read back from the wire.
"""
from __future__ import annotations

import math
import os
import socket
import time
from dataclasses import replace

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.app import AppOptions, CompanionApp, State  # noqa: E402
from companion.io.mavlink_link import mavlink  # noqa: E402
from companion.io.sensors.base import SampleKind  # noqa: E402
from companion.nav.mission import Command, Mission  # noqa: E402
from companion.params import NavConfig, default_values  # noqa: E402

ARMED_GUIDED = dict(type=11, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                    base_mode=mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                    custom_mode=15, system_status=4, mavlink_version=3)


def _msg(name: str, **fields):
    msg = getattr(mavlink, f"MAVLink_{name.lower()}_message")(**fields)
    msg.pack(mavlink.MAVLink(None, 1, 1))
    return msg


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FakeMission:
    """Stands in for the core: returns a prepared command."""

    def __init__(self, command: Command) -> None:
        self.config = NavConfig.from_values(default_values())
        self.command = command
        self.k = command.step

    def step(self, meas):
        return self.command

    def reconfigure(self, new):
        return []


GOOD = Command(time_s=360.0, step=5, phase="cruise", course_rad=2.3, speed_mps=13.0, done=False, est_lat_deg=32.5,
               est_lon_deg=152.5, est_sigma_m=800.0, remaining_m=70_000.0, fix_lat_deg=32.5, fix_lon_deg=152.51)


@pytest.fixture
def rig(tmp_path):
    port = _free_port()
    fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    app = CompanionApp(AppOptions(connect=f"udpout:127.0.0.1:{port}", params=str(tmp_path / "p.parm"),
                                  log_dir=str(tmp_path / "log"), quiet=True, tlog=False))
    app.open()
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "base_mode": 1, "custom_mode": 4}))   # disarmed in HOLD
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=1000))
    assert app.state == State.STARTUP and not app.failsafe_active
    app.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}   # sensors fresh
    app.handle(_msg("HEARTBEAT", **ARMED_GUIDED))
    app.state = State.RUNNING
    app.m0 = 0.0
    yield app, fc
    app.close()
    fc.close()


def _sent(fc, quiet_s: float = 0.15, limit_s: float = 3.0) -> list:
    """Everything received until the socket was quiet for ``quiet_s``."""
    out, deadline = [], time.monotonic() + limit_s
    while time.monotonic() < deadline:
        msg = fc.recv_match(blocking=True, timeout=quiet_s)
        if msg is None:
            break
        out.append(msg)
    return out


def _run_step(app: CompanionApp, command: Command) -> None:
    app.mission = FakeMission(command)
    app.mag.averager.add(0.5, 1.0, 50.0)
    app._step(1.0)


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
    assert app.state == State.STARTUP and app.restarts == 1 and app.mission is None
    assert app.restart_from == pytest.approx((32.5, 152.5))           # from the last estimate
    texts = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert "FAILSAFE" in texts and why in texts
    holds = [m for m in sent if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE]
    assert holds and holds[0].param2 == 4                              # ArduPilot Rover HOLD
    app.tick()
    assert not [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]


def test_good_step_streams_and_publishes(rig):
    app, fc = rig
    app.params.set_value("COMP_POS_PUB", 0)      # EXTERNAL_POSITION_ESTIMATE (the default is GPS_INPUT)
    app._apply_params()
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


def test_odometry_when_selected(rig):
    app, fc = rig
    app.params.set_value("COMP_POS_PUB", 1)
    app._apply_params()
    app.handle(_msg("GLOBAL_POSITION_INT", time_boot_ms=1000, lat=325000000, lon=1525000000, alt=0, relative_alt=0,
                    vx=0, vy=0, vz=0, hdg=0))
    app.handle(_msg("LOCAL_POSITION_NED", time_boot_ms=1000, x=1000.0, y=-500.0, z=0.0, vx=0.0, vy=0.0, vz=0.0))
    _run_step(app, GOOD)
    [odo] = [m for m in _sent(fc) if m.get_type() == "ODOMETRY"]
    # the estimate is the FC's own position here, so it sits at the FC's local (x, y)
    assert odo.x == pytest.approx(1000.0, abs=0.5) and odo.y == pytest.approx(-500.0, abs=0.5)
    assert odo.pose_covariance[0] == pytest.approx(800.0 ** 2) and odo.frame_id == mavlink.MAV_FRAME_LOCAL_NED


def test_silent_flight_controller_is_judged_in_wall_time(rig):
    """No message at all: message time stands still, so only the wall clock can tell."""
    app, fc = rig
    app.mission = FakeMission(GOOD)
    app.command = GOOD
    start = app.link.fc.last_heartbeat_wall_s
    app.link.wall = lambda: start + 3.5                                # 3.5 s of silence (COMP_HB_TMO_S = 3)
    app.last_hb_sent_wall = -math.inf
    app.idle()
    assert app.failsafe_active and any("wall time" in r for r in app.health.reasons)
    texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
    assert "heartbeat" in texts
    app.next_tick = -math.inf
    app.tick()
    assert not [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]


def test_real_mission_first_step_probes_east(rig):
    app, fc = rig
    app.mission = Mission(NavConfig.from_values(default_values()))
    app.mag.averager.add(0.5, -1.5, 48.0)
    app._step(1.0, window_limit_s=0.0)
    assert app.command.phase == "probe1" and app.command.course_rad == pytest.approx(math.pi / 2)


def test_flight_controller_reboot_restarts_the_mission(rig):
    app, fc = rig
    _run_step(app, GOOD)
    for ms in range(2_000, 30_001, 4_000):                                       # the clock ticks on to 30 s
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=ms))
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2_000))          # one frame 28 s back: no reboot
    assert app.state == State.RUNNING and app.link.clock.far_past == 1
    for ms in (2_100, 2_200, 2_300):                                               # the new base ticks on ...
        app.handle(_msg("ATTITUDE", time_boot_ms=ms, roll=0, pitch=0, yaw=0, rollspeed=0, pitchspeed=0,
                        yawspeed=0))
    app.handle(_msg("HEARTBEAT", **ARMED_GUIDED))                                 # ... with the FC's heartbeat
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2_400))          # and its SYSTEM_TIME: a reboot
    assert app.state == State.STARTUP and app.restarts == 1 and app.mission is None
    assert "rebooted" in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")


def test_operator_mode_change_is_respected(rig):
    """A mode change the companion did not command pauses the mission; it does not fight back."""
    app, fc = rig
    app.params.set_value("COMP_ARM_ENABLE", 1)
    _run_step(app, GOOD)
    app.next_tick = -math.inf
    app.tick()
    _sent(fc)
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "custom_mode": 0}))        # the pilot selects MANUAL
    app.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}
    app.next_tick = -math.inf
    app.tick()
    sent = _sent(fc)
    assert "FC left GUIDED (now MANUAL)" in "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert not [m for m in sent if m.get_type() == "COMMAND_LONG"]               # no GUIDED, no arm
    assert math.isfinite(app.paused_since)                                       # mission clock stopped

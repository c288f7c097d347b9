"""Real ArduPilot Rover SITL with OUR world as its physics (``--model JSON``), in lockstep.

The world's process (:mod:`sitl.physics.ardupilot_json`) answers every ArduPilot frame and waits
for the companion whenever one of its messages could be due that it has not sent yet, so ArduPilot's
clock advances only as fast as both answer: no wall-time pacing, nothing a loaded machine can break. The GPS-lost mission test here
replaced the wall-paced one of test_ardupilot.py (ArduPilot's 3 s GUIDED timeout was 60 ms of wall
time at 50x); the other wall-paced tests with the built-in motorboat stay as the independent check.
"""
from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import pytest

from fcmpc.firmware import ArduPilotSitl
from fcmpc.firmware.monitor import FirmwareMonitor
from sitl.physics.relay import relay_port
from fcmpc.firmware.ardupilot_json_rig import JSON_PARAMS, start_world, stop_world
from tests.firmware.conftest import _WORKER, Rig, _binary_or_skip, claim_instance
from tests.firmware.conftest import assert_guided_and_on_course_without_gps

GUIDED = 15
WALL_S = 300.0          # a hang guard: lockstep keeps no wall pace
START_UNIX_S = 1715364000.0   # the Pacific scenario's start (2024-05-10), as fcmpc-fly gives ArduPilot


class JsonRig(Rig):
    """The world's process + ArduPilot (--model JSON) + the monitor + (later) the companion via the relay."""

    companion_args = ("--lockstep",)

    def __init__(self, tmp_path: Path, params: dict | None = None, relay: bool = True,
                 motor_field: str | None = None) -> None:
        self.tmp = tmp_path
        tmp_path.mkdir(parents=True, exist_ok=True)
        binary = _binary_or_skip()
        self.claims = contextlib.ExitStack()      # the instance, held until close()
        instance = claim_instance(self.claims, "ardupilot", 51, 90, 51 + (_WORKER % 4) * 10 + os.getpid() % 5)
        self.instance = instance
        self.companion: subprocess.Popen | None = None
        self.monitor = None
        self.stats: dict = {}
        self.world = start_world(instance, (33.0, 152.0), (0.0, 0.0), tmp_path, relay, motor_field)
        self.sitl = ArduPilotSitl(workdir=tmp_path / "ardupilot", instance=instance, model="JSON", speedup=1e6,
                                  params={**JSON_PARAMS, **(params or {})}, binary=binary,
                                  start_unix_s=START_UNIX_S)
        self.sitl.start()
        self.sitl.wait_listening()
        self.monitor = FirmwareMonitor(self.sitl.serial0)
        self.monitor.start()

    @property
    def companion_url(self) -> str:
        return f"tcp:127.0.0.1:{relay_port(self.instance)}"

    def close(self) -> dict:
        """Stop everything by PID (once); the world's statistics (frames, lockstep waits and timeouts)."""
        if self.world is not None:
            super().close()
        return self.stats

    def stop_firmware(self) -> None:
        self.stats = stop_world(self.world, self.sitl, self.tmp)
        self.world = None


@pytest.fixture
def json_rig(tmp_path):
    """``json_rig(name, params=None, relay=True)``: a JsonRig in its own folder, closed after the test."""
    rigs: list[JsonRig] = []
    yield lambda name, **options: rigs.append(JsonRig(tmp_path / name, **options)) or rigs[-1]
    for rig in rigs:
        rig.close()


def test_ardupilots_throttle_and_steering_move_our_boat_where_ardupilot_believes_it_is(json_rig):
    """No companion: ArduPilot armed in MANUAL with its throttle stick at 80 % drives our world's boat
    (SERVO3 -> speed, SERVO1 -> turn); its own copy of our state (SIMSTATE) is where our world put
    the boat, within a metre, after hundreds of metres (the NED offsets invert ArduPilot's
    ``Location::offset``), the boat ran forward along its heading, and every frame was 20 ms."""
    from companion.nav.geo import geodesic_distance_m, geodesic_inverse
    from fcmpc.firmware.monitor import mavlink

    rig = json_rig("manual", params={"GPS2_TYPE": 0, "RC_OVERRIDE_TIME": -1}, relay=False)
    mon = rig.monitor
    mon.pump(lambda m: m.gps_fix >= 3 and m.time_s > 40.0, WALL_S, "a GPS fix")
    mon.conn.mav.set_mode_send(mon.target_system, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0)   # MANUAL
    mon.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
    mon.pump(lambda m: m.armed, WALL_S, "armed")
    mon.conn.mav.rc_channels_override_send(mon.target_system, 1, 1500, 65535, 1900, 65535, 65535, 65535, 65535, 65535)
    t0 = mon.time_s
    mon.pump(lambda m: m.time_s > t0 + 60.0, WALL_S, "a minute at 80 % throttle")
    moving = [s for s in mon.truth if s.time_s > t0 + 20.0]
    a, b = moving[0], moving[-1]
    speed = geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg) / (b.time_s - a.time_s)
    track = geodesic_inverse(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg)[1]
    assert speed == pytest.approx(8.0, abs=0.3), speed              # BoatDynamics: 10 m/s at full throttle
    assert abs((track * 57.29577951308232 - a.yaw_deg + 180.0) % 360.0 - 180.0) < 5.0
    mon.conn.mav.rc_channels_override_send(mon.target_system, 1, 1500, 65535, 1500, 65535, 65535, 65535, 65535, 65535)
    t1 = mon.time_s
    mon.pump(lambda m: m.time_s > t1 + 30.0, WALL_S, "coming to rest")
    last = mon.truth[-1]
    stats = rig.close()
    assert stats["frames"] > 0 and stats["sim_s"] == pytest.approx(stats["frames"] * 0.02, abs=1e-6)
    assert geodesic_distance_m(last.lat_deg, last.lon_deg, stats["lat_deg"], stats["lon_deg"]) < 1.0


@pytest.mark.slow
def test_lockstep_gps_lost_after_start_up_guided_kept_and_on_course(json_rig):
    """GPS lost 30 s (of firmware time) after arming: the companion feeds GPS_INPUT, ArduPilot stays in
    GUIDED for 30 simulated minutes and our world's boat (moved by ArduPilot's own steering and throttle)
    follows the companion's courses. The world waited for the companion whenever it had to and never
    gave up; the companion's frames reached ArduPilot at their stamps plus the relay's latency (the
    GPS_INPUT feed at the 100 ms of firmware time ArduPilot judges a GPS's health on)."""
    rig = json_rig("gps_lost")
    log_dir = rig.start_companion(startup_s=30.0, NAV_DEST_LAT=28.0, NAV_DEST_LON=158.0, NAV_PERIOD_S=120.0)
    mon = rig.monitor
    # ArduPilot may refuse to arm for a while ("GPS 2: not healthy", once for 1,500 s of firmware time:
    # the note's open point); the companion retries, so the wall-time guard is generous
    mon.pump(lambda m: m.armed and m.mode == GUIDED, 3 * WALL_S, "armed in GUIDED")
    t_arm = mon.time_s
    mon.pump(lambda m: m.time_s >= t_arm + 30.0, WALL_S, "30 s after arming")
    mon.set_param("SIM_GPS1_ENABLE", 0)
    mon.pump(lambda m: m.truth and m.truth[-1].gps_fix < 3, WALL_S, "GPS lost")
    t_lost = mon.time_s
    mon.pump(lambda m: m.truth[-1].time_s > t_lost + 1800.0 or m.mode != GUIDED, 3 * WALL_S,
             "30 minutes without GPS")
    assert_guided_and_on_course_without_gps(mon, log_dir, t_lost)
    stats = rig.close()
    # the gate read the companion as its frames' due times neared (2,708 times in 2,671 s, waiting at 157 of
    # them, at a load average of 12), never gave up and never let a frame through before it was known
    assert stats["lockstep_reads"] > 1000 and stats["lockstep_timeouts"] == 0, stats
    # ... but at the start: before the companion asks for its streams, ArduPilot's only timed message on its
    # port comes once a second (MAV2_POSITION), less fresh than the latency needs (6 fallbacks in one run)
    assert stats["lockstep_last_fallback_s"] < t_arm, stats
    # late frames only before the companion's first stamped frame (none here; 3 in 56,689 on a 20 km leg);
    # the relay of boundaries every 0.2 s before the gate let 6 % through late at a load average of 22
    assert stats["relay_late_frames"] < 0.01 * stats["relay_frames_to_fc"], stats

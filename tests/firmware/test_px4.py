"""The companion against real PX4 SITL with SIH (Ackermann rover): what the PX4 issue names.

Every test starts PX4 in its own folder with its own ``PX4_INSTANCE`` (claimed for the test, see
:func:`fcmpc.firmware.instances.claimed_instance`), a monitor on PX4's ground-station link
(HIL_STATE_QUATERNION, SIH's ground truth) and the companion listening on PX4's onboard link,
and waits on events (texts, heartbeats, firmware time), never on sleeps.
"""
from __future__ import annotations

import asyncio
import os
import select
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from companion.params import REGISTRY, read_parm_file
from fcmpc.firmware.px4 import read_qgc_params
from tests.firmware.conftest import assert_forward_on, moving_pairs
from tests.ports import free_port

OFFBOARD = 6 << 16                    # PX4 custom_mode: main mode in bits 16-23
AUTO_LOITER = (4 << 16) | (3 << 24)   # AUTO (4), sub mode LOITER (3): the rover's Hold
WALL_S = 400.0                        # generous: a loaded 2-core machine runs SIH far below its speed factor
ROVER_MIN_SPEED = 1.5                 # m/s: "moving" for a 3 m/s rover
# NAV_PERIOD_S: the gradient needs moves of 200 m between the centres of the averaging windows,
# and the first probe's window starts at rest, so it counts half its length: 160 s at 3 m/s.
PROBE_S = 160.0
# PX4's speed factor for the quadrant test (the rig's default is 12). Issue 15: this test failed in
# parallel CI runs (a reversing heading, a track 17 deg off) and was skipped as flaky under load.
# Cause, measured beside another session's parallel test run (load average 14-21): at 12x SIH keeps
# its pace while the companion (Python) and the monitor are starved. The companion fell hundreds of
# simulated seconds behind PX4 (its step 1 at 328 s of its message time reached PX4 at 657 s), lost
# 61-188 s of PX4's messages in gaps, PX4 said "Connection to mission computer lost" a dozen times,
# and the companion's own failsafe took the rover to Hold mid-probe; the judged windows showed the
# CI symptoms (SW-NW's track 229-259 deg on 225 with the heading 50-70 deg off it; NE-SE's heading
# 38 deg off its track once). At 4x a wall-time stall costs a third of the simulated time. Measured
# at 4x (PX4 runs at about 1x until the rover arms, then 3.9x): 2 of 2 passed beside other sessions'
# runs (load 8-10; 262 s each) and 4 of 4 beside two busy processes as well (load 4.6-7.7; 266-276 s);
# in all six the companion's steps reached PX4 within 0.4 s of simulated time, no message gap, track
# within 4.2 deg of the course (15 allowed), heading within 2.4 deg of the track (30 allowed). Those
# runs used the 160 s start-up average; since 2026-12-02 the rig's 30 s at 50 Hz (PX4_STARTUP_S).
QUADRANT_SPEED = 4.0
REPO = Path(__file__).resolve().parents[2]


def _next_phase_s(mon, after_s: float) -> float | None:
    """Monitor time of the companion's first phase text after ``after_s`` that is not probe 2."""
    later = [t for t, _, text in mon.texts_matching(" phase ", 191) if t > after_s and "phase probe2" not in text]
    return later[0] if later else None


def _offboard_samples(truth, t0: float, t1: float):
    return [s for s in truth if t0 <= s.time_s <= t1]


# Issue 15: PX4's HIGHRES_IMU has EKF2's magnetometer-bias state subtracted, which wandered by
# thousands of nT in flight (|F| -5,500 nT after 15 min of driving); the companion reads SCALED_IMU
# (sensor_mag) on PX4 (companion/io/px4.py), and the test below checks that no step was excluded.
PX4_MAG_DRIFT = "HIGHRES_IMU's |F| drifted thousands of nT (EKF2's mag bias state): every step was excluded"


# Issue 15, fix noise: SIH's magnetometer (0.02-0.03 gauss per axis) and its accelerometer shaking while
# the rover drives make a 160 s period's gravity-referenced I good to only 0.21-0.29 deg (its standard
# error), fixes scattering 12-190 km. The per-sample average of I_g was also biased -0.4 deg driving;
# now a ratio of averages (companion/nav/inclination.py) and the fix_jump bound has a term for the
# period's own noise (130-210 km here): no step was excluded and 6 of 6 runs passed (NE-SE 201 s and
# 206 s, SW-NW 203 s and 205 s of wall time, and one more of each); the third run of the old companion timed out in its
# first probe (16 exclusions, 30-183 km).


@pytest.mark.parametrize("probes", [
    pytest.param((45.0, 315.0), id="NE-SE"),
    pytest.param((225.0, 135.0), id="SW-NW"),
])
def test_offboard_engaged_held_and_every_quadrant_driven_forward(px4_factory, probes):
    """OFFBOARD after setpoints stream, held through both probing moves (courses NE, SE or SW, NW),
    each driven forward; then an operator's Hold is respected, not fought."""
    rig = px4_factory("quadrants", speed=QUADRANT_SPEED)
    # the rig's 30 s start-up average: at 10 Hz it took SIH's noise into the calibration at the start
    # (I -0.30 deg), every step's fix then implied a 220-290 km jump against a 170-200 km bound, and the
    # second probe never came (CI run of 2026-11-30), so this test averaged one period (160 s, ~1x
    # before arming: 130 s more wall time per case); at SIH's 50 Hz (COMP_MAG_HZ, 2026-12-01) 30 s
    # are 1500 samples, as many as 160 s were
    rig.start_companion(NAV_DEST_LAT=32.9, NAV_DEST_LON=152.1, NAV_PERIOD_S=PROBE_S,
                        NAV_PROBE1_DEG=probes[0], NAV_PROBE2_DEG=probes[1])
    mon = rig.monitor
    mon.pump(rig.said("phase probe2"), WALL_S, "second probing move")
    t1 = mon.texts_matching("phase probe1", 191)[0][0]
    t2 = mon.texts_matching("phase probe2", 191)[0][0]
    mon.pump(lambda m: _next_phase_s(m, t2) is not None, WALL_S, "the step after the second probe")
    # each probe is judged until 2 s before the step that ends it, as the monitor stamped that
    # step's text: a probe-2 text that reached the monitor late (load) moved a window ending at
    # t2 + PROBE_S - 2 into the cruise's turn of ~175 deg (15.02 deg off once in CI; measured, 8
    # runs: the rover leaves the course 2.4-3.3 s after that end, 1 s of turn inside is 2-3 deg)
    t3 = min(_next_phase_s(mon, t2), t2 + PROBE_S)
    held = _offboard_samples(mon.truth, t1 + 2.0, t3 - 2.0)
    assert held and all(s.mode == OFFBOARD and s.armed for s in held), \
        f"left OFFBOARD: modes {sorted({hex(s.mode) for s in held})}"
    courses = [(90.0 - p) % 360.0 for p in probes]
    assert_forward_on(mon.truth, t1 + 10.0, t2 - 2.0, courses[0], ROVER_MIN_SPEED)
    assert_forward_on(mon.truth, t2 + 10.0, t3 - 2.0, courses[1], ROVER_MIN_SPEED)
    assert not mon.texts_matching("mission failed", 191), mon.texts_matching("FcMPC", 191)
    assert not mon.texts_matching("stuck", 191), "SIH's magnetometer was judged stuck"
    # no period excluded for |F| (the f_band check): what HIGHRES_IMU's drifting field did ("nT off the
    # model" is the f_band words, single or sustained). A fix_jump exclusion stays possible (a fix more
    # than ~3 sigma of the period's own noise off: one of the 15 steps recorded on SIH came to 0.88
    # of its bound); it postpones a step by one period, which the waits allow
    assert not mon.texts_matching("nT off the model", 191), PX4_MAG_DRIFT
    # home is the mission's start, and the yaw is known to be the magnetometer's: (I, F), not D
    start = mon.truth[0]
    assert abs(start.lat_deg - 33.0) < 1e-4 and abs(start.lon_deg - 152.0) < 1e-4, (start.lat_deg, start.lon_deg)
    assert mon.texts_matching("elements (I, F): FC yaw is compass-derived (EKF2_MAG_TYPE 1", 191)
    # the operator selects Hold: the companion pauses and leaves the mode alone
    mon.send_command(176, 1, 4, 3)    # MAV_CMD_DO_SET_MODE, custom main 4 (AUTO) sub 3 (LOITER)
    mon.pump(lambda m: m.mode == AUTO_LOITER, WALL_S, "the operator's Hold")
    t_hold = mon.time_s
    mon.pump(rig.said("mission paused"), WALL_S, "the companion's pause")   # it may lag PX4 under load
    t_seen = mon.time_s
    mon.pump(lambda m: m.time_s >= max(t_hold + 30.0, t_seen + 10.0), WALL_S, "some time in the operator's Hold")
    after = _offboard_samples(mon.truth, t_hold + 1.0, mon.time_s)
    assert after and all(s.mode == AUTO_LOITER for s in after), "the companion took the vehicle back"


def test_companion_sigkill_leads_to_px4s_offboard_loss_failsafe(px4_factory):
    """The companion dies: PX4 leaves OFFBOARD for Hold (COM_OBL_RC_ACT 5) within COM_OF_LOSS_T."""
    rig = px4_factory("sigkill")
    rig.start_companion(NAV_DEST_LAT=32.9, NAV_DEST_LON=152.1, NAV_PERIOD_S=60.0)
    mon = rig.monitor
    mon.pump(rig.said("phase probe1"), WALL_S, "first probing move")
    t_probe = mon.time_s
    mon.pump(lambda m: m.time_s >= t_probe + 20.0, WALL_S, "driving")
    assert moving_pairs(mon.truth, t_probe + 5.0, mon.time_s, ROVER_MIN_SPEED), "not moving before the kill"
    assert mon.mode == OFFBOARD
    mon.drain()                  # the firmware's time now, not that of the last message read (under load
    t_kill = mon.time_s          # seconds of it sat in the socket: a CI run measured 26.0 s for 24); at or
    os.kill(rig.companion.pid, signal.SIGKILL)   # before the kill, so the delay below is not understated
    rig.companion.wait(timeout=10)
    mon.pump(lambda m: m.mode != OFFBOARD, WALL_S, "PX4's offboard-loss failsafe")
    t_failsafe = mon.time_s
    assert mon.mode == AUTO_LOITER, f"failsafe mode {mon.mode:#x}, expected Hold (AUTO.LOITER)"
    # PX4's heartbeat comes once a second: the mode change is seen up to 1 s after it happened
    assert t_failsafe - t_kill <= rig.loss_timeout_s + 1.5, \
        f"Hold {t_failsafe - t_kill:.1f} s after the kill, COM_OF_LOSS_T {rig.loss_timeout_s:g} s"
    mon.pump(lambda m: m.time_s >= t_failsafe + 25.0, WALL_S, "holding")
    assert not moving_pairs(mon.truth, t_failsafe + 15.0, t_failsafe + 25.0, min_speed_mps=0.5), \
        "still moving 15 s into Hold"
    # PX4's logger is off (fcmpc.firmware.px4.SIMULATOR_PARAMS): armed for a while, it wrote no ULog
    assert not list((rig.tmp / "px4").rglob("*.ulg")), "PX4 wrote a ULog"


async def _mavsdk_params(url: str) -> dict:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.plugins.param import ParamError, ProtocolVersion

    out: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(url)
        system = await sdk.first_autopilot(timeout_s=60)
        assert system is not None, "MAVSDK saw no autopilot"
        for _ in range(600):
            if 191 in await system.component_ids():
                break
            await asyncio.sleep(0.1)
        out["components"] = await system.component_ids()
        param = ParamAsync(system)
        try:
            await param.select_component(191, ProtocolVersion.V1)
        except ParamError:
            pass   # MAVSDK 4.1 reports UNKNOWN although the selection is made (tests/companion/test_ground_station.py)
        everything = await param.get_all_params()
        out["ints"] = {p.name: p.value for p in everything.int_params}
        out["floats"] = {p.name: p.value for p in everything.float_params}
        await param.set_param_float("NAV_SPEED_KMH", 9.5)
        await param.set_param_int("NAV_MAX_STEPS", 321)
        out["speed"] = await param.get_param_float("NAV_SPEED_KMH")
        out["steps"] = await param.get_param_int("NAV_MAX_STEPS")
    return out


class _GcsRelay(threading.Thread):
    """PX4's GCS link answers the first client that speaks to it, and MAVSDK listens (udpin) before it
    speaks: this relay speaks to PX4 first (a GCS heartbeat every second until PX4 answers) and
    passes datagrams both ways."""

    def __init__(self, px4_port: int, hello: bytes) -> None:
        super().__init__(daemon=True)
        self.px4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.px4.connect(("127.0.0.1", px4_port))
        self.hello = hello
        self.sdk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sdk.bind(("127.0.0.1", 0))
        self.sdk_port = free_port()
        self.stop = threading.Event()

    def run(self) -> None:
        answered = False
        while not self.stop.is_set():
            if not answered:
                self.px4.send(self.hello)
            ready, _, _ = select.select([self.px4, self.sdk], [], [], 1.0)
            for sock in ready:
                try:
                    data = sock.recv(65536)
                except ConnectionRefusedError:   # PX4 not listening yet
                    continue
                answered = answered or sock is self.px4
                if sock is self.px4:
                    self.sdk.sendto(data, ("127.0.0.1", self.sdk_port))
                else:
                    self.px4.send(data)


def test_mavsdk_lists_and_sets_companion_parameters_through_px4(px4_factory):
    """A ground station on PX4's GCS link reaches the companion (191) through PX4's forwarding;
    INT32 values travel bytewise, as PX4's own do."""
    pytest.importorskip("mavsdk")
    from pymavlink.dialects.v20 import common

    rig = px4_factory("mavsdk", monitor=False)
    # MAVSDK's ground station is system 245: allowed as the second ground station (LINK_GCS_ID2)
    log_dir = rig.start_companion(NAV_DEST_LAT=32.9, NAV_DEST_LON=152.1, NAV_PERIOD_S=60.0, LINK_GCS_ID2=245)
    mav = common.MAVLink(None, srcSystem=255, srcComponent=190)
    hello = common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav)    # MAV_TYPE_GCS, no autopilot
    relay = _GcsRelay(rig.sitl.ports_for(rig.sitl.instance)[1], hello)
    relay.start()
    try:
        result = asyncio.run(asyncio.wait_for(_mavsdk_params(f"udpin://127.0.0.1:{relay.sdk_port}"), WALL_S))
    finally:
        relay.stop.set()
        relay.join(timeout=5)
    assert 1 in result["components"] and 191 in result["components"]
    assert set(result["ints"]) | set(result["floats"]) == {spec.name for spec in REGISTRY}
    assert result["speed"] == pytest.approx(9.5) and result["steps"] == 321
    saved = read_parm_file(rig.tmp / "companion.parm")
    assert saved["NAV_SPEED_KMH"] == pytest.approx(9.5) and saved["NAV_MAX_STEPS"] == 321
    assert log_dir.exists()


def test_shipped_px4_params_parse_and_name_real_parameters():
    """params/px4-rover.params is QGroundControl's format and every name is one PX4 documents."""
    import xml.etree.ElementTree as ET

    values = read_qgc_params(REPO / "params" / "px4-rover.params")
    assert values["MAV_USEHILGPS"] == 1 and values["COM_OBL_RC_ACT"] == 5
    try:
        from fcmpc.firmware.px4 import px4_root

        xml = px4_root() / "parameters.xml"
    except Exception as err:  # noqa: BLE001 - FirmwareMissing: names cannot be checked here
        pytest.skip(str(err))
    known = {p.get("name") for p in ET.parse(xml).iter("parameter")}
    assert set(values) <= known, set(values) - known


def test_read_qgc_params_names_the_bad_line(tmp_path):
    path = tmp_path / "bad.params"
    path.write_text("# comment\n1\t1\tCOM_OBL_RC_ACT\t5\t6\n1\t1\tEKF2_REQ_EPH\t10\n")
    with pytest.raises(ValueError, match=r"bad.params:3"):
        read_qgc_params(path)


def test_main_job_says_in_one_line_when_px4_is_missing(tmp_path):
    env = {**os.environ, "FCMPC_PX4": str(tmp_path / "no-such-px4")}
    done = subprocess.run([sys.executable, "-m", "fcmpc.fly.cli", "--fc", "px4", "--out-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, env=env, timeout=120, stdin=subprocess.DEVNULL, cwd=REPO,
                          check=False)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no-such-px4" in lines[0] and "Traceback" not in done.stderr
    assert not (tmp_path / "run").exists()

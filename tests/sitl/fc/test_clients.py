"""Other real clients: PX4 conventions through pymavlink, and MAVSDK (4.x ctypes binding) flying offboard."""
from __future__ import annotations

import asyncio
import math
import threading
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.fc import ServerConfig, SitlServer
from tests.ports import free_port
from tests.sitl.conftest import gps_scenario

PX4_OFFBOARD, PX4_LOITER = 6 << 16, (4 << 16) | (3 << 24)


def test_px4_offboard_requires_streaming_and_falls_back_to_hold(sitl):
    server, client = sitl(autopilot="px4", speedup=20.0, init_s=0.2)
    client.recv("HEARTBEAT", 5.0,
                lambda m: m.custom_mode == PX4_LOITER and m.system_status == mavlink.MAV_STATE_STANDBY)
    set_mode = mavlink.MAV_CMD_DO_SET_MODE
    assert client.command(set_mode, 1, 6, 0).result == mavlink.MAV_RESULT_DENIED          # no setpoints yet
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    mask = 0b0000_1101_1100_0111
    for _ in range(10):                                                 # stream 2 s of setpoints (local NED)
        t = client.recv("GLOBAL_POSITION_INT").time_boot_ms
        client.mav.set_position_target_local_ned_send(t, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask,
                                                      0, 0, 0, 0.0, 3.0, 0.0, 0, 0, 0, 0, 0)
    assert client.command(set_mode, 1, 6, 0).result == mavlink.MAV_RESULT_ACCEPTED
    client.wait_mode(PX4_OFFBOARD)
    text = client.recv("STATUSTEXT", 10.0, lambda m: "Offboard lost" in m.text)    # stopped streaming
    assert "Hold" in text.text
    client.wait_mode(PX4_LOITER)
    assert server.guidance.mode == "AUTO.LOITER"


async def _fly_with_mavsdk(port: int, server: SitlServer) -> dict:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityNedYaw
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    out: dict = {}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await sdk.first_autopilot(timeout_s=10)
        assert system is not None, "MAVSDK saw no autopilot"
        out["autopilot"] = (await system.autopilot_type()).name
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            position = await telemetry.position()
            heading = await telemetry.heading()
            if math.isfinite(position.latitude_deg) and math.isfinite(heading.heading_deg):
                break
            await asyncio.sleep(0.1)
        out["lat"], out["lon"], out["heading"] = position.latitude_deg, position.longitude_deg, heading.heading_deg
        while server.time_s < 1.5:                                      # past INITIALISING
            await asyncio.sleep(0.05)
        await action.arm()
        await offboard.set_velocity_ned(VelocityNedYaw(3.0, 3.0, 0.0, 45.0))   # north-east, 4.24 m/s
        await offboard.start()
        started = server.time_s
        while server.time_s < started + 25.0:                           # 7.5 s to turn 45 deg, 8.5 s to speed up
            await asyncio.sleep(0.1)
        velocity = await telemetry.velocity_ned()
        out["vn"], out["ve"] = velocity.north_m_s, velocity.east_m_s
        out["mode"] = (await telemetry.flight_mode()).name
        out["speed"], out["course_deg"] = server.state.speed_mps, math.degrees(server.state.course_rad)
        await offboard.stop()
    return out


@pytest.mark.parametrize("autopilot", ["ardupilot", pytest.param("px4", marks=pytest.mark.slow)])
def test_mavsdk_connects_reads_telemetry_and_flies_offboard(tmp_path, autopilot):
    pytest.importorskip("mavsdk")
    port = free_port()
    server = SitlServer(ServerConfig(scenario=str(gps_scenario(tmp_path)), outs=(f"udp:127.0.0.1:{port}",),
                                     speedup=8.0, autopilot=autopilot, quiet=True, log_dir=str(tmp_path / "log"),
                                     duration_s=600.0))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        result = asyncio.run(asyncio.wait_for(_fly_with_mavsdk(port, server), 60))
    finally:
        server.request_stop()
        thread.join(10)
    assert ("ARDUPILOT" if autopilot == "ardupilot" else "PX4") in result["autopilot"].upper()
    assert result["lat"] == pytest.approx(33.0, abs=1e-3) and result["lon"] == pytest.approx(152.0, abs=1e-3)
    assert 0.0 <= result["heading"] < 360.0
    # MAVSDK's offboard start put the vehicle in GUIDED (ArduPilot) / OFFBOARD (PX4) and its setpoints flew it
    assert server.guidance.counters.get("setpoints_velocity", 0) > 20
    assert result["speed"] == pytest.approx(math.hypot(3.0, 3.0), abs=0.01)           # the truth
    assert result["course_deg"] == pytest.approx(45.0, abs=0.1)
    assert result["vn"] == pytest.approx(3.0, abs=0.3) and result["ve"] == pytest.approx(3.0, abs=0.3)
    assert "OFFBOARD" in result["mode"].upper()
    assert server.state.distance_m > 40.0

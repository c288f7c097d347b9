"""The PX4 lockstep bridge's frames (``sitl.physics.px4_hil``), against a stand-in for PX4's
``simulator_mavlink`` on a real TCP socket: no firmware needed."""
from __future__ import annotations

import math
import socket

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.nav.ins_error import EARTH_RATE_RADPS
from sitl.clock import LockstepGate
from sitl.physics.px4_hil import (ACCEL_LSB, ARMED_FLAG, FIELDS_IMU_MAG_BARO, GYRO_LSB, HIL_RATE_HZ, HilSensors, HilWorld,
                                   Px4HilBridge, simulator_port)
from sitl.sensors import GRAVITY_MPS2, WaveMotion
from sitl.world.vehicle import VehicleState

FIELD_NT = (25_000.0, -3_000.0, 35_000.0)
CALM = WaveMotion(0.0, 8.0, 0.0, 6.3, 0.0)
QUIET = HilSensors(accel_mps2=0.0, gyro_radps=0.0, mag_nt=0.0, baro_hpa=0.0, gps_m=0.0)


def _world(course_rad: float = 0.0) -> HilWorld:
    return HilWorld(VehicleState(33.0, 152.0, course_rad), lambda lat, lon, t: FIELD_NT, waves=CALM, sensors=QUIET)


def _decode(bridge: Px4HilBridge, message):
    return mavlink2.MAVLink(None).decode(bytearray(message.pack(bridge.mav)))


def _count(value: float, lsb: float) -> int:
    """simulator_mavlink's int16 FIFO count: C's conversion truncates toward zero."""
    return int(np.float32(value) / np.float32(lsb))


def _fly_against_a_standin(bridge: Px4HilBridge, instance: int, frames: int, controls: list[float]) -> list[int]:
    """A stand-in for simulator_mavlink over TCP: it answers every HIL_SENSOR with ``controls``,
    stamped with the frame's time, until ``frames`` frames; their times (the bridge is stopped)."""
    bridge.start(accept_timeout_s=10.0)
    px4 = socket.create_connection(("127.0.0.1", simulator_port(instance)), timeout=10.0)
    parser, mav = mavlink2.MAVLink(None), mavlink2.MAVLink(None, srcSystem=instance + 1, srcComponent=1)
    times = []
    try:
        while len(times) < frames:
            for msg in parser.parse_buffer(px4.recv(65536)) or ():
                if msg.get_type() == "HIL_SENSOR":
                    times.append(msg.time_usec)
                    px4.sendall(mav.hil_actuator_controls_encode(msg.time_usec, controls, ARMED_FLAG | 1, 1)
                                .pack(mav))
    finally:
        px4.close()
        bridge.stop()
    return times[:frames]


def test_a_frame_carries_the_world_in_the_body_frame():
    """At rest, level, heading east: gravity on -z, the field's north on the body's -y, in gauss; the
    gyro senses the Earth's rotation (north component on the body's -y, the vertical on -z), and
    PX4's truncation of accel and gyro to FIFO counts gives the nearest count."""
    world = _world(math.pi / 2)
    bridge = Px4HilBridge(7, world, 0.0)
    frame = world.step(0.02, 0.02, 0.0, 0.0)
    msg = _decode(bridge, bridge._sensor_message(frame))
    assert msg.fields_updated == FIELDS_IMU_MAG_BARO and msg.id == 0
    assert [_count(a, ACCEL_LSB) for a in (msg.xacc, msg.yacc, msg.zacc)] == [0, 0, round(-GRAVITY_MPS2 / ACCEL_LSB)]
    lat = math.radians(33.0)
    earth = (0.0, -EARTH_RATE_RADPS * math.cos(lat), -EARTH_RATE_RADPS * math.sin(lat))
    sensed = [g - math.copysign(0.5 * GYRO_LSB, g) for g in (msg.xgyro, msg.ygyro, msg.zgyro)]
    assert np.allclose(sensed, earth, atol=1e-8)
    assert np.allclose((msg.xmag, msg.ymag, msg.zmag), (-0.03, -0.25, 0.35), atol=1e-6)
    assert msg.abs_pressure == np.float32(1013.25)


def test_gps_has_a_fix_until_denied_then_reports_none():
    world = _world()
    bridge = Px4HilBridge(7, world, 1_700_000_000.0)
    frame = world.step(0.02, 0.02, 0.0, 0.0)
    fixed = _decode(bridge, bridge._gps_message(frame))
    assert (fixed.fix_type, fixed.satellites_visible) == (3, 12)
    assert abs(fixed.lat * 1e-7 - frame.lat_deg) < 1e-6
    assert fixed.time_usec == 1_700_000_000_000_000 + bridge.t_us     # UTC: PX4's date comes from it
    bridge.deny_gps()
    lost = _decode(bridge, bridge._gps_message(frame))
    assert (lost.fix_type, lost.satellites_visible, lost.lat, lost.lon) == (0, 0, 0, 0)


def test_lockstep_each_frame_waits_for_the_answer_and_outputs_move_the_boat():
    """A stand-in for simulator_mavlink over TCP: it answers every HIL_SENSOR with full throttle,
    stamped with the frame's time. The frames advance by exactly 1/HIL_RATE_HZ, one per answer, and
    the boat speeds up under PX4's throttle."""
    world = _world()
    bridge = Px4HilBridge(8, world, 0.0).listen()
    times = _fly_against_a_standin(bridge, 8, 100, [0.0, 1.0] + [0.0] * 14)
    assert np.all(np.diff(times) == round(1e6 / HIL_RATE_HZ))
    assert bridge.actuator_timeouts == 0
    assert bridge.throttle == 1.0 and world.state.speed_mps > 1.0


def test_once_the_companion_has_ended_the_world_no_longer_waits_for_it():
    """After the mission (the companion gone) PX4's clock must run on while the boat comes to rest:
    a gate that heard the companion once, and would hold each boundary for a minute, no longer holds
    a frame once the companion is released. Without the release this stand-in's 10 s socket timeout
    ends the test at the first boundary the companion never answered."""
    gate = LockstepGate(0.4, timeout_s=60.0)
    gate.observe(0, 0)                                   # heard once, then silent for good
    bridge = Px4HilBridge(9, _world(), 0.0, gate=gate).listen()
    bridge.release_companion()
    times = _fly_against_a_standin(bridge, 9, 200, [0.0] * 16)      # 4 s of PX4's time: ten boundaries
    assert np.all(np.diff(times) == round(1e6 / HIL_RATE_HZ))
    assert gate.timeouts == 0

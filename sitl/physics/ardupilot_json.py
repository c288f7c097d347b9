"""Our world as ArduPilot SITL's physics (``--model JSON``), in lockstep with the firmware and the companion.

ArduPilot's JSON backend (``libraries/SITL/SIM_JSON.cpp``) sends one binary servo packet per
physics frame to UDP port ``9002 + 10 I`` (``-I I``) and blocks until the answer arrives:

* out, 40 bytes little-endian: ``uint16 magic = 18458, uint16 frame_rate, uint32 frame_count,
  uint16 pwm[16]`` (rover: SERVO1 steering, SERVO3 throttle, 1000-2000 us around 1500);
* back, one line of JSON between newlines: ``timestamp`` (s, absolute), ``imu.gyro`` (rad/s, body
  FRD), ``imu.accel_body`` (specific force, m/s^2, body FRD), ``position`` (m, NED from home),
  ``velocity`` (m/s, NED), ``attitude`` (roll, pitch, yaw in rad).

ArduPilot's clock advances only by our timestamps: it runs exactly as fast as we answer. Its
Rover loop cannot run below 50 Hz (``AP_Scheduler`` clamps ``SCHED_LOOP_RATE`` to >= 50) and the
JSON readme asks for a physics rate at or above the loop rate, so a frame is 20 ms and 29
simulated hours are 5.2 million frames (``docs/notes/2026-12-06-ardupilot-json-lockstep.md``).

What the interface cannot carry (the evidence is ``SIM_JSON.h``'s key table): a magnetometer. ArduPilot
computes its compass from our position and attitude with its own field tables
(``update_mag_field_bf()``: "the model does not provide mag field"), and its GPS from our position
(``SIM_GPS1_ENABLE 0`` denies it as before). Nor, in the shared binary, a battery current, so SITL's motor
interference (``SIM_MAG_MOT`` x the backend's current) never acts: with ``--motor-field`` the world puts
the motor's field on the compass itself (:mod:`sitl.physics.motor_field`, over the relay's SERIAL1 link, or
SERIAL2 without a relay).

The loop is pipelined: the answer to frame ``n`` (the state at ``t_n + dt``) is ready when the
packet arrives and leaves at once; the world then steps with that packet's outputs while the
firmware runs its next loop (on the second core), so the outputs act one frame (20 ms) later, as
an ESC's and a rudder servo's latency would.

The companion's link passes through :class:`~sitl.physics.relay.CompanionRelay` (ArduPilot's
SERIAL1 <-> the companion): each of the companion's messages (stamped, as ``companion --lockstep``
stamps them, with the firmware time it has seen) reaches ArduPilot a fixed latency of firmware time
after its stamp, and before each frame the world makes sure every message due by then is known,
waiting for the companion only when it has fallen that far behind. The firmware's clock advances
with our frames, ours waits for the companion: a run does not depend on how fast the machine is.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import struct
import sys
import time
from dataclasses import dataclass, field

from sitl.physics.motor_field import MotorField, MotorFieldConfig
from sitl.sensors import WaveMotion
from sitl.world.actuated import BoatDynamics, PhysicsFrame, frame_of, step_boat
from sitl.world.vehicle import NO_MOTION_ERRORS, MotionErrors, VehicleState

__all__ = ["JsonPhysicsConfig", "JsonPhysics", "json_port", "ned_from_home", "outputs_of", "encode_frame",
           "SERVO_PACKET"]

SERVO_MAGIC = 18458
SERVO_PACKET = struct.Struct("<HHI16H")
_RUDDER_THROTTLE = struct.Struct("<8xH2xH")     # pwm[0] (SERVO1, steering) and pwm[2] (SERVO3, throttle)
# ArduPilot's Location::offset: 1e-7 degree of latitude is LOCATION_SCALING_FACTOR metres
LOCATION_SCALING_M_PER_DEG = 0.011131884502145034 * 1e7
FRAME_TEMPLATE = ('\n{"timestamp":%.4f,"imu":{"gyro":[%.7f,%.7f,%.7f],"accel_body":[%.6f,%.6f,%.6f]},'
                  '"position":[%.4f,%.4f,0],"attitude":[%.7f,%.7f,%.7f],"velocity":[%.5f,%.5f,0]}\n')


def json_port(instance: int) -> int:
    """The UDP port ArduPilot SITL ``-I instance`` sends its servo packets to.

    >>> json_port(0), json_port(3)
    (9002, 9032)
    """
    return 9002 + 10 * instance


def ned_from_home(lat_deg: float, lon_deg: float, home: tuple[float, float]) -> tuple[float, float]:
    """(north, east) in metres that ArduPilot's ``Location::offset`` from ``home`` turns back into
    (lat_deg, lon_deg): its spherical scaling, with the longitude scaled at the mid latitude, so a
    1000 km route arrives where our world is (not a flat-earth approximation of it).

    >>> [round(v, 1) for v in ned_from_home(33.01, 152.0, (33.0, 152.0))]
    [1113.2, 0.0]
    """
    d_lat = lat_deg - home[0]
    d_lon = (lon_deg - home[1] + 180.0) % 360.0 - 180.0
    scale = max(math.cos(math.radians(home[0] + 0.5 * d_lat)), 0.01)
    return d_lat * LOCATION_SCALING_M_PER_DEG, d_lon * LOCATION_SCALING_M_PER_DEG * scale


def outputs_of(packet: bytes) -> tuple[float, float]:
    """(throttle, steering), normalised to -1..1, from a servo packet's SERVO3 and SERVO1 pulses (us);
    a channel at 0 (not yet output) is neutral.

    >>> outputs_of(SERVO_PACKET.pack(SERVO_MAGIC, 50, 7, 2000, 0, 1750, *(0,) * 13))
    (0.5, 1.0)
    """
    steer, throttle = _RUDDER_THROTTLE.unpack_from(packet)
    return ((throttle - 1500) / 500.0 if throttle else 0.0), ((steer - 1500) / 500.0 if steer else 0.0)


def encode_frame(frame: PhysicsFrame, home: tuple[float, float]) -> bytes:
    """One JSON answer (between newlines, as SIM_JSON splits them)."""
    north, east = ned_from_home(frame.lat_deg, frame.lon_deg, home)
    g, a, v = frame.gyro_frd_radps, frame.accel_frd_mps2, frame.vel_ned_mps
    return (FRAME_TEMPLATE % (frame.time_s, g[0], g[1], g[2], a[0], a[1], a[2], north, east, frame.roll_rad,
                              frame.pitch_rad, frame.yaw_rad, v[0], v[1])).encode("ascii")


class _Stopped(Exception):
    """SIGTERM or SIGINT: the world's process ends, writing its statistics."""


@dataclass
class JsonPhysicsConfig:
    """One run of the world behind ArduPilot: where, the boat, the water, the lockstep."""

    instance: int
    home: tuple[float, float]
    heading_deg: float = 0.0
    dt_s: float = 0.02                  # 50 Hz: Rover's lowest loop rate
    dynamics: BoatDynamics = field(default_factory=BoatDynamics)
    motion: MotionErrors = NO_MOTION_ERRORS
    waves: WaveMotion = field(default_factory=WaveMotion)
    gate_timeout_s: float = 120.0       # wall seconds without an answer before going on (counted): a hang guard
    #                                     (a loaded machine once kept the companion 30 s from its answer)
    relay: bool = True
    motor_field: MotorFieldConfig | None = None   # the motor's field on the compass (None: the binary's, none)
    idle_timeout_s: float = 60.0        # wall seconds without a servo packet: the firmware has gone

    def __post_init__(self) -> None:
        if not (0.0 < self.dt_s <= 0.02 + 1e-12):
            raise ValueError(f"dt_s {self.dt_s}: ArduPilot Rover needs a physics rate >= its 50 Hz loop")


class JsonPhysics:
    """The world's loop: answers ArduPilot's frames, steps the boat, relays and gates the companion."""

    def __init__(self, config: JsonPhysicsConfig, relay=None) -> None:
        self.config = config
        self.relay = relay
        self.motor = (MotorField(config.instance, config.motor_field, send=relay.to_fc if relay is not None else None)
                      if config.motor_field is not None else None)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", json_port(config.instance)))
        # the idle timeout in the kernel (SO_RCVTIMEO) on a blocking socket: one system call a frame
        # (Python's settimeout polls before each recv: 3 us more CPU a frame and twice the wall time, measured)
        seconds = int(config.idle_timeout_s)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO,
                             struct.pack("ll", seconds, int((config.idle_timeout_s - seconds) * 1e6)))
        self.state = VehicleState(config.home[0], config.home[1], math.radians(config.heading_deg) % (2 * math.pi),
                                  0.0, 0.0, *config.motion.current_en_mps)
        self.time_s = 0.0
        self.frames = 0
        self.stop = False
        self.wall_s = 0.0
        self.cpu_s = 0.0

    def run(self) -> dict:
        """Until ArduPilot goes quiet for ``idle_timeout_s`` or :attr:`stop`; returns the statistics."""
        c = self.config
        dt, home, dyn, motion, waves = c.dt_s, c.home, c.dynamics, c.motion, c.waves
        dt_us = int(round(dt * 1e6))
        sock = self.sock
        relay_frame = self.relay.frame if self.relay is not None else None
        relay_answered = self.relay.answered if self.relay is not None else None
        motor_update = self.motor.update if self.motor is not None else None
        state = self.state
        reply = encode_frame(frame_of(dt, state, 0.0, 0.0, waves), home)   # the first answer: at rest
        n = 0           # frames answered and stepped: the time is n * dt (one counter, so a signal
        wall0, cpu0 = time.perf_counter(), time.process_time()   # cannot leave frames and time apart)
        try:
            data, addr = sock.recvfrom(256)
            sock.connect(addr)              # ArduPilot's one sender: recv and send without addresses
            recv, send = sock.recv, sock.send
            while not self.stop:
                if len(data) >= SERVO_PACKET.size and data[0] | data[1] << 8 == SERVO_MAGIC:
                    if relay_frame is not None:
                        relay_frame((n + 1) * dt_us)    # what ArduPilot's loop at t + dt is to read
                    send(reply)
                    if relay_answered is not None:
                        relay_answered((n + 1) * dt_us)
                    throttle, steering = outputs_of(data)
                    if motor_update is not None:
                        motor_update((n + 1) * dt_us, throttle)
                    state, yaw_rate, accel = step_boat(state, dt, throttle, steering, dyn, motion)
                    n += 1
                    reply = encode_frame(frame_of((n + 1) * dt, state, yaw_rate, accel, waves), home)
                data = recv(256)
        except (BlockingIOError, socket.timeout):
            pass                            # idle_timeout_s without a packet: ArduPilot has gone
        finally:
            self.state, self.time_s, self.frames = state, n * dt, n
            self.wall_s, self.cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
        return self.stats()

    def stats(self) -> dict:
        out = {"frames": self.frames, "sim_s": round(self.time_s, 3), "wall_s": round(self.wall_s, 3),
               "cpu_s": round(self.cpu_s, 3), "lat_deg": self.state.lat_deg, "lon_deg": self.state.lon_deg,
               "us_per_frame_wall": round(self.wall_s / max(self.frames, 1) * 1e6, 1),
               "us_per_frame_cpu": round(self.cpu_s / max(self.frames, 1) * 1e6, 1)}
        if self.relay is not None:
            out.update(self.relay.stats())
        if self.motor is not None:
            out.update(self.motor.stats())
        return out


def main(argv: list[str] | None = None) -> int:
    """``python -m sitl.physics.ardupilot_json --instance I --home LAT,LON ...``: the world's process."""
    from sitl.physics.relay import LATENCY_S, CompanionRelay

    p = argparse.ArgumentParser(prog="python -m sitl.physics.ardupilot_json", description=__doc__.split("\n")[0])
    p.add_argument("--instance", type=int, required=True)
    p.add_argument("--home", required=True, help="LAT,LON in degrees")
    p.add_argument("--heading-deg", type=float, default=0.0)
    p.add_argument("--current-en", default="0,0", help="the water's current east,north in m/s")
    p.add_argument("--relay-latency", type=float, default=LATENCY_S,
                   help="firmware seconds from a companion message's stamp to ArduPilot (default %(default)s)")
    p.add_argument("--no-relay", action="store_true", help="no companion link (a physics-only measurement)")
    p.add_argument("--hold-from-s", type=float, default=90.0,
                   help="firmware seconds after which the world waits for the companion to appear: past the "
                        "rig's preparation (default %(default)s)")
    p.add_argument("--motor-field", default=None, metavar="MOT;OFS;DIA;ODI",
                   help="put SIM_MAG_MOT's field on the compass (sitl.physics.motor_field): SIM_MAG_MOT and "
                        "SIM_MAG1_OFS, _DIA, _ODI as ArduPilot has them, each x,y,z")
    p.add_argument("--stats", default=None, help="write the run's statistics here (JSON) at the end")
    args = p.parse_args(argv)
    lat, lon = (float(v) for v in args.home.split(","))
    east, north = (float(v) for v in args.current_en.split(","))
    config = JsonPhysicsConfig(args.instance, (lat, lon), args.heading_deg, motion=MotionErrors((east, north)),
                               motor_field=MotorFieldConfig.parse(args.motor_field) if args.motor_field else None)
    relay = None if args.no_relay else CompanionRelay(args.instance, config.gate_timeout_s, args.hold_from_s,
                                                      latency_s=args.relay_latency)
    physics = JsonPhysics(config, relay)

    def _stop(signum, frame) -> None:  # noqa: ARG001
        # a blocking recv is retried after a signal (PEP 475): end it by raising
        raise _Stopped(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        stats = physics.run()
    except _Stopped:
        stats = physics.stats()
    if relay is not None:
        relay.close()
    if physics.motor is not None:
        physics.motor.close()
    if args.stats:
        with open(args.stats, "w") as handle:
            json.dump(stats, handle, indent=1)
    print(json.dumps(stats), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MAVLINK20", "1")
    sys.exit(main())

"""Our world as PX4's physics in lockstep, through PX4's MAVLink simulator interface (``simulator_mavlink``).

PX4 started with ``PX4_SIMULATOR=mavlink`` (:class:`fcmpc.firmware.px4.Px4Sitl`, ``simulator="mavlink"``)
connects as a TCP client to port 4560+N. Its clock is set by every HIL_SENSOR's ``time_usec``
(``px4_clock_settime``; the start-up script itself waits for the first one), and once armed it
answers a frame with HIL_ACTUATOR_CONTROLS (after EKF2 and the other lockstep components have
caught up), so PX4's time advances only with our frames:

* each frame (:data:`HIL_RATE_HZ`, the lowest IMU rate PX4 accepts: VehicleIMU constrains
  ``IMU_INTEG_RATE`` to >= 50 Hz; at 40 Hz EKF2 reported "missing data" and PX4 left frames
  unanswered, at 25 Hz with ``EKF2_PREDICT_US`` 40000 it flew a 3 km leg 106-1,122 m off where 50 Hz
  ends 67-68 m off: docs/notes/2026-12-06-px4-hil-lockstep.md, section 9) moves the boat with PX4's last outputs
  (:func:`sitl.world.actuated.step_boat`: ``controls[0]`` steering, ``controls[1]`` throttle, as
  ``PWM_MAIN_FUNC1/2`` of the Ackermann airframe map them) and sends HIL_SENSOR: the IMU's specific
  force and body rates with noise, the magnetometer from the world's true field in the body frame
  through the run's compass errors, and the pressure at sea level;
* HIL_GPS at 10 Hz while the receiver has a fix; after :meth:`Px4HilBridge.deny_gps` it keeps
  reporting with ``fix_type`` 0 and no satellites, as a jammed receiver does;
* HIL_STATE_QUATERNION (the truth) at 1 Hz: PX4 publishes it as its ground-truth topics, which only
  its HIL_STATE_QUATERNION stream reads (the monitor on the GCS link), never its estimator.

While PX4 is disarmed it sends no outputs (``simulator_mavlink`` sends when ``actuator_outputs_sim``
updates), so until the first HIL_ACTUATOR_CONTROLS each frame waits at most :data:`PREARM_WAIT_S`
of wall time for one: start-up is paced, the mission is in lockstep.

The companion's onboard link passes through the bridge (PX4 sends to 14540+N, where the bridge
listens; the companion listens on :meth:`Px4HilBridge.companion_port`), so at every boundary of
``lockstep_period_s`` the world waits until the companion has answered PX4's time
(:class:`sitl.clock.LockstepGate`, the stand-in's protocol: the companion runs with ``--lockstep``);
until the companion is first heard, PX4's start-up is paced as above.
"""
from __future__ import annotations

import math
import select
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.frames import ned_to_body
from companion.nav.ins_error import EARTH_RATE_RADPS
from sitl.clock import LockstepGate
from sitl.physics.mavlink_frames import actuator_controls, frames, time_boot_ms
from sitl.sensors import Normals, WaveMotion
from sitl.world.actuated import BoatDynamics, PhysicsFrame, frame_of, step_boat
from sitl.world.magerrors import MagErrors
from sitl.world.vehicle import NO_MOTION_ERRORS, MotionErrors, VehicleState

__all__ = ["ACCEL_LSB", "GYRO_LSB", "HIL_COMPANION_VALUES", "HIL_RATE_HZ", "HilSensors", "HilWorld", "Px4HilBridge",
           "hil_companion_values", "hil_params", "hil_world", "rounded_count", "simulator_port"]

HIL_RATE_HZ = 50.0
GPS_RATE_HZ = 10.0
TRUTH_RATE_HZ = 1.0
FIELD_REFRESH_S = 10.0      # the true field is re-evaluated every 10 s (30 m at 3 m/s; one evaluation of the
                            # main field and crust costs about 50 frames' worth of the rest)
PREARM_WAIT_S = 0.001       # wall time per frame while PX4 sends no outputs (disarmed)
ACTUATOR_TIMEOUT_S = 5.0    # wall time to wait for an armed PX4's outputs before going on alone: a loaded
                            # machine stalls PX4 for seconds, and now and then a frame gets no output at all
                            # (1-2 per 30 simulated minutes, at 2 s and at 30 s alike); the frame then goes on
                            # with PX4's last outputs
SEA_LEVEL_HPA = 1013.25
NT_PER_GAUSS = 1.0e5
# HIL_SENSOR.fields_updated: accel (bits 0-2), gyro (3-5), mag (6-8), baro abs/alt/temperature (9, 11, 12)
FIELDS_IMU_MAG_BARO = 0b1_1011_1111_1111
ARMED_FLAG = 128


# simulator_mavlink stores HIL_SENSOR's accel and gyro (id 0) as int16 FIFO counts of these sizes
# (SimulatorMavlink::update_sensors: ACCEL_FIFO_SCALE = g / 2048, GYRO_FIFO_SCALE = 2000 deg/s / 32768),
# and C's float-to-int conversion truncates toward zero: half a count (0.0024 m/s^2, 0.53 mrad/s)
# towards zero on average, a gyro bias in every steady turn
ACCEL_LSB = 9.80665 / 2048.0
GYRO_LSB = math.radians(2000.0 / 32768.0)


def rounded_count(value: float, lsb: float) -> float:
    """``value`` moved half a count away from zero, so that PX4's truncation to a count rounds it
    to the nearest one, as a sensor's converter does.

    >>> int(rounded_count(0.9 * ACCEL_LSB, ACCEL_LSB) / ACCEL_LSB), int(rounded_count(-1.6 * GYRO_LSB, GYRO_LSB) / GYRO_LSB)
    (1, -2)
    """
    return value + math.copysign(0.5 * lsb, value)


def simulator_port(instance: int) -> int:
    """PX4's simulator TCP port (``px4-rc.mavlinksim``: 4560 + instance).

    >>> simulator_port(3)
    4563
    """
    return 4560 + instance


def hil_params(dynamics: BoatDynamics) -> dict[str, float]:
    """PX4 parameters that describe our boat to its Ackermann rover controller and our single sensors.

    RO_MAX_THR_SPEED, RO_SPEED_LIM: the speed at full throttle (PX4's speed feed-forward, and no lower
    limit than the boat's; the airframe's 3 m/s is SIH's rover's); RA_WHEEL_BASE: the
    wheel base whose full steering angle (RA_MAX_STR_ANG, 30 deg) turns as our rudder does
    (yaw rate = speed * tan(angle) / base); EKF2_MULTI_IMU 1: one IMU is simulated (the script's 3
    ran two idle filters, a fifth of PX4's CPU).

    >>> p = hil_params(BoatDynamics())
    >>> p["RO_MAX_THR_SPEED"], round(p["RA_WHEEL_BASE"], 2)
    (10.0, 5.51)
    """
    max_steer_rad = math.radians(30.0)
    return {"RO_MAX_THR_SPEED": dynamics.max_speed_mps, "RO_SPEED_LIM": dynamics.max_speed_mps,
            "RA_MAX_STR_ANG": max_steer_rad,
            "RA_WHEEL_BASE": math.tan(max_steer_rad) / dynamics.yaw_rate_per_mps, "EKF2_MULTI_IMU": 1,
            "IMU_INTEG_RATE": int(HIL_RATE_HZ), "IMU_GYRO_RATEMAX": int(HIL_RATE_HZ)}


# The companion's feed against PX4 on our world (issue 49; docs/notes/2026-12-06-px4-hil-lockstep.md):
# COMP_FEED_ACC_M 1: the feed's short-term accuracy (a smooth dead-reckoned track), where the 5 m
# measured on ArduPilot left EKF2's tilt unobservable without GPS (its tilt standard deviation about
# east grew to 46 deg in 10 minutes, the tilt error to 6-13 deg and the vertical accelerometer bias to
# its 0.4 m/s^2 limit: "High Accelerometer Bias", failsafe); COMP_FEED_ACCEL: the fed track turns as
# PX4's rover controller turned our boat, measured at two speeds (speed x turn rate: 3 m/s at 9.5 deg/s,
# 8 m/s at 25 deg/s), linear between them; COMP_MAG_HZ 10 (the registry's): our magnetometer has a real
# sensor's 100 nT of noise, not SIH's 2000-3000 nT that the SIH rig's 50 Hz averages away, and every
# SCALED_IMU is a datagram through the bridge and a parse in the companion (section 9 of the note)
HIL_COMPANION_VALUES = {"COMP_FEED_ACCEL": 0.5, "COMP_FEED_ACC_M": 1.0, "COMP_MAG_HZ": 10.0}
TURN_ACCEL_MEASURED = ((3.0, 0.5), (8.0, 3.0))     # (speed m/s, lateral acceleration m/s^2)


def hil_companion_values(speed_mps: float) -> dict[str, float]:
    """The companion's feed parameters against PX4 on our world at a cruise speed (see above).

    >>> hil_companion_values(3.0)["COMP_FEED_ACCEL"], hil_companion_values(8.0)["COMP_FEED_ACCEL"]
    (0.5, 3.0)
    """
    (v0, a0), (v1, a1) = TURN_ACCEL_MEASURED
    frac = min(max((speed_mps - v0) / (v1 - v0), 0.0), 1.0)
    return {**HIL_COMPANION_VALUES, "COMP_FEED_ACCEL": round(a0 + frac * (a1 - a0), 3)}


@dataclass(frozen=True)
class HilSensors:
    """1-sigma white noise of the firmware's sensors (SI): a MEMS IMU, a magnetometer, a barometer."""

    accel_mps2: float = 0.02
    gyro_radps: float = 0.002
    mag_nt: float = 100.0
    baro_hpa: float = 0.01
    gps_m: float = 0.5                # a receiver's position error: first-order Gauss-Markov, 1-sigma ...
    gps_tau_s: float = 60.0           # ... and correlation time (white noise failed PX4's drift check at rest)


@dataclass
class HilWorld:
    """The vehicle, its seaway and the true field: the physics a flight controller flies in.

    ``field_ned_nt(lat_deg, lon_deg, elapsed_s) -> (n, e, d)`` is the true field;
    ``mag_errors`` the firmware compass's residual calibration errors.
    """

    state: VehicleState
    field_ned_nt: object
    dynamics: BoatDynamics = field(default_factory=BoatDynamics)
    motion: MotionErrors = NO_MOTION_ERRORS
    waves: WaveMotion = field(default_factory=WaveMotion)
    mag_errors: MagErrors = field(default_factory=MagErrors.none)
    sensors: HilSensors = field(default_factory=HilSensors)
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def step(self, time_s: float, dt_s: float, throttle: float, steering: float) -> PhysicsFrame:
        self.state, yaw_rate, accel = step_boat(self.state, dt_s, throttle, steering, self.dynamics, self.motion)
        return frame_of(time_s, self.state, yaw_rate, accel, self.waves)


class Px4HilBridge:
    """The simulator end of PX4's ``simulator_mavlink`` and the relay of its onboard link; see the module.

    ``gate``: the companion's lockstep (None: the world does not wait for it). Run :meth:`listen`
    before PX4 starts, then :meth:`start` (a thread) and :meth:`stop`.
    """

    def __init__(self, instance: int, world: HilWorld, start_unix_s: float, gate: LockstepGate | None = None,
                 companion_port: int | None = None) -> None:
        self.instance = instance
        self.world = world
        self.start_unix_s = start_unix_s
        self.gate = gate
        self.companion_port = companion_port if companion_port is not None else 24540 + instance
        self.mav = mavlink2.MAVLink(None, srcSystem=instance + 1, srcComponent=51)
        self.mav.robust_parsing = True
        self.t_us = 0
        self.frames = 0
        self.gps_fix = True
        self.throttle = self.steering = 0.0
        self.armed = False
        self.last_output_us = -1
        self.actuator_timeouts = 0
        self.actuator_timeout_at_s: list[float] = []     # PX4's time of each (the first few are worth a look)
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._companion_gone = threading.Event()
        self._thread: threading.Thread | None = None
        self._field_ned = (0.0, 0.0, 0.0)
        self._gps_error_m = np.zeros(2)
        self._normal = Normals(world.rng)
        errors = world.mag_errors
        self._mag_matrix = (np.eye(3) + errors.soft_iron).tolist()    # (I + S) b + o (+ c dT, per refresh)
        self._mag_offset_nt = errors.hard_iron_nt.tolist()
        self._field_at_s = -math.inf
        self._server: socket.socket | None = None
        self._sim: socket.socket | None = None
        self._sim_buf = bytearray()
        self._px4_side: socket.socket | None = None
        self._companion_side: socket.socket | None = None
        self._companion_addr = ("127.0.0.1", self.companion_port)
        self._px4_onboard = ("127.0.0.1", 14580 + instance)

    # --- set-up -----------------------------------------------------------------------------------
    def listen(self) -> Px4HilBridge:
        """Bind PX4's simulator port and the onboard link's port (before PX4 starts)."""
        self._server = socket.create_server(("127.0.0.1", simulator_port(self.instance)), reuse_port=False)
        self._px4_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._px4_side.bind(("127.0.0.1", 14540 + self.instance))
        self._companion_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._companion_side.bind(("127.0.0.1", 0))
        return self

    @property
    def companion_url(self) -> str:
        return f"udpin:127.0.0.1:{self.companion_port}"

    def start(self, accept_timeout_s: float = 60.0) -> Px4HilBridge:
        self._accept_timeout_s = accept_timeout_s
        self._thread = threading.Thread(target=self._run, name="px4-hil", daemon=True)
        self._thread.start()
        return self

    def deny_gps(self) -> None:
        """The receiver loses its fix from the next GPS report on (a jammed receiver still reports)."""
        self.gps_fix = False

    def release_companion(self) -> None:
        """The companion has ended (its mission is over): the world no longer waits for it, so PX4's
        clock runs on while the boat comes to rest."""
        self._companion_gone.set()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for sock in (self._sim, self._server, self._px4_side, self._companion_side):
            if sock is not None:
                sock.close()

    @property
    def time_s(self) -> float:
        return self.t_us * 1e-6

    # --- the frame loop ---------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._server.settimeout(self._accept_timeout_s)
            self._sim, _ = self._server.accept()
            self._sim.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._loop()
        except BaseException as err:   # noqa: BLE001 - reported to the rig, which stops the flight
            if not self._stop.is_set():
                self.error = err

    def _loop(self) -> None:
        dt_us = int(round(1e6 / HIL_RATE_HZ))
        gps_every = int(round(HIL_RATE_HZ / GPS_RATE_HZ))
        truth_every = int(round(HIL_RATE_HZ / TRUTH_RATE_HZ))
        boundary_us = self.gate.period_us if self.gate else None
        self.t_us = dt_us
        while not self._stop.is_set():
            frame = self.world.step(self.t_us * 1e-6, dt_us * 1e-6, self.throttle, self.steering)
            out = [self._sensor_message(frame)]
            if self.frames % gps_every == 0:
                out.append(self._gps_message(frame))
            if self.frames % truth_every == 0:
                out.append(self._truth_message(frame))
            self._sim.sendall(b"".join(m.pack(self.mav) for m in out))
            self.frames += 1
            self._await_outputs()
            if boundary_us is not None and self.t_us >= boundary_us:
                self._await_companion(boundary_us)
                boundary_us += self.gate.period_us
            self.t_us += dt_us

    def _await_outputs(self) -> None:
        """Relay the onboard link until PX4 has answered this frame (armed) or a short wall wait (disarmed)."""
        wait_s = ACTUATOR_TIMEOUT_S if self.armed else PREARM_WAIT_S
        deadline = time.perf_counter() + wait_s
        while self.last_output_us < self.t_us and not self._stop.is_set():
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                if self.armed:
                    self.actuator_timeouts += 1
                    self.actuator_timeout_at_s.append(round(self.time_s, 2))
                    self.armed = False       # disarmed, or stalled: paced until PX4 answers again
                return
            self._pump(remaining)

    def _await_companion(self, boundary_us: int) -> None:
        """Relay the onboard link until the companion has answered PX4's time ``boundary_us``.

        Until the companion is first heard the boundaries pass: PX4 starts (its start-up script
        sleeps in PX4's time) before the rig starts the companion."""
        gate = self.gate
        if not gate.peer_heard or self._companion_gone.is_set():
            return
        start = time.perf_counter()
        limit = gate.timeout_s
        timed_out = False
        while not gate.satisfied(boundary_us) and not self._stop.is_set() and not self._companion_gone.is_set():
            if time.perf_counter() - start > limit:
                timed_out = True
                break
            self._pump(0.05)
        gate.finish(time.perf_counter() - start, timed_out)

    def _pump(self, timeout_s: float) -> None:
        """Handle what arrives within ``timeout_s``: PX4's outputs, and the onboard link both ways."""
        ready, _, _ = select.select((self._sim, self._px4_side, self._companion_side), (), (), timeout_s)
        for sock in ready:
            if sock is self._sim:
                data = sock.recv(65536)
                if not data:
                    raise ConnectionError("PX4 closed the simulator connection")
                self._sim_buf += data
                for fields in actuator_controls(self._sim_buf):
                    self._outputs(fields)
            elif sock is self._px4_side:
                self._companion_side.sendto(sock.recv(65536), self._companion_addr)
            else:
                data = sock.recv(65536)
                self._px4_side.sendto(data, self._px4_onboard)
                if self.gate is not None:
                    for msgid, payload in frames(bytearray(data)):
                        self.gate.observe(time_boot_ms(msgid, payload), self.t_us)

    def _outputs(self, fields: tuple) -> None:
        """One HIL_ACTUATOR_CONTROLS's fields (:func:`actuator_controls`)."""
        self.armed = bool(fields[-1] & ARMED_FLAG)
        self.steering, self.throttle = float(fields[2]), float(fields[3])
        self.last_output_us = max(self.last_output_us, int(fields[0]))

    # --- messages ---------------------------------------------------------------------------------
    def _field_body_gauss(self, frame: PhysicsFrame) -> np.ndarray:
        world = self.world
        if frame.time_s - self._field_at_s >= FIELD_REFRESH_S:
            self._field_ned = tuple(float(v) for v in world.field_ned_nt(frame.lat_deg, frame.lon_deg, frame.time_s))
            self._field_at_s = frame.time_s
            errors = world.mag_errors
            drift = errors.temperature_change_k(frame.time_s) * errors.temp_coeff_nt_per_k
            self._mag_offset_nt = (errors.hard_iron_nt + drift).tolist()
        body = ned_to_body(self._field_ned, frame.roll_rad, frame.pitch_rad, frame.yaw_rad)
        sigma, normal = world.sensors.mag_nt, self._normal.three()
        return [(row[0] * body[0] + row[1] * body[1] + row[2] * body[2] + offset + sigma * n) / NT_PER_GAUSS
                for row, offset, n in zip(self._mag_matrix, self._mag_offset_nt, normal)]

    def _sensor_message(self, frame: PhysicsFrame):
        noise, normal = self.world.sensors, self._normal
        acc = [a + noise.accel_mps2 * n for a, n in zip(frame.accel_frd_mps2, normal.three())]
        # a gyro senses the Earth's rotation too, and EKF2 subtracts it (Ekf::predictState,
        # _earth_rate_NED): without it EKF2 sees a heading-dependent gyro bias of 0.06 mrad/s
        lat_rad = math.radians(frame.lat_deg)
        earth = ned_to_body((EARTH_RATE_RADPS * math.cos(lat_rad), 0.0, -EARTH_RATE_RADPS * math.sin(lat_rad)),
                            frame.roll_rad, frame.pitch_rad, frame.yaw_rad)
        gyro = [g + e + noise.gyro_radps * n for g, e, n in zip(frame.gyro_frd_radps, earth, normal.three())]
        acc, gyro = [rounded_count(a, ACCEL_LSB) for a in acc], [rounded_count(g, GYRO_LSB) for g in gyro]
        mag = self._field_body_gauss(frame)
        baro = SEA_LEVEL_HPA + noise.baro_hpa * normal()
        return self.mav.hil_sensor_encode(self.t_us, *acc, *gyro, *mag, baro, 0.0, 0.0, 20.0, FIELDS_IMU_MAG_BARO, 0)

    def _gps_message(self, frame: PhysicsFrame):
        vn, ve, vd = frame.vel_ned_mps
        # HIL_GPS's time_usec is the receiver's UTC (PX4's sensor_gps.time_utc_usec, its SYSTEM_TIME
        # and the companion's date for the field model); boot time here put the companion in 1970
        utc_us = int(round(self.start_unix_s * 1e6)) + self.t_us
        if not self.gps_fix:
            return self.mav.hil_gps_encode(utc_us, 0, 0, 0, 0, 65535, 65535, 65535, 0, 0, 0, 65535, 0)
        noise = self.world.sensors
        keep = math.exp(-1.0 / (GPS_RATE_HZ * noise.gps_tau_s))
        fresh = self.world.rng.normal(0.0, noise.gps_m, 2)
        self._gps_error_m = keep * self._gps_error_m + math.sqrt(1.0 - keep * keep) * fresh
        lat = frame.lat_deg + self._gps_error_m[0] / 111_320.0
        lon = frame.lon_deg + self._gps_error_m[1] / (111_320.0 * max(math.cos(math.radians(frame.lat_deg)), 0.01))
        speed = math.hypot(vn, ve)
        cog = int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0)) % 36000
        return self.mav.hil_gps_encode(utc_us, 3, int(round(lat * 1e7)), int(round(lon * 1e7)), 0, 80, 120,
                                       int(round(speed * 100.0)), int(round(vn * 100.0)), int(round(ve * 100.0)),
                                       int(round(vd * 100.0)), cog, 12)

    def _truth_message(self, frame: PhysicsFrame):
        cr, sr = math.cos(frame.roll_rad / 2), math.sin(frame.roll_rad / 2)
        cp, sp = math.cos(frame.pitch_rad / 2), math.sin(frame.pitch_rad / 2)
        cy, sy = math.cos(frame.yaw_rad / 2), math.sin(frame.yaw_rad / 2)
        q = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
             cr * cp * sy - sr * sp * cy)
        vn, ve, vd = frame.vel_ned_mps
        return self.mav.hil_state_quaternion_encode(
            self.t_us, q, *frame.gyro_frd_radps, int(round(frame.lat_deg * 1e7)), int(round(frame.lon_deg * 1e7)),
            int(round(frame.alt_m * 1000)), int(round(vn * 100)), int(round(ve * 100)), int(round(vd * 100)),
            int(round(math.hypot(vn, ve) * 100)), 0, 0, 0, 0)

    def stats(self) -> dict:
        out = {"hil_frames": self.frames, "hil_time_s": round(self.time_s, 3),
               "hil_actuator_timeouts": self.actuator_timeouts, "hil_actuator_timeout_at_s": self.actuator_timeout_at_s[:10]}
        if self.gate is not None:
            out.update(self.gate.stats())
        return out


def hil_world(scenario, seed: int = 0, dynamics: BoatDynamics | None = None) -> HilWorld:
    """The scenario's world for one run: its true field (:func:`sitl.world.build.build_truth_field`
    for ``seed``), the firmware compass's residuals drawn from its ``mag_errors`` sizes, the boat at
    the start heading north."""
    from sitl.world.build import build_truth_field

    truth = build_truth_field(scenario, seed=seed)
    rng = np.random.default_rng([seed, 49])

    def field_ned_nt(lat_deg: float, lon_deg: float, elapsed_s: float):
        return truth.field_ned_nt(lat_deg, lon_deg, 0.0, elapsed_s)

    return HilWorld(VehicleState(scenario.start_lat_deg, scenario.start_lon_deg), field_ned_nt,
                    dynamics or BoatDynamics(), mag_errors=MagErrors.draw(scenario.sensors.mag_errors, rng), rng=rng)

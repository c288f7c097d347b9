"""fcmpc-sitl: a MAVLink 2 flight-controller stand-in that flies a scenario faster than real time.

It wraps the world models of :mod:`sitl.world` (vehicle kinematics, INS error, true field
= WMM + storm) and the sensor/estimate models of :mod:`sitl.sensors` in the messages an
ArduPilot Rover (or, with ``--autopilot px4``, a PX4) boat sends, and obeys the commands
and setpoints a companion computer or a ground station sends back.

Quick start::

    fcmpc-sitl                                   # pacific, udp to 127.0.0.1:14550, 1x real time
    fcmpc-sitl --speedup 1000 --duration 3600    # an hour of mission in about 3 s
    fcmpc-sitl --master tcp:127.0.0.1:5760       # listen like ArduPilot SITL (MAVProxy --master tcp:...)
    fcmpc-sitl --lockstep --out udp:127.0.0.1:14550   # time advances only when the companion answers
    fcmpc-sitl --fault mag_off:600:30 --fault link_loss:0:inf:0.2

Identity: system 1, component 1, HEARTBEAT type MAV_TYPE_SURFACE_BOAT. Every time field of
every message carries *simulated* time: ``time_boot_ms``/``time_usec`` since boot,
SYSTEM_TIME.time_unix_usec = scenario ``start_utc`` + simulated time. See README
"Simulator" and :mod:`sitl.clock` for pacing and the lockstep protocol.
"""
from __future__ import annotations

import os

# Before numpy: small-matrix BLAS calls (the INS's expm) are ~100x slower with OpenBLAS
# threads on a 2-core machine, and the simulator is single-threaded by design.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MAVLINK20", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import selectors  # noqa: E402
import signal  # noqa: E402
import socket  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import deque  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from datetime import datetime  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion import wrap_2pi, wrap_pi  # noqa: E402
from companion.nav.geo import geodesic_distance_m, metres_per_degree  # noqa: E402
from companion.params import SPEC_BY_NAME  # noqa: E402
from sitl.clock import US_PER_S, LockstepGate, Pacer  # noqa: E402
from sitl.guidance import (  # noqa: E402
    DIALECTS, MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED,
    SEVERITY_INFO, SEVERITY_NOTICE, SEVERITY_WARNING, Guidance, SetpointError, interpret_position_target,
)
from sitl.mavframe import FrameEncoder  # noqa: E402
from sitl.links import MAX_DATAGRAM_BYTES, Link, open_link, parse_endpoint  # noqa: E402
from sitl.scenario import FAULT_KINDS, Fault, Scenario, ScenarioError, load_scenario  # noqa: E402
from sitl.sensors import GRAVITY_MPS2, NavSolution, SensorSuite, WaveMotion, make_error_models  # noqa: E402
from sitl.truthlog import TlogWriter, TruthLog  # noqa: E402
from sitl.world.build import build_truth_field  # noqa: E402
from sitl.world.magnetic import TruthField, decl_incl_from_ned  # noqa: E402
from sitl.world.vehicle import VehicleState, step_vehicle  # noqa: E402

__all__ = ["ServerConfig", "SitlServer", "DEFAULT_RATES_HZ", "parse_fault", "build_parser", "config_from_args",
           "main", "benchmark"]

DEFAULT_OUT = "udp:127.0.0.1:14550"
DEFAULT_SPEEDUP = 1.0
MAX_RATE_HZ = 1000.0
PHYSICS_STEP_US = 100_000          # the kinematics step at least every 0.1 s of simulated time
STATUSTEXT_MIN_INTERVAL_S = 5.0    # per kind of repeated warning

# Messages the simulator can stream, by name: (message id, default rate in Hz).
# ArduPilot-like defaults (SRn_* of a telemetry port); HEARTBEAT/SYSTEM_TIME/SYS_STATUS at 1 Hz.
DEFAULT_RATES_HZ = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "SYSTEM_TIME": 1.0,
    "RAW_IMU": 10.0,
    "SCALED_IMU": 10.0,
    "ATTITUDE": 10.0,
    "GLOBAL_POSITION_INT": 5.0,
    "GPS_RAW_INT": 5.0,
    "LOCAL_POSITION_NED": 5.0,
    "HIGHRES_IMU": 0.0,
    "VFR_HUD": 0.0,
    "HOME_POSITION": 0.0,
    "EXTENDED_SYS_STATE": 0.0,
}
STREAM_IDS = {
    "HEARTBEAT": 0, "SYS_STATUS": 1, "SYSTEM_TIME": 2, "GPS_RAW_INT": 24, "SCALED_IMU": 26, "RAW_IMU": 27,
    "ATTITUDE": 30, "LOCAL_POSITION_NED": 32, "GLOBAL_POSITION_INT": 33, "VFR_HUD": 74, "HIGHRES_IMU": 105,
    "HOME_POSITION": 242, "EXTENDED_SYS_STATE": 245,
}
STREAM_BY_ID = {v: k for k, v in STREAM_IDS.items()}
# REQUEST_DATA_STREAM groups (ArduPilot's assignment of messages to MAV_DATA_STREAM_*).
DATA_STREAM_GROUPS = {
    1: ("RAW_IMU", "SCALED_IMU"),                      # RAW_SENSORS
    2: ("SYS_STATUS", "GPS_RAW_INT"),                  # EXTENDED_STATUS
    3: (), 4: (),                                      # RC_CHANNELS, RAW_CONTROLLER
    6: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),  # POSITION
    10: ("ATTITUDE",),                                 # EXTRA1
    11: ("VFR_HUD",),                                  # EXTRA2
    12: ("SYSTEM_TIME",),                              # EXTRA3
}
DATA_STREAM_GROUPS[0] = tuple(name for group in DATA_STREAM_GROUPS.values() for name in group)

MAV_TYPE_SURFACE_BOAT = 11
MAV_STATE_BOOT, MAV_STATE_STANDBY, MAV_STATE_ACTIVE = 1, 3, 4
MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32 = 6, 9
SENSOR_GYRO, SENSOR_ACCEL, SENSOR_MAG, SENSOR_GPS, SENSOR_GEOFENCE, SENSOR_AHRS = 1, 2, 4, 32, 0x100000, 0x200000
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
INT16_MAX = 32767


def _int16(value: float) -> int:
    v = int(round(value))
    return INT16_MAX if v > INT16_MAX else (-INT16_MAX - 1 if v < -INT16_MAX - 1 else v)


def parse_fault(text: str) -> Fault:
    """``kind:at_s[:duration_s[:value]]`` -> Fault (duration ``inf`` or omitted = to the end).

    >>> parse_fault("link_loss:10:inf:0.25")
    Fault(kind='link_loss', at_s=10.0, duration_s=inf, value=0.25)
    """
    parts = text.split(":")
    if not 2 <= len(parts) <= 4 or parts[0] not in FAULT_KINDS:
        raise ValueError(f"fault {text!r}: expected kind:at_s[:duration_s[:value]], "
                         f"kind one of {', '.join(FAULT_KINDS)}")
    try:
        at = float(parts[1])
        duration = float(parts[2]) if len(parts) > 2 and parts[2] else math.inf
        value = float(parts[3]) if len(parts) > 3 and parts[3] else 0.0
    except ValueError:
        raise ValueError(f"fault {text!r}: at_s, duration_s and value must be numbers") from None
    if not (math.isfinite(at) and at >= 0.0 and duration > 0.0 and math.isfinite(value)):
        raise ValueError(f"fault {text!r}: need at_s >= 0, duration_s > 0, finite value")
    return Fault(parts[0], at, duration, value)


@dataclass
class ServerConfig:
    """Everything the simulator is started with (the CLI fills it; tests build it directly)."""

    scenario: str = "pacific"
    outs: tuple[str, ...] = ()          # udp:HOST:PORT senders (default DEFAULT_OUT when no endpoint given)
    masters: tuple[str, ...] = ()       # tcp:HOST:PORT / udpin:HOST:PORT listeners
    speedup: float | None = None        # sim s per wall s; None: 1 (or unlimited with lockstep); 0: unlimited
    lockstep: bool = False
    lockstep_period_s: float = 0.2
    lockstep_timeout_s: float = 2.0
    lockstep_start_timeout_s: float = 60.0
    lockstep_peer: tuple[int, int] | None = None
    lockstep_slack: int = 1              # periods the companion may lag (0: the two processes alternate)
    duration_s: float | None = None     # stop after this much simulated time
    max_sim_s: float = 30 * 3600.0
    seed: int = 0
    autopilot: str = "ardupilot"
    sysid: int = 1
    setpoint_timeout_s: float | None = None
    cruise_speed_mps: float | None = None
    init_s: float = 1.0
    cruise: tuple[float, float] | None = None   # (course_deg, speed_mps): armed in guided from init_s
    log_dir: str | None = None
    truth_log: bool = True
    log_rate_hz: float = 1.0
    tlog: str | None = None             # path, "" = <log_dir>/sitl.tlog, None = no tlog
    faults: tuple[str, ...] = ()
    rates: tuple[str, ...] = ()         # NAME:HZ overrides of DEFAULT_RATES_HZ
    field_step_s: float = 1.0
    ins_step_s: float = 5.0
    wave_roll_deg: float = 3.0
    wave_pitch_deg: float = 2.0
    data_dir: str | None = None
    expected_duration_s: float | None = None
    routing: bool = True
    batch: bool = True
    summary_json: str | None = None
    quiet: bool = False

    def validate(self) -> None:
        """Raise ValueError naming the first setting out of range."""
        checks = [
            ("speedup", self.speedup is None or self.speedup >= 0.0, ">= 0 (0 = unlimited)"),
            ("duration_s", self.duration_s is None or self.duration_s > 0.0, "> 0"),
            ("max_sim_s", self.max_sim_s > 0.0, "> 0"),
            ("lockstep_period_s", self.lockstep_period_s > 0.0, "> 0"),
            ("lockstep_timeout_s", self.lockstep_timeout_s > 0.0, "> 0"),
            ("lockstep_start_timeout_s", self.lockstep_start_timeout_s >= 0.0, ">= 0"),
            ("init_s", self.init_s >= 0.0, ">= 0"),
            ("log_rate_hz", self.log_rate_hz >= 0.0, ">= 0"),
            ("field_step_s", self.field_step_s > 0.0, "> 0"),
            ("ins_step_s", self.ins_step_s > 0.0, "> 0"),
            ("setpoint_timeout_s", self.setpoint_timeout_s is None or self.setpoint_timeout_s > 0.0, "> 0"),
            ("sysid", 1 <= self.sysid <= 255, "in 1..255"),
            ("autopilot", self.autopilot in DIALECTS, f"one of {', '.join(DIALECTS)}"),
        ]
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"{name} = {getattr(self, name)!r} must be {rule}")


class _Stream:
    __slots__ = ("name", "interval_us", "next_us", "send")

    def __init__(self, name: str, rate_hz: float, send) -> None:
        self.name = name
        self.send = send
        self.next_us = 0
        self.interval_us = 0
        self.set_rate(rate_hz, 0)

    def set_rate(self, rate_hz: float, now_us: int) -> None:
        if rate_hz <= 0.0:
            self.interval_us = 0
            self.next_us = 1 << 62
        else:
            self.interval_us = max(int(round(US_PER_S / min(rate_hz, MAX_RATE_HZ))), 1)
            self.next_us = now_us


class SitlServer:
    """The simulator: ``run()`` until the duration ends or ``request_stop()``; returns the summary."""

    def __init__(self, config: ServerConfig, scenario: Scenario | None = None, truth: TruthField | None = None) -> None:
        config.validate()
        self.config = config
        self.dialect = DIALECTS[config.autopilot]
        base = scenario if scenario is not None else load_scenario(config.scenario)
        extra_faults = tuple(parse_fault(text) for text in config.faults)
        self.scenario = replace(base, faults=tuple(base.faults) + extra_faults)
        if any(f.kind == "storm_onset" for f in self.scenario.faults) and not self.scenario.storm.enabled:
            raise ScenarioError("storm_onset fault needs a scenario with [storm] enabled = true")
        self.truth_full = truth if truth is not None else build_truth_field(
            self.scenario, config.data_dir, config.expected_duration_s, seed=config.seed)
        self.truth = self.truth_full
        self.sysid, self.compid = config.sysid, 1
        rng_sensors, rng_nav, rng_link, rng_gps, rng_att, rng_cal = (
            np.random.default_rng(s) for s in np.random.SeedSequence(config.seed).spawn(6))
        self._link_rng = rng_link
        sc = self.scenario
        self.state = VehicleState(sc.start_lat_deg, sc.start_lon_deg, 0.0, 0.0)
        self.wave = WaveMotion(roll_amp_deg=config.wave_roll_deg, pitch_amp_deg=config.wave_pitch_deg)
        errors = make_error_models(sc, rng_att, rng_cal)   # sitl.world's attitude/calibration errors
        self.sensors = SensorSuite(sc.sensors, rng_sensors, errors.attitude, errors.mag, errors.decl_table_deg)
        self.nav = NavSolution(sc.ins, rng_nav, aided_noise_m=0.2 * sc.sensors.gps_noise_m,
                               ins_step_s=config.ins_step_s)
        self._gps_rng = rng_gps
        cruise = config.cruise_speed_mps
        if cruise is None:
            cruise = float(SPEC_BY_NAME["NAV_SPEED_KMH"].default) / 3.6
        self.guidance = Guidance(self.dialect, sc.vehicle, cruise, config.setpoint_timeout_s)
        self.encoder = FrameEncoder(self.sysid, self.compid)
        self._decoder = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=self.compid)
        self.t_us = 0
        self.end_us = int(min(config.duration_s if config.duration_s is not None else math.inf,
                              config.max_sim_s) * US_PER_S)
        self.start_unix_us = int(round(sc.start_posix * US_PER_S))
        self._stop = threading.Event()
        self.ready_event = threading.Event()
        self.counters: dict[str, int] = {}
        self.tx_by_type: dict[str, int] = {}
        self.rx_by_type: dict[str, int] = {}
        self.peers: dict[tuple[int, int], int] = {}   # (sysid, compid) -> MAV_TYPE
        self._out: list[bytes] = []
        self._delayed: list[tuple[int, bytes]] = []
        self._stream_buffers: dict[object, bytearray] = {}
        self._last_say: dict[str, float] = {}
        self._cmd = (0.0, 0.0)
        self._accel_ned = (0.0, 0.0, 0.0)
        self._yaw_rate = 0.0
        self._fc_memo: tuple[int, tuple[float, float]] | None = None
        self._att_memo = None
        self._mag_ints = (0, 0, 0)
        self._imu_ints = (0, 0, -1000, 0, 0, 0)
        self._field = (0.0, 0.0, 0.0)
        self._dist = (0.0, 0.0, 0.0)
        self._field_us = -1
        self._mag_nan = False
        self._ext_estimate: tuple[float, float] | None = None
        self._last_system_time_us = -1
        self._last_log_us = -1
        # faults
        self._fault_times = sorted({f.at_s for f in sc.faults} | {f.at_s + f.duration_s for f in sc.faults
                                                                 if math.isfinite(f.duration_s)})
        self._active_faults: tuple[Fault, ...] = ()
        self._loss = self._dup = 0.0
        self._delay_us = 0
        self._heartbeat_off = self._gps_off = self._mag_off = self._mag_stuck = False
        self._mag_spike_nt = 0.0
        self._storm_scale_now = None if not any(f.kind == "storm_onset" for f in sc.faults) else 0.0
        self._apply_storm_scale()
        # streams and timers
        rates = dict(DEFAULT_RATES_HZ)
        for text in config.rates:
            name, _, hz = text.partition(":")
            if name.upper() not in rates:
                raise ValueError(f"--rate {text!r}: unknown message (streams: {', '.join(rates)})")
            rates[name.upper()] = float(hz)
        self.default_rates = dict(rates)
        senders = {"HEARTBEAT": self._send_heartbeat, "SYS_STATUS": self._send_sys_status,
                   "SYSTEM_TIME": self._send_system_time, "RAW_IMU": self._send_raw_imu,
                   "SCALED_IMU": self._send_scaled_imu, "ATTITUDE": self._send_attitude,
                   "GLOBAL_POSITION_INT": self._send_global_position_int, "GPS_RAW_INT": self._send_gps_raw_int,
                   "LOCAL_POSITION_NED": self._send_local_position_ned, "HIGHRES_IMU": self._send_highres_imu,
                   "VFR_HUD": self._send_vfr_hud, "HOME_POSITION": self._send_home_position,
                   "EXTENDED_SYS_STATE": self._send_extended_sys_state}
        self.streams = {name: _Stream(name, rates[name], senders[name]) for name in DEFAULT_RATES_HZ}
        self._stream_list = list(self.streams.values())
        self._mag_interval_us = int(US_PER_S / sc.sensors.mag_rate_hz)
        self._imu_interval_us = int(US_PER_S / sc.sensors.imu_rate_hz)
        self._field_interval_us = max(1, int(config.field_step_s * US_PER_S))
        self._log_interval_us = int(US_PER_S / config.log_rate_hz) if config.log_rate_hz > 0 else 0
        self._next = {"mag": 0, "imu": 0, "field": 0, "log": 0 if self._log_interval_us else 1 << 62,
                      "physics": 0, "init": int(config.init_s * US_PER_S),
                      "fault": self._next_fault_us(-1)}
        # time
        speedup = config.speedup
        if speedup is None:
            speedup = 0.0 if config.lockstep else DEFAULT_SPEEDUP
        self.pacer = Pacer(speedup)
        self.gate = LockstepGate(config.lockstep_period_s, config.lockstep_timeout_s,
                                 config.lockstep_start_timeout_s, config.lockstep_peer,
                                 config.lockstep_slack) if config.lockstep else None
        self._pending: deque = deque()   # lockstep: (link, peer, message, frame) read but not yet handled
        self._next["lockstep"] = 0 if self.gate else 1 << 62
        # parameters (a tiny read-mostly set, so ground stations finish their parameter download)
        self.params: dict[str, list] = {
            "SYSID_THISMAV": [float(self.sysid), MAV_PARAM_TYPE_INT32, None],
            "FRAME_CLASS": [2.0, MAV_PARAM_TYPE_INT32, None],           # 2 = boat
            "CRUISE_SPEED": [self.guidance.cruise_speed_mps, MAV_PARAM_TYPE_REAL32, (0.0, sc.vehicle.max_speed_mps)],
            "GUID_TIMEOUT": [self.guidance.setpoint_timeout_s, MAV_PARAM_TYPE_REAL32, (0.1, 60.0)],
            "SIM_SPEEDUP": [float(speedup), MAV_PARAM_TYPE_REAL32, None],
        }
        # sockets and records
        outs, masters = tuple(config.outs), tuple(config.masters)
        if not outs and not masters:
            outs = (DEFAULT_OUT,)
        self.links: list[Link] = []
        self.selector = selectors.DefaultSelector()
        try:
            for text in outs + masters:
                link = open_link(parse_endpoint(text), len(self.links))
                link.register(self.selector)
                self.links.append(link)
        except Exception:
            self._close_links()
            raise
        self.log_dir = self._resolve_log_dir()
        self.truth_log = TruthLog(self.log_dir / "truth.csv") if config.truth_log else None
        tlog_path = config.tlog
        if tlog_path is not None:
            tlog_path = self.log_dir / "sitl.tlog" if tlog_path == "" else Path(tlog_path)
        self.tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        self.wall_start = self.wall_end = 0.0
        self.home = self._fc_position()
        self._home_scale = tuple(float(v) for v in metres_per_degree(self.home[0]))
        self.guidance.home = self.home
        self.summary: dict = {}

    # ------------------------------------------------------------------ setup helpers
    def _resolve_log_dir(self) -> Path:
        if self.config.log_dir:
            path = Path(self.config.log_dir)
        else:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            path = Path("out") / "sitl" / f"{self.scenario.name}-{stamp}-{os.getpid()}"
        if self.config.truth_log or self.config.tlog == "":
            path.mkdir(parents=True, exist_ok=True)
        return path

    def _close_links(self) -> None:
        for link in self.links:
            try:
                link.close()
            except OSError:
                pass
        self.selector.close()

    def _count(self, key: str, n: int = 1) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    @property
    def time_s(self) -> float:
        return self.t_us / US_PER_S

    def request_stop(self) -> None:
        """Stop at the next iteration (thread- and signal-safe)."""
        self._stop.set()

    # ------------------------------------------------------------------ faults
    def _next_fault_us(self, after_us: int) -> int:
        for t in self._fault_times:
            us = int(round(t * US_PER_S))
            if us > after_us:
                return us
        return 1 << 62

    def _update_faults(self) -> None:
        now = self.time_s + 1e-9
        active = tuple(f for f in self.scenario.faults if f.active(now))
        if active != self._active_faults:
            old = {(f.kind, f.at_s) for f in self._active_faults}
            new = {(f.kind, f.at_s) for f in active}
            for f in active:
                if (f.kind, f.at_s) not in old:
                    self._count(f"fault_{f.kind}")
                    self._say(None, SEVERITY_WARNING, f"SITL fault {f.kind} ON" + (f" {f.value:g}" if f.value else ""))
            for f in self._active_faults:
                if (f.kind, f.at_s) not in new:
                    self._say(None, SEVERITY_NOTICE, f"SITL fault {f.kind} OFF")
            self._active_faults = active
            kinds = [f.kind for f in active]
            self._mag_off = "mag_off" in kinds
            self._mag_stuck = "mag_stuck" in kinds
            self._mag_nan = "mag_nan" in kinds
            self._mag_spike_nt = sum(f.value for f in active if f.kind == "mag_spike")
            self._gps_off = "gps_off" in kinds
            self._heartbeat_off = "heartbeat_off" in kinds
            self._loss = min(1.0, max(0.0, max([f.value for f in active if f.kind == "link_loss"], default=0.0)))
            self._dup = min(1.0, max(0.0, max([f.value for f in active if f.kind == "link_duplicate"], default=0.0)))
            self._delay_us = int(max([f.value for f in active if f.kind == "link_delay"], default=0.0) * US_PER_S)
            if self._storm_scale_now is not None:
                onset = [f.value or 1.0 for f in active if f.kind == "storm_onset"]
                self._storm_scale_now = max(onset) if onset else 0.0
                self._apply_storm_scale()
                self._field_us = -1
        self._next["fault"] = self._next_fault_us(self.t_us)

    def _apply_storm_scale(self) -> None:
        if self._storm_scale_now is None:
            self.truth = self.truth_full
        else:
            self.truth = replace(self.truth_full, storm_scale=self.truth_full.storm_scale * self._storm_scale_now)

    @property
    def gps_fix(self) -> bool:
        return self.time_s < self.scenario.sensors.gps_denied_after_s and not self._gps_off

    # ------------------------------------------------------------------ world
    def _fc_position(self) -> tuple[float, float]:
        memo = self._fc_memo
        if memo is not None and memo[0] == self.t_us:
            return memo[1]
        s = self.state
        self.nav.update(self.time_s, self.gps_fix, s.lat_deg, s.vel_east_mps, s.vel_north_mps)
        pos = self.nav.position(self.time_s, s.lat_deg, s.lon_deg)
        self._fc_memo = (self.t_us, pos)
        return pos

    def _update_field(self) -> None:
        s, truth = self.state, self.truth
        t = self.time_s
        ned = truth.field_ned_nt(s.lat_deg, s.lon_deg, self.scenario.alt_m, t)
        self._field = (float(ned[0]), float(ned[1]), float(ned[2]))
        if truth.disturbance is not None and truth.storm_scale != 0.0:   # the storm's part, for the truth log
            wmm = truth.model.elements(s.lat_deg, s.lon_deg, self.scenario.alt_m, truth.year)
            self._dist = (self._field[0] - wmm.x_nt, self._field[1] - wmm.y_nt, self._field[2] - wmm.z_nt)
        else:
            self._dist = (0.0, 0.0, 0.0)
        self._field_us = self.t_us

    def _true_attitude(self):
        memo = self._att_memo
        if memo is not None and memo[0] == self.t_us:
            return memo[1]
        att = self.wave.attitude(self.time_s, self.state.course_rad, self._yaw_rate)
        self._att_memo = (self.t_us, att)
        return att

    def _advance_physics(self, t_next_us: int) -> None:
        dt = (t_next_us - self.t_us) / US_PER_S
        if dt <= 0.0:
            return
        before = self.state
        course_cmd, speed_cmd = self._cmd
        self.state = after = step_vehicle(before, dt, course_cmd, speed_cmd, self.scenario.vehicle)
        self._accel_ned = ((after.vel_north_mps - before.vel_north_mps) / dt,
                           (after.vel_east_mps - before.vel_east_mps) / dt, 0.0)
        self._yaw_rate = wrap_pi(after.course_rad - before.course_rad) / dt

    def _update_command(self) -> None:
        g = self.guidance
        if g.armed and g.behaviour in ("guided", "rtl"):
            lat, lon = self._fc_position()
        else:
            lat = lon = 0.0
        self._cmd = g.command(self.time_s, self.state.course_rad, lat, lon)
        if g.events:
            self._drain_guidance_events()

    def _sample_mag(self) -> None:
        if self._mag_stuck:
            return
        if self._field_us < 0:
            self._update_field()
        x, y, z = self.sensors.sample_mag(self._field, self._true_attitude(), self._mag_spike_nt, self.time_s)
        self._mag_ints = (_int16(x / 100.0), _int16(y / 100.0), _int16(z / 100.0))   # nT -> mGauss

    def _sample_imu(self) -> None:
        sensors = self.sensors
        sensors.sample_imu(self._true_attitude(), self._accel_ned, self.time_s, self.nav.ins, self._fc_position)
        ax, ay, az = sensors.accel_mps2
        gx, gy, gz = sensors.gyro_radps
        k = 1000.0 / GRAVITY_MPS2
        self._imu_ints = (_int16(ax * k), _int16(ay * k), _int16(az * k),
                          _int16(gx * 1000.0), _int16(gy * 1000.0), _int16(gz * 1000.0))

    # ------------------------------------------------------------------ output
    def _emit(self, cls, *fields) -> None:
        """Queue one message (class and ``*_encode`` arguments) for the end of this iteration."""
        self._out.append(self.encoder.frame(cls, *fields))
        name = cls.msgname
        self.tx_by_type[name] = self.tx_by_type.get(name, 0) + 1

    def _say(self, key: str | None, severity: int, text: str) -> None:
        """STATUSTEXT (at most one per ``key`` per 5 s of simulated time when ``key`` is given)."""
        if key is not None:
            last = self._last_say.get(key)
            if last is not None and self.time_s - last < STATUSTEXT_MIN_INTERVAL_S:
                self._count("statustext_suppressed")
                return
            self._last_say[key] = self.time_s
        if not self.config.quiet and os.environ.get("FCMPC_SITL_ECHO"):
            print(f"[{self.time_s:10.1f}] {text}", file=sys.stderr)
        self._emit(mavlink.MAVLink_statustext_message, severity, text.encode("ascii", "replace")[:50])

    def _drain_guidance_events(self) -> None:
        events, self.guidance.events = self.guidance.events, []
        for severity, text in events:
            self._say(None, severity, text)

    def _flush(self) -> None:
        frames, self._out = self._out, []
        if self._loss or self._dup:
            kept = []
            rand = self._link_rng.random
            for frame in frames:
                if self._loss and rand() < self._loss:
                    self._count("tx_dropped_fault")
                    continue
                kept.append(frame)
                if self._dup and rand() < self._dup:
                    kept.append(frame)
                    self._count("tx_duplicated_fault")
            frames = kept
        if self._delay_us or self._delayed:
            # a FIFO link with latency: frames leave in order, none overtakes a delayed one
            if frames:
                release = self.t_us + self._delay_us
                if self._delayed:
                    release = max(release, self._delayed[-1][0])
                self._delayed.extend((release, frame) for frame in frames)
                if self._delay_us:
                    self._count("tx_delayed_fault", len(frames))
            k = 0
            while k < len(self._delayed) and self._delayed[k][0] <= self.t_us:
                k += 1
            frames = [frame for _, frame in self._delayed[:k]]
            del self._delayed[:k]
        if not frames:
            for link in self.links:
                link.flush()
            return
        self._count("tx_messages", len(frames))
        if self.tlog is not None:
            stamp = self.start_unix_us + self.t_us
            for frame in frames:
                self.tlog.write(stamp, frame)
        if self.config.batch:
            chunks, current, size = [], [], 0
            for frame in frames:
                if size + len(frame) > MAX_DATAGRAM_BYTES and current:
                    chunks.append(b"".join(current))
                    current, size = [], 0
                current.append(frame)
                size += len(frame)
            chunks.append(b"".join(current))
        else:
            chunks = frames
        for link in self.links:
            for chunk in chunks:
                link.send(chunk)

    # ------------------------------------------------------------------ streams
    def _send_heartbeat(self) -> None:
        if self._heartbeat_off:
            self._count("heartbeats_suppressed")
            return
        g = self.guidance
        status = MAV_STATE_BOOT if not g.ready else (MAV_STATE_ACTIVE if g.armed else MAV_STATE_STANDBY)
        self._emit(mavlink.MAVLink_heartbeat_message, MAV_TYPE_SURFACE_BOAT, self.dialect.autopilot, g.base_mode,
                   g.custom_mode, status, 3)

    def _send_system_time(self) -> None:
        self._last_system_time_us = self.t_us
        self._emit(mavlink.MAVLink_system_time_message, self.start_unix_us + self.t_us, self.t_us // 1000)

    def _send_sys_status(self) -> None:
        present = SENSOR_GYRO | SENSOR_ACCEL | SENSOR_MAG | SENSOR_GPS | SENSOR_AHRS
        health = present | SENSOR_GEOFENCE   # like ArduPilot: the fence bit is healthy while not breached
        if self._mag_off or self._mag_nan or self._mag_stuck:
            health &= ~SENSOR_MAG
        if not self.gps_fix:
            health &= ~SENSOR_GPS
        errors = self.counters.get("rx_bad_frames", 0)
        self._emit(mavlink.MAVLink_sys_status_message, present, present, health, 100, 12600, -1, -1,
                   int(self._loss * 10000), min(errors, 65535), 0, 0, 0, 0)

    def _mag_mgauss(self) -> tuple[int, int, int]:
        if self._mag_off:
            return 0, 0, 0
        if self._mag_nan:   # int16 cannot carry NaN: saturated, an impossible 3.3 G reading
            return INT16_MAX, INT16_MAX, INT16_MAX
        return self._mag_ints

    def _send_raw_imu(self) -> None:
        self._emit(mavlink.MAVLink_raw_imu_message, self.t_us, *self._imu_ints, *self._mag_mgauss(), 0, 0)

    def _send_scaled_imu(self) -> None:
        self._emit(mavlink.MAVLink_scaled_imu_message, self.t_us // 1000, *self._imu_ints, *self._mag_mgauss(), 0)

    def _send_highres_imu(self) -> None:
        ax, ay, az = self.sensors.accel_mps2
        gx, gy, gz = self.sensors.gyro_radps
        updated = 0b111111
        if self._mag_off:
            mx = my = mz = 0.0
        elif self._mag_nan:
            mx = my = mz = math.nan
            updated |= 0b111000000
        else:
            mx, my, mz = (v * 1e-5 for v in self.sensors.mag_nt)   # nT -> gauss
            updated |= 0b111000000
        self._emit(mavlink.MAVLink_highres_imu_message, self.t_us, ax, ay, az, gx, gy, gz, mx, my, mz,
                   1013.25, 0.0, self.scenario.alt_m, 25.0, updated, 0)

    def _send_attitude(self) -> None:
        a = self.sensors.attitude_est
        self._emit(mavlink.MAVLink_attitude_message, self.t_us // 1000, a.roll_rad, a.pitch_rad, wrap_pi(a.yaw_rad),
                   a.roll_rate_radps, a.pitch_rate_radps, a.yaw_rate_radps)

    def _fc_velocity(self) -> tuple[float, float]:
        s = self.state
        return self.nav.velocity(s.vel_east_mps, s.vel_north_mps)

    def _send_global_position_int(self) -> None:
        lat, lon = self._fc_position()
        ve, vn = self._fc_velocity()
        hdg = int(round(math.degrees(wrap_2pi(self.sensors.attitude_est.yaw_rad)) * 100.0)) % 36000
        alt_mm = int(round(self.scenario.alt_m * 1000.0))
        self._emit(mavlink.MAVLink_global_position_int_message,
                   self.t_us // 1000, int(round(lat * 1e7)), int(round(lon * 1e7)), alt_mm, 0,
                   _int16(vn * 100.0), _int16(ve * 100.0), 0, hdg)

    def _send_local_position_ned(self) -> None:
        lat, lon = self._fc_position()
        # enu_offset() of the home tangent plane, with its scale factors computed once
        east = ((lon - self.home[1] + 180.0) % 360.0 - 180.0) * self._home_scale[0]
        north = (lat - self.home[0]) * self._home_scale[1]
        ve, vn = self._fc_velocity()
        self._emit(mavlink.MAVLink_local_position_ned_message, self.t_us // 1000, float(north), float(east), 0.0,
                   vn, ve, 0.0)

    def _send_gps_raw_int(self) -> None:
        s = self.state
        stamp = self.start_unix_us + self.t_us
        if not self.gps_fix:
            fix = 0 if self._gps_off else 1
            self._emit(mavlink.MAVLink_gps_raw_int_message, stamp, fix, 0, 0, 0, 65535, 65535, 65535, 65535, 0,
                       0, 0, 0, 0, 0, 0)
            return
        sigma = self.scenario.sensors.gps_noise_m
        dn, de = self._gps_rng.normal(0.0, sigma, 2) if sigma > 0 else (0.0, 0.0)
        lat = s.lat_deg + math.degrees(dn / 6.3675e6)
        lon = s.lon_deg + math.degrees(de / (6.3781e6 * math.cos(math.radians(s.lat_deg))))
        cog = int(round(math.degrees(s.course_rad) * 100.0)) % 36000
        h_acc = int(sigma * 1000.0)
        alt_mm = int(self.scenario.alt_m * 1000)
        self._emit(mavlink.MAVLink_gps_raw_int_message,
                   stamp, 3, int(round(lat * 1e7)), int(round(lon * 1e7)), alt_mm, 90, 150,
                   int(round(s.speed_mps * 100.0)), cog, 14, alt_mm, h_acc, 2 * h_acc, 100, 0, 0)

    def _send_vfr_hud(self) -> None:
        s = self.state
        throttle = int(100 * s.speed_mps / self.scenario.vehicle.max_speed_mps)
        self._emit(mavlink.MAVLink_vfr_hud_message, s.speed_mps, s.speed_mps,
                   int(math.degrees(wrap_2pi(self.sensors.attitude_est.yaw_rad))) % 360,
                   throttle, self.scenario.alt_m, 0.0)

    def _send_home_position(self) -> None:
        lat, lon = self.home
        self._emit(mavlink.MAVLink_home_position_message, int(round(lat * 1e7)), int(round(lon * 1e7)),
                   int(self.scenario.alt_m * 1000), 0.0, 0.0, 0.0,
                   [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, self.t_us)

    def _send_extended_sys_state(self) -> None:
        self._emit(mavlink.MAVLink_extended_sys_state_message, 0, 1)  # landed state ON_GROUND (on the water)

    def _send_gps_global_origin(self) -> None:
        lat, lon = self.home
        self._emit(mavlink.MAVLink_gps_global_origin_message, int(round(lat * 1e7)), int(round(lon * 1e7)),
                   int(self.scenario.alt_m * 1000), self.t_us)

    def _send_autopilot_version(self) -> None:
        self._emit(mavlink.MAVLink_autopilot_version_message,
                   CAPABILITIES, self.dialect.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                   0x5157_0000 + self.sysid, [0] * 18)

    # ------------------------------------------------------------------ truth log
    def _write_truth(self) -> None:
        s = self.state
        if self._field_us < 0:
            self._update_field()
        fc_lat, fc_lon = self._fc_position()
        err_e, err_n = self.nav.error_m(self.time_s, s.lat_deg, s.lon_deg)
        decl, incl = decl_incl_from_ned(*self._field)
        att = self._true_attitude()
        g = self.guidance
        remaining = geodesic_distance_m(s.lat_deg, s.lon_deg, self.scenario.dest_lat_deg, self.scenario.dest_lon_deg)
        est = self._ext_estimate
        self._last_log_us = self.t_us
        self.truth_log.write({
            "time_s": self.time_s, "lat_deg": s.lat_deg, "lon_deg": s.lon_deg,
            "course_deg": math.degrees(s.course_rad), "speed_mps": s.speed_mps,
            "vn_mps": s.vel_north_mps, "ve_mps": s.vel_east_mps,
            "roll_deg": math.degrees(att.roll_rad), "pitch_deg": math.degrees(att.pitch_rad),
            "cmd_course_deg": math.degrees(wrap_2pi(self._cmd[0])), "cmd_speed_mps": float(self._cmd[1]),
            "mode": g.mode, "armed": int(g.armed), "fc_lat_deg": fc_lat, "fc_lon_deg": fc_lon,
            "fc_err_e_m": float(err_e), "fc_err_n_m": float(err_n), "gps_fix": int(self.gps_fix),
            "field_n_nt": self._field[0], "field_e_nt": self._field[1], "field_d_nt": self._field[2],
            "dist_n_nt": self._dist[0], "dist_e_nt": self._dist[1], "dist_d_nt": self._dist[2],
            "decl_deg": float(decl), "incl_deg": float(incl), "distance_m": s.distance_m,
            "remaining_m": remaining,
            "est_lat_deg": est[0] if est else None, "est_lon_deg": est[1] if est else None,
            "faults": ";".join(f.kind if not f.value else f"{f.kind}={f.value:g}" for f in self._active_faults),
        })

    # ------------------------------------------------------------------ input
    def _poll(self, timeout: float) -> int:
        """Read every readable socket (waiting up to ``timeout`` s) and handle what arrived."""
        try:
            events = self.selector.select(timeout)
        except (OSError, ValueError):
            return 0
        n = 0
        for key, _ in events:
            link: Link = key.data
            try:
                chunks = link.on_readable(key.fileobj, self.selector)
            except OSError:
                self._count("rx_socket_errors")
                continue
            for peer, data, is_datagram in chunks:
                n += self._receive(link, peer, data, is_datagram)
        return n

    def _receive(self, link: Link, peer, data: bytes, is_datagram: bool) -> int:
        self._count("rx_bytes", len(data))
        key = (link.index, peer)
        if is_datagram:
            buf = bytearray(data)
        else:
            if not data:  # TCP client closed
                self._stream_buffers.pop(key, None)
                return 0
            buf = self._stream_buffers.setdefault(key, bytearray())
            buf += data
        handled = 0
        i, n = 0, len(buf)
        decode = self._decoder.decode
        while i < n:
            magic = buf[i]
            if magic == 0xFD:
                if n - i < 3:
                    break
                length = 12 + buf[i + 1] + (13 if buf[i + 2] & 1 else 0)
            elif magic == 0xFE:
                if n - i < 2:
                    break
                length = 8 + buf[i + 1]
            else:
                j = n
                for marker in (0xFD, 0xFE):
                    k = buf.find(marker, i + 1)
                    if k != -1 and k < j:
                        j = k
                self._count("rx_garbage_bytes", j - i)
                i = j
                continue
            if n - i < length:
                break
            frame = buf[i:i + length]
            try:
                msg = decode(frame)
            except Exception:  # bad CRC, bad length, bad signature: resynchronise one byte later
                self._count("rx_bad_frames")
                i += 1
                continue
            if isinstance(msg, mavlink.MAVLink_unknown):
                self._count("rx_unknown_messages")  # CRC cannot be checked: skip one byte, resynchronise
                i += 1
                continue
            i += length
            handled += 1
            if self.gate is None:
                self._handle_frame(link, peer, msg, bytes(frame))
            else:   # lockstep: handled in order at the boundaries (see _lockstep_wait)
                self._pending.append((link, peer, msg, bytes(frame)))
        if is_datagram:
            if i < n:
                self._count("rx_truncated_bytes", n - i)
        else:
            del buf[:i]
            if len(buf) > 65536:
                self._count("rx_garbage_bytes", len(buf))
                buf.clear()
        return handled

    def _handle_frame(self, link: Link, peer, msg, frame: bytes) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.sysid, self.compid):
            self._count("rx_own_echo")
            return
        name = msg.get_type()
        self._count("rx_messages")
        self.rx_by_type[name] = self.rx_by_type.get(name, 0) + 1
        if self.tlog is not None:
            self.tlog.write(self.start_unix_us + self.t_us, frame)
        target_sys = getattr(msg, "target_system", None)
        target_comp = getattr(msg, "target_component", None)
        for_us = (target_sys in (None, 0, self.sysid)) and (target_comp in (None, 0, self.compid))
        if self.config.routing and (target_sys != self.sysid or target_comp not in (self.compid,)) and \
                (len(self.links) > 1 or link.peer_count() > 1):
            for other in self.links:
                other.send(frame, exclude=peer if other is link else None)
            self._count("rx_routed")
        if self.gate is not None and self.gate.eligible(*src):
            stamp = getattr(msg, "time_boot_ms", None)
            self.gate.observe(stamp if isinstance(stamp, int) else None, self.t_us)
        if name == "HEARTBEAT":
            if src not in self.peers:
                self._say(None, SEVERITY_INFO, f"Peer {src[0]}/{src[1]} type {msg.type} connected")
            self.peers[src] = msg.type
            return
        if not for_us:
            self._count("rx_not_for_us")
            return
        handler = self._handlers.get(name)
        if handler is None:
            self._count("rx_unhandled")
            return
        self._call(handler, msg)

    def _call(self, handler, msg) -> None:
        try:
            handler(self, msg)
        except Exception as err:  # never let a message kill the simulator
            self._count("rx_handler_errors")
            self._say("handler_error", SEVERITY_WARNING, f"SITL: {msg.get_type()} failed: {type(err).__name__}")
            if os.environ.get("FCMPC_SITL_DEBUG"):
                raise

    # ------------------------------------------------------------------ handlers
    def _ack(self, msg, command: int, result: int) -> None:
        self._count(f"ack_{mavlink.enums['MAV_RESULT'][result].name[11:].lower()}" if result in
                    mavlink.enums["MAV_RESULT"] else "ack_other")
        self._emit(mavlink.MAVLink_command_ack_message, command, result, 0, 0, msg.get_srcSystem(),
                   msg.get_srcComponent())

    def _on_command(self, msg) -> None:
        is_int = msg.get_type() == "COMMAND_INT"
        cmd = msg.command
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if is_int:
            p += [msg.x / 1e7 if msg.frame not in (1, 4, 7, 8, 9, 12) else float(msg.x), msg.y / 1e7, msg.z]
        else:
            p += [msg.param5, msg.param6, msg.param7]
        g = self.guidance
        t = self.time_s
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] not in (0.0, 1.0):
                result = MAV_RESULT_DENIED
            else:
                result = g.request_arm(p[0] == 1.0, t)
        elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
            if not math.isfinite(p[0]) or not int(p[0]) & 1:
                result = MAV_RESULT_UNSUPPORTED   # only custom modes
            else:
                mode = self.dialect.mode_from_command(p[1], p[2])
                result = g.request_mode(mode, t, f"{p[1]:g}/{p[2]:g}")
        elif cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            result = g.request_mode(self.dialect.rtl_mode, t)
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_message_interval(p[0], p[1])
        elif cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            result = self._get_message_interval(p[0])
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if not self._can_send_once(p[0]):
                self._count("interval_unsupported")
                self._ack(msg, cmd, MAV_RESULT_UNSUPPORTED)
            else:
                self._ack(msg, cmd, MAV_RESULT_ACCEPTED)
                self._send_once(int(p[0]))
            return
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(msg, cmd, MAV_RESULT_ACCEPTED)
            self._send_autopilot_version()
            return
        elif cmd == mavlink.MAV_CMD_GUIDED_CHANGE_SPEED:
            result = g.change_speed(p[1]) if p[0] in (0.0, 1.0) else MAV_RESULT_DENIED
        elif cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            result = g.change_speed(p[1])
        elif cmd == mavlink.MAV_CMD_GUIDED_CHANGE_HEADING:
            if p[0] not in (0.0, 1.0) or not (math.isfinite(p[1]) and -360.0 <= p[1] <= 360.0):
                self._count("commands_bad_value")
                result = MAV_RESULT_DENIED
            else:
                result = g.change_heading(math.radians(p[1]))
        elif cmd == mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE:
            result = self._external_position(p, is_int)
        else:
            self._count("commands_unsupported")
            result = MAV_RESULT_UNSUPPORTED
        if g.events:
            self._drain_guidance_events()
        self._ack(msg, cmd, result)

    def _external_position(self, p: list[float], is_int: bool) -> int:
        lat, lon = p[4], p[5]
        if not (math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
            self._count("commands_bad_value")
            return MAV_RESULT_DENIED
        self._ext_estimate = (lat, lon)
        self._count("external_position_estimates")
        return MAV_RESULT_ACCEPTED

    def _can_send_once(self, msg_id: float) -> bool:
        return math.isfinite(msg_id) and (int(msg_id) in STREAM_BY_ID or int(msg_id) in (49, 148))

    def _send_once(self, msg_id: int) -> None:
        if msg_id == 148:
            self._send_autopilot_version()
        elif msg_id == 49:
            self._send_gps_global_origin()
        elif msg_id == 0 and self._heartbeat_off:
            return
        else:
            self.streams[STREAM_BY_ID[msg_id]].send()

    def _set_message_interval(self, msg_id: float, interval_us: float) -> int:
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)) or int(msg_id) not in STREAM_BY_ID:
            self._count("interval_unsupported")
            return MAV_RESULT_UNSUPPORTED
        stream = self.streams[STREAM_BY_ID[int(msg_id)]]
        if interval_us == -1:
            rate = 0.0
        elif interval_us == 0:
            rate = self.default_rates[stream.name]
        elif interval_us < 1000:
            return MAV_RESULT_DENIED
        else:
            rate = US_PER_S / interval_us
        stream.set_rate(rate, self.t_us)
        return MAV_RESULT_ACCEPTED

    def _get_message_interval(self, msg_id: float) -> int:
        if not math.isfinite(msg_id) or int(msg_id) not in STREAM_BY_ID:
            self._emit(mavlink.MAVLink_message_interval_message, int(msg_id) if math.isfinite(msg_id) else 0, 0)
            return MAV_RESULT_ACCEPTED
        stream = self.streams[STREAM_BY_ID[int(msg_id)]]
        self._emit(mavlink.MAVLink_message_interval_message, int(msg_id), stream.interval_us or -1)
        return MAV_RESULT_ACCEPTED

    def _on_set_mode(self, msg) -> None:
        if not msg.base_mode & 1:
            result = MAV_RESULT_UNSUPPORTED
        else:
            result = self.guidance.request_mode(self.dialect.mode_from_custom(msg.custom_mode), self.time_s,
                                                str(msg.custom_mode))
        self._drain_guidance_events()
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, result)

    def _on_request_data_stream(self, msg) -> None:
        names = DATA_STREAM_GROUPS.get(msg.req_stream_id)
        if names is None:
            self._count("data_stream_unknown")
            return
        rate = float(msg.req_message_rate) if msg.start_stop else 0.0
        for name in names:
            self.streams[name].set_rate(rate, self.t_us)

    def _on_position_target(self, msg) -> None:
        g = self.guidance
        is_global = msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"
        fc_lat, fc_lon = self._fc_position()
        try:
            if is_global:
                target = interpret_position_target(
                    frame=msg.coordinate_frame, type_mask=msg.type_mask, vx=msg.vx, vy=msg.vy, yaw=msg.yaw,
                    max_speed_mps=self.scenario.vehicle.max_speed_mps, current_yaw_rad=self.state.course_rad,
                    fc_lat_deg=fc_lat, fc_lon_deg=fc_lon, origin=self.home,
                    lat_deg=msg.lat_int / 1e7, lon_deg=msg.lon_int / 1e7)
            else:
                target = interpret_position_target(
                    frame=msg.coordinate_frame, type_mask=msg.type_mask, vx=msg.vx, vy=msg.vy, yaw=msg.yaw,
                    max_speed_mps=self.scenario.vehicle.max_speed_mps, current_yaw_rad=self.state.course_rad,
                    fc_lat_deg=fc_lat, fc_lon_deg=fc_lon, origin=self.home, x_m=msg.x, y_m=msg.y)
        except SetpointError as err:
            self._count(f"setpoints_rejected_{err.reason}")
            self._say(f"setpoint_{err.reason}", SEVERITY_WARNING, f"Setpoint rejected: {err}")
            return
        if not g.accept_setpoint(self.time_s):
            self._say("setpoint_mode", SEVERITY_WARNING,
                      f"Setpoint ignored: {'disarmed' if not g.armed else 'mode ' + g.mode}")
            return
        g.apply_target(target, self.time_s)

    def _on_timesync(self, msg) -> None:
        if msg.tc1 == 0:
            # tc1 = our simulated clock in ns (never 0: tc1 == 0 marks a request)
            self._emit(mavlink.MAVLink_timesync_message, max(1, self.t_us * 1000), msg.ts1)

    def _param_value(self, name: str, index: int) -> None:
        value, kind, _ = self.params[name]
        self._emit(mavlink.MAVLink_param_value_message, name.encode(), float(value), kind, len(self.params), index)

    def _on_param_request_list(self, msg) -> None:
        for index, name in enumerate(self.params):
            self._param_value(name, index)

    def _on_param_request_read(self, msg) -> None:
        names = list(self.params)
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("ascii", "replace")
        if name in self.params:
            self._param_value(name, names.index(name))
        elif 0 <= msg.param_index < len(names):
            self._param_value(names[msg.param_index], msg.param_index)

    def _on_param_set(self, msg) -> None:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("ascii", "replace")
        if name not in self.params:
            self._count("param_set_unknown")
            return
        entry = self.params[name]
        limits = entry[2]
        value = float(msg.param_value)
        if limits is not None and math.isfinite(value) and limits[0] <= value <= limits[1]:
            entry[0] = value
            if name == "CRUISE_SPEED":
                self.guidance.cruise_speed_mps = value
            elif name == "GUID_TIMEOUT":
                self.guidance.setpoint_timeout_s = value
        else:
            self._count("param_set_refused")
            self._say(f"param_{name}", SEVERITY_WARNING, f"PARAM_SET {name} refused")
        self._param_value(name, list(self.params).index(name))

    def _on_odometry(self, msg) -> None:
        """An external estimate in the FC's local NED frame (x north, y east of home) for the truth log."""
        if msg.frame_id not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD) or \
                not (math.isfinite(msg.x) and math.isfinite(msg.y)):
            self._count("odometry_ignored")
            return
        lat = self.home[0] + msg.x / self._home_scale[1]
        lon = (self.home[1] + msg.y / self._home_scale[0] + 180.0) % 360.0 - 180.0
        self._ext_estimate = (lat, lon)
        self._count("odometry_estimates")

    def _on_ping(self, msg) -> None:
        if msg.target_system == 0:   # a request: answer with the same seq and time, addressed to the sender
            self._emit(mavlink.MAVLink_ping_message, msg.time_usec, msg.seq, msg.get_srcSystem(),
                       msg.get_srcComponent())

    def _on_mission_request_list(self, msg) -> None:
        self._emit(mavlink.MAVLink_mission_count_message, msg.get_srcSystem(), msg.get_srcComponent(), 0,
                   getattr(msg, "mission_type", 0))

    _handlers = {
        "COMMAND_LONG": _on_command,
        "COMMAND_INT": _on_command,
        "SET_MODE": _on_set_mode,
        "REQUEST_DATA_STREAM": _on_request_data_stream,
        "SET_POSITION_TARGET_GLOBAL_INT": _on_position_target,
        "SET_POSITION_TARGET_LOCAL_NED": _on_position_target,
        "TIMESYNC": _on_timesync,
        "PARAM_REQUEST_LIST": _on_param_request_list,
        "PARAM_REQUEST_READ": _on_param_request_read,
        "PARAM_SET": _on_param_set,
        "MISSION_REQUEST_LIST": _on_mission_request_list,
        "PING": _on_ping,
        "ODOMETRY": _on_odometry,
    }

    # ------------------------------------------------------------------ the loop
    def _next_event_us(self) -> int:
        nxt = self._next
        t = min(nxt["mag"], nxt["imu"], nxt["field"], nxt["log"], nxt["physics"], nxt["init"], nxt["fault"],
                nxt["lockstep"])
        for stream in self._stream_list:
            if stream.next_us < t:
                t = stream.next_us
        if self._delayed and self._delayed[0][0] < t:
            t = self._delayed[0][0]
        return t

    def _run_due(self) -> None:
        now = self.t_us
        nxt = self._next
        if nxt["fault"] <= now:
            self._update_faults()
        if nxt["init"] <= now:
            nxt["init"] = 1 << 62
            self.guidance.set_ready()
            if self.config.cruise is not None:
                self.guidance.start_cruise(math.radians(self.config.cruise[0]), self.config.cruise[1])
            self._drain_guidance_events()
        if nxt["field"] <= now:
            nxt["field"] = now + self._field_interval_us
            self._update_field()
        if nxt["physics"] <= now:
            nxt["physics"] = now + PHYSICS_STEP_US
        if nxt["mag"] <= now:
            nxt["mag"] = now + self._mag_interval_us
            self._sample_mag()
        if nxt["imu"] <= now:
            nxt["imu"] = now + self._imu_interval_us
            self._sample_imu()
        for stream in self._stream_list:
            if stream.next_us <= now:
                stream.next_us += stream.interval_us
                if stream.next_us <= now:   # after a rate change or a long step: no burst
                    stream.next_us = now + stream.interval_us
                stream.send()
        if nxt["log"] <= now:
            nxt["log"] = now + self._log_interval_us
            if self.truth_log is not None:
                self._write_truth()

    def _lockstep_wait(self) -> None:
        """At a boundary: send its marker, then handle queued input in order until the gate opens.

        Messages are handled in arrival order and only up to (and including) the one that
        answers this boundary; the rest waits for the next boundary. Where the simulation
        stops reading therefore depends on the companion's message sequence, not on how fast
        either process runs, and a deterministic companion gives a bit-reproducible run.
        """
        gate = self.gate
        now_us = self.t_us
        self._next["lockstep"] = now_us + gate.period_us
        if self._last_system_time_us != now_us:
            self._send_system_time()
        self._flush()
        start = time.perf_counter()
        if not gate.peer_heard:
            limit = gate.start_timeout_s
            beat = start
            while not gate.peer_heard and not self._pending and not self._stop.is_set():
                now = time.perf_counter()
                if limit > 0 and now - start > limit:
                    break
                if now - beat >= 1.0:
                    beat = now
                    self._send_heartbeat()
                self._poll(0.1)
                self._flush()
        # a link_delay fault holds our frames back: the companion can only have answered older ones
        threshold = now_us - self._delay_us
        deadline = time.perf_counter() + gate.timeout_s
        timed_out = False
        while not self._stop.is_set():
            answered = self._handle_pending(threshold)
            self._flush()
            if answered:
                break
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                timed_out = True
                break
            self._poll(min(remaining, 0.1))
        waited = time.perf_counter() - start
        gate.finish(waited, timed_out)
        if timed_out:
            self._say("lockstep_timeout", SEVERITY_WARNING, f"Lockstep: no answer in {gate.timeout_s:g}s, going on")
            self._flush()
        self.pacer.restart(now_us)

    def _handle_pending(self, threshold_us: int) -> bool:
        """Handle queued messages in order until the gate is satisfied (True) or none is left (False)."""
        gate, pending = self.gate, self._pending
        while not gate.satisfied(threshold_us):
            if not pending:
                return False
            self._handle_frame(*pending.popleft())
        return True

    def _pace(self, t_next_us: int) -> None:
        lockstep = self.gate is not None
        deadline = self.pacer.deadline(t_next_us)
        if deadline is None:
            if not lockstep:
                self._poll(0.0)
            return
        while not self._stop.is_set():
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                break
            if lockstep:
                time.sleep(min(remaining, 0.05))
            else:
                self._poll(min(remaining, 0.05))
                self._flush()
        if not lockstep:
            self._poll(0.0)

    def run(self) -> dict:
        """Run the simulation; returns (and stores in ``summary``) the counters of the run."""
        self.wall_start = time.perf_counter()
        self.pacer.restart(0)
        self.ready_event.set()
        if not self.config.quiet:
            self._print_banner()
        try:
            self._update_faults()
            while not self._stop.is_set():
                t_next = self._next_event_us()
                if t_next > self.end_us:
                    break
                self._pace(t_next)
                self._update_command()
                self._advance_physics(t_next)
                self.t_us = t_next
                self._run_due()
                self._flush()
                if self._next["lockstep"] <= self.t_us:
                    self._lockstep_wait()
        finally:
            self.wall_end = time.perf_counter()
            self._finish()
        return self.summary

    def _print_banner(self) -> None:
        c = self.config
        links = ", ".join(f"{link.endpoint} (local {link.local_address[0]}:{link.local_address[1]})"
                          for link in self.links)
        pace = "unlimited" if self.pacer.speedup is None else f"{self.pacer.speedup:g}x"
        print(f"fcmpc-sitl: scenario {self.scenario.name}, {self.dialect.name} boat sysid {self.sysid}, "
              f"links {links}, speed-up {pace}{', lockstep %gs' % c.lockstep_period_s if c.lockstep else ''}, "
              f"records {self.log_dir if (self.truth_log or self.tlog) else 'off'}", file=sys.stderr, flush=True)

    def _finish(self) -> None:
        try:
            if self.truth_log is not None and self._last_log_us != self.t_us:
                self._write_truth()
        except Exception:  # pragma: no cover - never lose the summary for a log row
            pass
        for record in (self.truth_log, self.tlog):
            if record is not None:
                record.close()
        self._close_links()
        wall = max(self.wall_end - self.wall_start, 1e-9)
        sim = self.time_s
        tx = self.counters.get("tx_messages", 0)
        summary = {
            "scenario": self.scenario.name, "autopilot": self.dialect.name, "seed": self.config.seed,
            "sim_s": round(sim, 3), "wall_s": round(wall, 3), "speedup": round(sim / wall, 1),
            "tx_messages": tx, "tx_msgs_per_wall_s": round(tx / wall, 1),
            "tx_bytes": sum(link.tx_bytes for link in self.links),
            "tx_dropped_socket": sum(link.tx_dropped for link in self.links),
            "mode": self.guidance.mode, "armed": self.guidance.armed,
            "lat_deg": self.state.lat_deg, "lon_deg": self.state.lon_deg, "distance_m": self.state.distance_m,
            "counters": dict(sorted({**self.counters, **self.guidance.counters}.items())),
            "tx_by_type": dict(sorted(self.tx_by_type.items())),
            "rx_by_type": dict(sorted(self.rx_by_type.items())),
            "peers": [f"{s}/{c}" for s, c in self.peers],
            "log_dir": str(self.log_dir) if (self.truth_log or self.tlog) else None,
        }
        if self.gate is not None:
            summary.update(self.gate.stats())
        self.summary = summary
        path = self.config.summary_json
        if path is None and (self.truth_log is not None or self.tlog is not None):
            path = str(self.log_dir / "summary.json")
        if path:
            try:
                Path(path).parent.mkdir(parents=True, exist_ok=True)
                Path(path).write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
            except OSError as err:
                print(f"fcmpc-sitl: cannot write {path}: {err}", file=sys.stderr)
        if not self.config.quiet:
            print(format_summary(summary), file=sys.stderr, flush=True)


def format_summary(summary: dict) -> str:
    """Human-readable lines of a run summary."""
    lines = [f"fcmpc-sitl: {summary['sim_s']:.1f} s simulated in {summary['wall_s']:.2f} s wall "
             f"({summary['speedup']:g}x), {summary['tx_messages']} messages sent "
             f"({summary['tx_msgs_per_wall_s']:.0f}/s), mode {summary['mode']}, "
             f"{'armed' if summary['armed'] else 'disarmed'}, {summary['distance_m'] / 1000.0:.3f} km flown"]
    counters = summary.get("counters", {})
    if counters:
        lines.append("  counters: " + ", ".join(f"{k}={v}" for k, v in counters.items()))
    if "lockstep_boundaries" in summary:
        lines.append(f"  lockstep: {summary['lockstep_boundaries']} boundaries, "
                     f"{summary['lockstep_timeouts']} timeouts,"
                     f" waited {summary['lockstep_wait_wall_s']} s")
    if summary.get("log_dir"):
        lines.append(f"  records in {summary['log_dir']}")
    return "\n".join(lines)


# ---------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fcmpc-sitl",
        description="MAVLink 2 simulator of an ArduPilot Rover (or PX4) boat flying a geomagnetic-navigation "
                    "scenario faster than real time. Every message carries simulated time.",
    )
    p.add_argument("--scenario", default="pacific", help="bundled scenario name or TOML path (default pacific)")
    p.add_argument("--out", action="append", default=[], metavar="udp:HOST:PORT",
                   help=f"send to HOST:PORT (like ArduPilot SITL/MAVProxy --out); default {DEFAULT_OUT} "
                        "when neither --out nor --master is given. Repeatable")
    p.add_argument("--master", action="append", default=[], metavar="tcp:HOST:PORT",
                   help="listen: tcp:HOST:PORT (TCP server like ArduPilot SITL on 5760) or udpin:HOST:PORT. "
                        "Repeatable")
    p.add_argument("--speedup", type=float, default=None,
                   help="simulated seconds per wall second; 0 = as fast as possible "
                        f"(default {DEFAULT_SPEEDUP:g}, or unlimited with --lockstep)")
    p.add_argument("--lockstep", action="store_true", help="advance time only when the companion answers")
    p.add_argument("--lockstep-period", type=float, default=0.2, help="simulated seconds between lockstep boundaries (default 0.2)")
    p.add_argument("--lockstep-timeout", type=float, default=2.0, help="wall seconds to wait for an answer at a boundary (default 2)")
    p.add_argument("--lockstep-start-timeout", type=float, default=60.0,
                   help="wall seconds to wait for the first peer at t=0, 0 = for ever (default 60)")
    p.add_argument("--lockstep-slack", type=int, choices=(0, 1), default=1,
                   help="periods the companion may lag behind a boundary: 1 (default) lets both run in parallel, "
                        "0 makes them alternate")
    p.add_argument("--lockstep-peer", default=None, metavar="SYS:COMP",
                   help="only this sender answers lockstep (default any sender but the simulator)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    p.add_argument("--max-sim-s", type=float, default=30 * 3600.0, help="hard limit of simulated time (default 30 h)")
    p.add_argument("--seed", type=int, default=0, help="seed of every noise, INS error and fault draw (default 0)")
    p.add_argument("--autopilot", choices=sorted(DIALECTS), default="ardupilot",
                   help="mode numbering and guided rules: ArduPilot Rover GUIDED (default) or PX4 OFFBOARD")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--setpoint-timeout", type=float, default=None,
                   help="simulated seconds without velocity setpoints before stopping (default 3 ArduPilot, 1 PX4)")
    p.add_argument("--cruise-speed", type=float, default=None, help="m/s for RTL and position targets "
                                                                    "(default NAV_SPEED_KMH)")
    p.add_argument("--init-s", type=float, default=1.0, help="simulated seconds in INITIALISING after boot (default 1)")
    p.add_argument("--cruise", default=None, metavar="COURSE_DEG:SPEED_MPS",
                   help="without a companion: arm in GUIDED/OFFBOARD when ready and hold this course and speed")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:AT_S[:DURATION_S[:VALUE]]",
                   help=f"add a fault to the scenario's schedule; kinds: {', '.join(FAULT_KINDS)}")
    p.add_argument("--rate", action="append", default=[], metavar="MESSAGE:HZ",
                   help="default stream rate, e.g. RAW_IMU:20 or HIGHRES_IMU:10 (0 = off)")
    p.add_argument("--log-dir", default=None, help="records folder (default out/sitl/<scenario>-<time>-<pid>)")
    p.add_argument("--no-truth-log", action="store_true", help="do not write truth.csv")
    p.add_argument("--log-rate", type=float, default=1.0, help="truth.csv rows per simulated second (default 1)")
    p.add_argument("--tlog", nargs="?", const="", default=None, metavar="PATH",
                   help="write a MAVLink .tlog of everything sent and received (default <log-dir>/sitl.tlog)")
    p.add_argument("--summary-json", default=None, help="write the run summary here (default <log-dir>/summary.json)")
    p.add_argument("--data-dir", default=None, help="real data folder for storms (default $FCMPC_DATA_DIR or "
                                                     "../shared/data)")
    p.add_argument("--expected-duration", type=float, default=None,
                   help="mission seconds the 'compress' storm rule spreads the window over")
    p.add_argument("--field-step", type=float, default=1.0, help="simulated seconds between field evaluations (default 1)")
    p.add_argument("--ins-step", type=float, default=5.0, help="simulated seconds between INS propagations (default 5)")
    p.add_argument("--wave-roll", type=float, default=3.0, help="roll amplitude of the wave motion, deg (default 3)")
    p.add_argument("--wave-pitch", type=float, default=2.0, help="pitch amplitude of the wave motion, deg (default 2)")
    p.add_argument("--no-routing", action="store_true", help="do not forward messages between links")
    p.add_argument("--no-batch", action="store_true", help="one UDP datagram per message")
    p.add_argument("--quiet", action="store_true", help="no banner or summary on stderr")
    return p


def config_from_args(args: argparse.Namespace) -> ServerConfig:
    cruise = None
    if args.cruise:
        course, _, speed = args.cruise.partition(":")
        cruise = (float(course), float(speed or 0.0))
    peer = None
    if args.lockstep_peer:
        a, _, b = args.lockstep_peer.partition(":")
        peer = (int(a), int(b))
    return ServerConfig(
        scenario=args.scenario, outs=tuple(args.out), masters=tuple(args.master), speedup=args.speedup,
        lockstep=args.lockstep, lockstep_period_s=args.lockstep_period, lockstep_timeout_s=args.lockstep_timeout,
        lockstep_start_timeout_s=args.lockstep_start_timeout, lockstep_peer=peer,
        lockstep_slack=args.lockstep_slack, duration_s=args.duration,
        max_sim_s=args.max_sim_s, seed=args.seed, autopilot=args.autopilot, sysid=args.sysid,
        setpoint_timeout_s=args.setpoint_timeout, cruise_speed_mps=args.cruise_speed, init_s=args.init_s,
        cruise=cruise,
        log_dir=args.log_dir, truth_log=not args.no_truth_log, log_rate_hz=args.log_rate, tlog=args.tlog,
        faults=tuple(args.fault), rates=tuple(args.rate), field_step_s=args.field_step, ins_step_s=args.ins_step,
        wave_roll_deg=args.wave_roll, wave_pitch_deg=args.wave_pitch, data_dir=args.data_dir,
        expected_duration_s=args.expected_duration, routing=not args.no_routing, batch=not args.no_batch,
        summary_json=args.summary_json, quiet=args.quiet)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        server = SitlServer(config_from_args(args))
    except (ScenarioError, ValueError, OSError, RuntimeError) as err:
        print(f"fcmpc-sitl: {err}", file=sys.stderr)
        return 2

    def stop(signum, frame):  # noqa: ARG001
        server.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    server.run()
    return 0


# ---------------------------------------------------------------------- benchmark
def _free_udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind(("127.0.0.1", 0))
    return sock


def _count_frames(data: bytes) -> tuple[int, int]:
    """(MAVLink 2 frames, stray bytes) of a datagram, walking the length bytes of the headers."""
    frames = stray = 0
    i, n = 0, len(data)
    while i < n:
        if data[i] == 0xFD and i + 2 < n:
            i += 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
            frames += 1
        else:
            i += 1
            stray += 1
    return frames, stray


def benchmark(duration_sim_s: float = 3600.0, speedup: float | None = None, scenario: str = "pacific",
              extra_args: tuple[str, ...] = ("--cruise", "132.3:13.9"), decode_every: int = 20,
              timeout_s: float = 600.0) -> dict:
    """Speed of the simulator on a scenario, with a reader draining its UDP output.

    The simulator runs as a separate process (``python -m sitl.server``, unlimited speed-up
    unless ``speedup`` is given, default 10 Hz IMU/magnetometer streams, truth log on, the boat
    cruising at 50 km/h towards the destination by ``--cruise``: ``extra_args``). This process
    reads its UDP output, counts the frames of every datagram from their headers and decodes
    one datagram in ``decode_every`` completely with pymavlink, CRC checked (1 = all; a full
    decode costs the reader about a core at these rates, which on a 2-core machine slows the
    simulator it measures). Returns ``sim_s``, ``wall_s``, ``speedup`` (simulated over wall
    time), ``tx_messages`` and ``tx_msgs_per_s`` (sent, per wall second), ``rx_messages`` and
    ``rx_msgs_per_s`` (received by the reader), ``rx_loss`` (fraction lost on the way),
    ``rx_decoded`` and ``rx_bad`` (frames decoded, and failing to decode).
    """
    sock = _free_udp_socket()
    port = sock.getsockname()[1]
    sock.settimeout(0.2)
    with tempfile.TemporaryDirectory(prefix="fcmpc-bench-") as tmp:
        summary_path = Path(tmp) / "summary.json"
        cmd = [sys.executable, "-m", "sitl.server", "--scenario", scenario, "--out", f"udp:127.0.0.1:{port}",
               "--duration", str(duration_sim_s), "--speedup", str(speedup if speedup else 0),
               "--log-dir", tmp, "--summary-json", str(summary_path), "--quiet", *extra_args]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MAVLINK20="1")
        repo = str(Path(__file__).resolve().parents[1])
        env["PYTHONPATH"] = repo + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        rx = decoded = bad = datagrams = 0
        first = last = None
        deadline = time.monotonic() + timeout_s
        try:
            while time.monotonic() < deadline:
                try:
                    data = sock.recv(65535)
                except socket.timeout:
                    if proc.poll() is not None:
                        break
                    continue
                now = time.perf_counter()
                first = first or now
                last = now
                datagrams += 1
                frames, stray = _count_frames(data)
                rx += frames
                bad += stray
                if decode_every and datagrams % decode_every == 0:
                    for msg in mav.parse_buffer(data) or ():
                        if isinstance(msg, mavlink.MAVLink_bad_data):
                            bad += 1
                        else:
                            decoded += 1
        finally:
            if proc.poll() is None:
                proc.terminate()
            _, err = proc.communicate(timeout=30)
            sock.close()
        if not summary_path.exists():
            raise RuntimeError(f"simulator did not finish: {err.decode(errors='replace')[-2000:]}")
        summary = json.loads(summary_path.read_text())
    tx = summary["tx_messages"]
    wall = summary["wall_s"]
    reader_wall = (last - first) if first and last and last > first else wall
    return {
        "scenario": scenario, "sim_s": summary["sim_s"], "wall_s": wall, "speedup": summary["speedup"],
        "tx_messages": tx, "tx_msgs_per_s": round(tx / wall, 1), "rx_messages": rx,
        "rx_msgs_per_s": round(rx / reader_wall, 1), "rx_loss": round(1.0 - rx / tx, 4) if tx else 0.0,
        "rx_decoded": decoded, "rx_bad": bad,
    }


if __name__ == "__main__":
    sys.exit(main())

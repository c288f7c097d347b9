"""fcmpc-companion: the process on the companion board that flies the Fc-MPC mission over MAVLink.

::

    fcmpc-companion --connect udp:127.0.0.1:14550                 # listen, like a GCS on 14550
    fcmpc-companion --connect tcp:127.0.0.1:5760 --params my.parm  # ArduPilot SITL's TCP port
    fcmpc-companion --connect /dev/ttyAMA0,921600 --log-dir /var/log/fcmpc

It wires the MAVLink link (:mod:`companion.io.mavlink_link`), the parameter server
(:mod:`companion.io.param_server`), the sensor decoder (:mod:`companion.io.sensors.mavlink_source`),
the magnetometer pipeline (:mod:`companion.nav.magnetometer`) and the pure navigation core
(:class:`companion.nav.mission.Mission`), and owns the failsafes (:mod:`companion.failsafe`).

Clocks
    Everything the navigation sees runs on *message time*: the flight controller's
    ``time_boot_ms`` (and SYSTEM_TIME), so a simulator running 1000x faster than real time is
    flown exactly like a vehicle. The setpoint stream (COMP_SP_RATE_HZ), the heartbeat (1 Hz)
    and the control step (NAV_PERIOD_S) are scheduled in message time. Wall time is used only
    for socket waits, the heartbeat's wall-time floor (1 Hz) and judging a flight controller that
    went completely silent (see :mod:`companion.failsafe`).

Sequence
    ``wait_fc``: no flight-controller HEARTBEAT yet. ``startup``: streams requested; the vehicle is
    stationary while D and I are averaged over a start-up window (default one control period),
    which becomes the first measurement. ``ready``: with COMP_ARM_ENABLE = 1 the companion switches
    to GUIDED (ArduPilot) or, after >= 1 s of zero-velocity setpoints, OFFBOARD (PX4) and arms;
    with 0 it waits for the operator to do so. ``running``: once the flight controller is armed in
    GUIDED/OFFBOARD the mission starts (start = GPS fix if the receiver has a 3D fix, else
    NAV_START_LAT/LON); every NAV_PERIOD_S of *mission time* the averaged (D, I) and the flight
    controller's INS position (GLOBAL_POSITION_INT; dead reckoning on the commanded velocity when
    it is missing) go into the core, whose course and speed are streamed as setpoints.
    ``done``: arrived or failed: setpoints stop, hold mode is commanded.

Mission time and pauses
    Mission time is message time minus the time spent paused. The mission pauses whenever the
    vehicle is not following (failsafe, or the flight controller not armed in GUIDED/OFFBOARD):
    the core's dead reckoning assumes the last command was flown for the whole period, so the
    clock must not run while the vehicle holds. Samples taken while paused are not averaged.

Failsafes (:mod:`companion.failsafe`)
    Stale magnetometer or attitude, flight-controller heartbeat lost, broken parameter file:
    stop streaming velocity, command HOLD (ArduPilot) / AUTO.LOITER (PX4) if the vehicle was
    under guidance, STATUSTEXT the reason; after all conditions were healthy for 1 s of message
    time, re-engage (if COMP_ARM_ENABLE) and resume. A mode change the companion did not command
    (pilot, ground station, the autopilot's own failsafe) is respected: the mission pauses with a
    STATUSTEXT until GUIDED/OFFBOARD is selected again. Navigation failures (QP failure, estimate
    diverging from the geomagnetic fix by COMP_DIVERGE_KM, a non-finite command) hold the
    vehicle and restart the mission from the last estimate after a new stationary start-up
    (at most 3 restarts). No setpoint ever leaves without :func:`~companion.io.mavlink_link.guard_setpoint`.

Records (``--log-dir``, default ``out/companion/<time>-<pid>``): ``companion.tlog`` (both
directions), ``steps.csv`` (:mod:`companion.io.records`), ``summary.json``.

Sensor sources (``--sensors SPEC``, :func:`companion.io.sensors.make_source`)
    Without it the flight controller's MAVLink streams are the sensors. With it the source
    (``i2c:/dev/i2c-1``, ``dronecan:can0``, ``replay:log.bin?speed=1``, ``i2c:1+ubx:/dev/ttyS0``,
    ...) is opened at start (an error: exit code 2) and polled without waiting from the run loop;
    its samples take the same path as MAVLink's. The kinds it provides replace the flight
    controller's: its magnetometer makes the companion ignore RAW_IMU/SCALED_IMU/HIGHRES_IMU
    magnetometers (two magnetometers are never mixed), its attitude replaces ATTITUDE; a kind it
    lacks (DroneCAN: attitude) still comes from the flight controller, as do heartbeat, mode,
    arming and the INS position. Its GPS is start-up and record only.
    Time: a direct source stamps with the host monotonic clock, a replay with log time, the
    navigation runs on message time. A sample's time is mapped with an offset learned at
    reception, offset = message time now - source time of the newest sample of the batch, kept
    while it moves by less than SOURCE_RESYNC_S and learned again when it jumps (an FC reboot, a
    replay faster than message time). This assumes the transport latency on both paths is
    negligible against the 0.5 s attitude-matching window; the flight controller's message
    clock only advances in steps (its message rate), so the mapping jitters by up to one
    message interval. Before the first flight-controller time stamp samples are dropped
    (counted in the summary). A source that stops delivering (device gone, replay ended) goes
    stale like a silent MAVLink stream and triggers the same failsafe; a STATUSTEXT names the
    source once.
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import math  # noqa: E402
import signal  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from datetime import datetime  # noqa: E402
from pathlib import Path  # noqa: E402

from companion import wrap_2pi  # noqa: E402
from companion.cli import ArgumentParser, UsageError, one_line, run_main  # noqa: E402
from companion.failsafe import Health, HealthLimits, diverged  # noqa: E402
from companion.fc_view import FcView  # noqa: E402
from companion.io.mavlink_link import MavlinkLink, mavlink  # noqa: E402
from companion.io.param_server import ENCODINGS, ParamServer  # noqa: E402
from companion.io.records import StepRecorder, write_summary  # noqa: E402
from companion.io.sensors.base import SampleKind, SensorError, SensorSource, StreamEnd  # noqa: E402
from companion.io.sensors.factory import make_source  # noqa: E402
from companion.io.sensors.mavlink_source import MAG_MESSAGES, MavlinkDecoder  # noqa: E402
from companion.nav.geo import enu_offset, geodesic_distance_m, offset_position  # noqa: E402
from companion.nav.elements import ELEMENT_NAMES, ELEMENT_SETS, ElementSet  # noqa: E402
from companion.nav.magnetometer import AttitudeState, MagCalibration, MagProcessor  # noqa: E402
from companion.nav.field import model_for_date  # noqa: E402
from companion.nav.mission import FROZEN_IN_FLIGHT, WMM_NAMES, Command, Measurement, Mission, Phase  # noqa: E402
from companion.params import CompanionConfig, NavConfig  # noqa: E402

__all__ = ["AppOptions", "CompanionApp", "SourceTimeMap", "State", "build_parser", "main", "benchmark",
           "LIVE_FROZEN_FIELDS"]

MAX_RESTARTS = 3
_MAG, _ATT, _GPS = SampleKind.MAG, SampleKind.ATTITUDE, SampleKind.GPS
_PARAM_TYPES = frozenset({"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"})
FC_POSITION_MAX_AGE_S = 5.0       # older GLOBAL_POSITION_INT: dead reckoning instead
GPS_START_MAX_AGE_S = 5.0
COMMAND_RETRY_S = 2.0             # message time between retries of mode/arm commands
HOLD_RETRY_S = 2.0
STARTUP_GRACE_S = 5.0            # message time for the requested streams to arrive before complaining
LINGER_WALL_S = 0.5               # after done, before exiting: let the last messages go
ECHO_SIGMA_M = 50.0               # what the echo of the FC's own GPS-aided position is worth to the feed
SETTLE_AFTER_COMMAND_S = 60.0     # gravity-referenced I waits this long after a new course or speed
PREPARED_START_M = 100.0          # a mission built while READY serves a start this close
FEED_PERIOD_S = 0.1               # GPS_INPUT rate (message time)
ECHO_SATELLITES = 6               # fewer than a real receiver: the FC keeps its own GPS as primary
FEED_SATELLITES = 10
SOURCE_RESYNC_S = 1.0             # --sensors: re-learn the source-to-message-time offset beyond this jump
WAITING_REPEAT_WALL_S = 30.0      # repeat "waiting for a heartbeat" while no flight controller is heard

# NavConfig fields that define the mission: a change applies to the next mission only.
LIVE_FROZEN_FIELDS = FROZEN_IN_FLIGHT

# Streams requested from the flight controller (MAV_CMD_SET_MESSAGE_INTERVAL), Hz.
STREAMS_HZ = {"ATTITUDE": 10.0, "GLOBAL_POSITION_INT": 1.0, "GPS_RAW_INT": 1.0, "GPS2_RAW": 1.0, "SYSTEM_TIME": 1.0}
MAG_STREAM_HZ = 10.0


class State:
    WAIT_FC = "wait_fc"
    STARTUP = "startup"
    READY = "ready"
    RUNNING = "running"
    DONE = "done"


@dataclass
class AppOptions:
    connect: str = "udp:127.0.0.1:14550"
    params: str | None = None
    log_dir: str | None = None
    sysid: int | None = None
    lockstep: bool = False
    exit_when_done: bool = False
    param_encoding: str = "auto"
    mag_message: str | None = None
    startup_s: float | None = None
    tlog: bool = True
    request_streams: bool = True
    max_wall_s: float | None = None
    quiet: bool = False
    sensors: str | None = None
    linger_s: float = 0.0               # --exit-when-done: message time after the end before exiting


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, int(math.ceil(q * len(ordered))) - 1))
    return ordered[k]


# What each source class delivers (class name -> kinds); a CombinedSource is the union.
_SOURCE_KINDS = {
    "Mpu9250Source": frozenset({_MAG, _ATT}),
    "DroneCanMagSource": frozenset({_MAG}),
    "UbloxSource": frozenset({_GPS}),
    "LogReplaySource": frozenset({_MAG, _ATT, _GPS}),
}


def source_kinds(source: SensorSource) -> frozenset:
    """The sample kinds (MAG, ATTITUDE, GPS) ``source`` provides, which the FC's then do not."""
    subs = getattr(source, "sources", None)
    if subs is not None:
        return frozenset().union(*(source_kinds(s) for s in subs))
    kinds = getattr(source, "provides", None)
    return frozenset(kinds) if kinds is not None else _SOURCE_KINDS.get(type(source).__name__, frozenset({_MAG}))


class SourceTimeMap:
    """Source time -> message time: ``t_msg = t_source + offset``.

    ``offset`` = message time now - source time of the newest sample, learned on the first
    batch and again whenever that quantity moves by more than ``resync_s`` (a jump of either
    clock). Assumes negligible transport latency on both paths.

    >>> m = SourceTimeMap()
    >>> [round(t, 3) for t in m.map(100.0, [5000.0, 5000.1])]   # the newest sample is "now"
    [99.9, 100.0]
    >>> [round(t, 3) for t in m.map(100.25, [5000.3])]          # within 1 s: offset kept
    [100.2]
    >>> [round(t, 3) for t in m.map(250.0, [5000.4])]           # a jump: learned again
    [250.0]
    >>> m.resyncs
    2
    """

    def __init__(self, resync_s: float = SOURCE_RESYNC_S) -> None:
        self.resync_s = resync_s
        self.offset_s: float | None = None
        self.resyncs = 0

    def map(self, now_msg_s: float, source_times: list[float]) -> list[float]:
        finite = [t for t in source_times if math.isfinite(t)]
        if finite:
            candidate = now_msg_s - max(finite)
            if self.offset_s is None or abs(candidate - self.offset_s) > self.resync_s:
                self.offset_s = candidate
                self.resyncs += 1
        off = self.offset_s if self.offset_s is not None else math.nan
        return [t + off for t in source_times]


class CompanionApp:
    """The companion process; :meth:`run` until done (``--exit-when-done``), a signal or ``max_wall_s``."""

    def __init__(self, options: AppOptions) -> None:
        self.opts = options
        if options.log_dir:
            self.log_dir = Path(options.log_dir)
        else:
            self.log_dir = Path("out") / "companion" / f"{datetime.now():%Y%m%d-%H%M%S}-{os.getpid()}"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        params_path = options.params if options.params is not None else str(self.log_dir / "companion.parm")
        self.link = MavlinkLink(options.connect, options.sysid,
                                tlog_path=self.log_dir / "companion.tlog" if options.tlog else None)
        self.params = ParamServer(self.link, params_path, on_change=self._param_changed,
                                  encoding=options.param_encoding)
        self.params.load()
        self.nav_cfg = NavConfig.from_values(self.params.values)
        self.comp_cfg = CompanionConfig.from_values(self.params.values)
        model_for_date(self.nav_cfg.year, WMM_NAMES.get(self.nav_cfg.wmm))   # load the coefficients now, not at take-off
        self.decoder = MavlinkDecoder(self.link.clock, options.mag_message, imu=True)   # specific force: I_g
        # --sensors: a sensor source beside the link (built here so a bad spec fails early)
        self.sensors: SensorSource | None = make_source(options.sensors) if options.sensors else None
        self.source_kinds = source_kinds(self.sensors) if self.sensors is not None else frozenset()
        self.source_time = SourceTimeMap()
        self.source_open = False
        self.source_dropped_no_clock = 0
        self.source_last_rx = math.nan      # message time of the newest mapped source sample
        self.source_silent_said = False
        self.source_ended = ""
        self.source_problem: dict[str, str] = {}
        self.mag = MagProcessor(MagCalibration.from_mgauss(self.comp_cfg.mag_offset_mgauss, self.comp_cfg.mag_scale),
                                self.comp_cfg.spike_nt)
        self.last_valid: dict[SampleKind, float] = {}   # message time of the last valid sample per kind
        self.health = Health(self._limits())
        self.fc_view = FcView(self.comp_cfg.heading_source, self.comp_cfg.position_publish, self.comp_cfg.feed_blend_mps)
        self.next_feed_s = -math.inf
        self.elements_code = 0          # the element set of the running mission (resolved NAV_ELEMENTS)
        self.bias: tuple[float, float] | None = None
        if self.params.load_error:
            self.health.latch("params", f"broken parameter file, defaults served, will not steer: "
                                        f"{self.params.load_error}")
        self.recorder: StepRecorder | None = None
        # state
        self.state = State.WAIT_FC
        self.mission: Mission | None = None
        self.mission_no = 0
        self.restarts = 0
        self.restart_from: tuple[float, float] | None = None
        self.command: Command | None = None
        self.last_phase = ""
        self.exit_code: int | None = None
        self.done_wall = math.nan
        self.done_msg_s = math.nan        # message time the mission ended
        self._stop = False
        self._params_dirty = False
        # clocks and timers (message time unless *_wall)
        self.offset_s = 0.0             # message time - mission time (pauses)
        self.paused_since = math.nan
        self.m0 = math.nan              # mission time of the mission start
        self.next_step_m = math.nan
        self.startup_begin = math.nan
        self.fc_detected_at = math.nan
        self.stream_since = math.nan    # message time since setpoints stream without a gap
        self.next_tick = -math.inf
        self.last_hb_sent = -math.inf
        self.last_hb_sent_wall = -math.inf
        self.last_mode_cmd = -math.inf
        self.last_arm_cmd = -math.inf
        self.last_hold_cmd = -math.inf
        self.hold_commanded = False
        self.fc_failsafe_hold = ""      # the FC's own failsafe that took it out of GUIDED (re-engage when cleared)
        self._prepared: Mission | None = None   # built while READY, used at arming if nothing changed
        self.was_following = False
        self.failsafe_active = False
        self.last_gps = None
        self.local_ned: tuple[float, float, float] | None = None   # (time, north, east) of LOCAL_POSITION_NED
        self.dr: tuple[float, float, float] | None = None          # (time, lat, lon) dead reckoning
        self.last_tick_time = math.nan
        # statistics
        self.step_latency_s: list[float] = []
        self.core_latency_s: list[float] = []
        self.events: list[str] = []
        self.wall_start = time.monotonic()
        self._waiting_said_wall = self.wall_start
        self.messages_from_fc = 0
        self.invalid_mag = 0
        self.fc_reboots = 0

    # ------------------------------------------------------------------ configuration
    def _limits(self) -> HealthLimits:
        c = self.comp_cfg
        return HealthLimits(c.mag_timeout_s, c.att_timeout_s, c.heartbeat_timeout_s)

    def _param_changed(self, name: str, value) -> None:
        self._params_dirty = True
        if self.state != State.RUNNING:
            self._apply_params()

    def _apply_params(self) -> None:
        """Rebuild the configurations from the parameter values (at a control step when running)."""
        self._params_dirty = False
        values = self.params.values
        self.comp_cfg = CompanionConfig.from_values(values)
        self.mag.configure(MagCalibration.from_mgauss(self.comp_cfg.mag_offset_mgauss, self.comp_cfg.mag_scale),
                           self.comp_cfg.spike_nt)
        self.health.limits = self._limits()
        self.fc_view.position_publish = self.comp_cfg.position_publish
        self.fc_view.feed.blend_mps = self.comp_cfg.feed_blend_mps
        new_nav = NavConfig.from_values(values)
        self.nav_cfg = new_nav
        if self.mission is not None and self.state == State.RUNNING:
            deferred = apply_live_config(self.mission, new_nav)
            for name in deferred:
                self._say(f"FcMPC: {name} applies to the next mission", mavlink.MAV_SEVERITY_NOTICE)

    # ------------------------------------------------------------------ time
    @property
    def now(self) -> float:
        return self.link.clock.now_s

    def mission_time(self, now: float | None = None) -> float:
        now = self.now if now is None else now
        if math.isfinite(self.paused_since):
            return self.paused_since - self.offset_s
        return now - self.offset_s

    # ------------------------------------------------------------------ output helpers
    def _stamp(self) -> str:
        """``[message time]``, or ``[no FC time]`` before the first time-stamped message."""
        return f"[{self.now:10.1f}]" if math.isfinite(self.now) else "[no FC time]"

    def _say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.events.append(f"{self._stamp()} {text}")
        if not self.opts.quiet:
            print(f"fcmpc-companion {self._stamp()} {text}", file=sys.stderr, flush=True)
        if self.link.conn is not None:
            self.link.send_statustext(text, severity)

    def _send_heartbeat(self) -> None:
        state = mavlink.MAV_STATE_CRITICAL if self.failsafe_active else (
            mavlink.MAV_STATE_ACTIVE if self.state == State.RUNNING else mavlink.MAV_STATE_STANDBY)
        self.link.send_heartbeat(state)
        self.last_hb_sent = self.now if self.link.clock.started else -math.inf
        self.last_hb_sent_wall = time.monotonic()

    # ------------------------------------------------------------------ main loop
    def open(self) -> None:
        if self.sensors is not None and not self.source_open:
            self.sensors.open()          # SensorError: main() exits with 2 before anything else opens
            self.source_open = True
        try:
            with contextlib.redirect_stdout(io.StringIO()):   # pymavlink prints its TCP retries
                self.link.open()
        except OSError as err:
            self._close_sensors()
            raise ConnectionError(f"cannot connect to {self.opts.connect}: {err.strerror or err}") from err
        except BaseException:
            self._close_sensors()
            raise
        self.recorder = StepRecorder(self.log_dir / "steps.csv")
        self._send_heartbeat()   # a udpout link must speak first
        self._waiting_said_wall = time.monotonic()
        if not self.opts.quiet:
            print(f"fcmpc-companion: waiting for a heartbeat on {self.opts.connect}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.link.conn is not None and self.link.fc.detected and self.link.fc.guided and self.link.fc.armed \
                and self.state in (State.RUNNING, State.READY):
            self.link.send_hold_mode()   # do not leave a vehicle in GUIDED without a companion
        if self.recorder is not None:
            self.recorder.close()
        self._write_summary()
        self.link.close()
        self._close_sensors()

    def _close_sensors(self) -> None:
        if self.sensors is not None and self.source_open:
            self.source_open = False
            try:
                self.sensors.close()
            except (OSError, SensorError) as err:  # pragma: no cover - the device is gone anyway
                print(f"fcmpc-companion: closing {self.sensors.name}: {err}", file=sys.stderr)

    def request_stop(self) -> None:
        self._stop = True

    def run(self) -> int:
        self.open()
        try:
            while not self._stop and self.exit_code is None:
                if self.link.wait_readable(0.02):
                    for _ in range(256):
                        msgs = self.link.read()
                        if not msgs:
                            break
                        for msg in msgs:
                            self.handle(msg)
                if self.sensors is not None:
                    self.poll_sensors()
                self.idle()
        finally:
            self.close()
        return self.exit_code if self.exit_code is not None else 0

    def handle(self, msg) -> None:
        """Receive hook: every message read from the link."""
        link = self.link
        if link.observe(msg):
            self.messages_from_fc += 1
            self.fc_view.packet(msg, link.clock.now_s)
            if link.clock.reboots != self.fc_reboots:
                self._on_fc_reboot()
            was_detected = self.state != State.WAIT_FC
            own = self.source_kinds
            for sample in self.decoder.decode(msg):
                if sample.kind not in own:   # a kind --sensors provides: the FC's is ignored
                    self._use_sample(sample, sample.time_s, self.decoder.rates)
            if msg._type == "LOCAL_POSITION_NED":
                self.local_ned = (msg.time_boot_ms * 1e-3, msg.x, msg.y)
            if self.link.clock.now_s >= self.next_tick or not was_detected:
                if self.link.clock.started:
                    self.tick()
            if self.link.clock.now_s >= self.next_feed_s and self.state != State.WAIT_FC:
                # 10 Hz: ArduPilot calls a GPS unhealthy when its updates average over 245 ms apart
                self.next_feed_s = self.link.clock.now_s + FEED_PERIOD_S
                self._feed_position(self.link.clock.now_s)
        elif msg._type in _PARAM_TYPES:
            self.params.mavlink_packet(msg)

    def _use_sample(self, sample, t: float, rates: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """One sample (MAVLink or --sensors) at message time ``t`` into the magnetometer pipeline."""
        kind = sample.kind
        if kind is _MAG:
            if sample.flags:
                self.invalid_mag += 1
            else:
                self.last_valid[_MAG] = t
                self.mag.add_mag(t, sample.mag_body_nt)
        elif kind is _ATT:
            if not sample.flags:
                att = AttitudeState.from_body_rates(t, sample.roll_rad, sample.pitch_rad, sample.yaw_rad, *rates)
                if self.mag.add_attitude(att):
                    self.last_valid[_ATT] = t
        elif kind is _GPS:
            self.last_gps = sample if t == sample.time_s else replace(sample, time_s=t)
        elif kind is SampleKind.IMU and not sample.flags:
            self.mag.add_specific_force(t, sample.accel_body_mps2, sample.gyro_body_radps)

    def poll_sensors(self) -> None:
        """Periodic hook for ``--sensors``: take what the source has now (never waits)."""
        source = self.sensors
        if source is None or not self.source_open:
            return
        try:
            samples = source.poll(0.0)
        except SensorError as err:   # sources count errors instead of raising; be safe anyway
            samples = []
            self.source_problem["mag"] = str(err)
        if samples:
            if not self.link.clock.started:   # no message time to put them on yet
                self.source_dropped_no_clock += len(samples)
                return
            times = self.source_time.map(self.now, [s.time_s for s in samples])
            rates = (0.0, 0.0, 0.0)
            fresh = False
            for sample, t in zip(samples, times):
                if isinstance(sample, StreamEnd):
                    self.source_ended = sample.detail or "end of stream"
                    continue
                if sample.kind is SampleKind.IMU:
                    rates = sample.gyro_body_radps
                    continue
                if sample.kind not in self.source_kinds:
                    continue
                if sample.flags and sample.kind is _MAG:
                    self.source_problem["mag"] = f"{source.name}: flagged {sample.flags!r}"
                self._use_sample(sample, t, rates)
                if not sample.flags:
                    fresh = True
                    self.source_last_rx = t   # batch order is time order; after an FC reboot, the new base
            if fresh and self.source_silent_said and not self.source_ended:
                self.source_silent_said = False
                self.source_problem.pop("mag", None)
                self._say(f"FcMPC: sensor source {source.name} delivering again", mavlink.MAV_SEVERITY_NOTICE)
        self._check_source_silence()

    def _check_source_silence(self) -> None:
        """Say once that the source stopped (ended, or nothing for longer than the staleness timeout)."""
        if self.source_silent_said or not self.link.clock.started:
            return
        source = self.sensors
        why = ""
        if self.source_ended or source.finished:
            why = f"ended ({self.source_ended or 'finished'})"
        else:
            timeout = min(self.comp_cfg.mag_timeout_s, self.comp_cfg.att_timeout_s) \
                if _ATT in self.source_kinds else self.comp_cfg.mag_timeout_s
            since = self.source_last_rx if math.isfinite(self.source_last_rx) else self.fc_detected_at
            if math.isfinite(since) and self.now - since > timeout:
                err = source.stats.last_error
                why = f"silent for {self.now - since:.1f} s" + (f" (last error: {err})" if err else "")
        if why:
            self.source_silent_said = True
            self.source_problem["mag"] = f"sensor source {source.name} {why}"
            self._say(f"FcMPC: sensor source {source.name} {why}"[:200], mavlink.MAV_SEVERITY_CRITICAL)

    def _on_fc_reboot(self) -> None:
        """The flight controller's clock went back: everything timed is void; start again."""
        self.fc_reboots = self.link.clock.reboots
        self.next_tick = -math.inf
        self.last_hb_sent = -math.inf
        self.last_valid.clear()
        self.last_mode_cmd = self.last_arm_cmd = self.last_hold_cmd = -math.inf
        self.link.fc.last_heartbeat_time_s = self.now
        self.mag.attitude = None
        self.decoder.fc_position = None
        self.dr = None
        self.fc_view.feed.stop()
        self.fc_view.feeding_own = False
        reason = "flight controller rebooted (its clock went back)"
        if self.state == State.RUNNING and self.command is not None:
            self._nav_failure(reason, self.command)
        elif self.state in (State.STARTUP, State.READY, State.RUNNING):
            self._say(f"FcMPC: {reason}", mavlink.MAV_SEVERITY_WARNING)
            self.mission = None
            self._enter_startup(reason)

    def age(self, kind: SampleKind) -> float:
        """Message-time age of the last valid sample of a kind (infinite if none yet)."""
        last = self.last_valid.get(kind)
        return math.inf if last is None else self.now - last

    def idle(self) -> None:
        """Periodic hook in wall time: heartbeat floor, silent flight controller, exit conditions."""
        wall = time.monotonic()
        if wall - self.last_hb_sent_wall >= 1.0:
            self._send_heartbeat()
            if self.state == State.WAIT_FC and wall - self._waiting_said_wall >= WAITING_REPEAT_WALL_S:
                self._waiting_said_wall = wall
                if not self.opts.quiet:
                    print(f"fcmpc-companion: still waiting for a heartbeat on {self.opts.connect} "
                          f"({wall - self.wall_start:.0f} s)", file=sys.stderr, flush=True)
            if self.link.fc.detected and self.link.clock.started:
                self._evaluate_health()   # a silent FC: message time stands still, wall time does not
                if self.failsafe_active and self.state == State.RUNNING:
                    self._failsafe_actions()
        if self.state == State.DONE and self.opts.exit_when_done and wall - self.done_wall >= LINGER_WALL_S \
                and self._lingered():
            self.exit_code = 0 if self.command is not None and self.command.phase == Phase.ARRIVED else 1
        if self.opts.max_wall_s is not None and wall - self.wall_start > self.opts.max_wall_s:
            self._say(f"FcMPC: wall-time limit {self.opts.max_wall_s:g} s reached, exiting",
                      mavlink.MAV_SEVERITY_WARNING)
            self.exit_code = 3

    # ------------------------------------------------------------------ the control tick
    def tick(self) -> None:
        """Runs at COMP_SP_RATE_HZ of message time (and when the flight controller appears)."""
        now = self.now
        period = 1.0 / self.comp_cfg.setpoint_rate_hz
        self.next_tick = now + period if now - self.next_tick >= period else self.next_tick + period
        if now - self.last_hb_sent >= 1.0:
            self._send_heartbeat()
        dt = now - self.last_tick_time if math.isfinite(self.last_tick_time) else 0.0
        self.last_tick_time = now
        if self.state == State.WAIT_FC:
            self._on_fc_detected()
        self.fc_view.poll_requests(self.link, now)
        reasons = self._evaluate_health()
        sent = False
        if self.state == State.STARTUP:
            self._startup(now, reasons)
        if self.state == State.READY:
            sent = self._ready(now, reasons)
        if self.state == State.RUNNING:
            sent = self._running(now, reasons, dt)
        if self.state == State.DONE:
            self._hold_if_guided(now)
        if not sent:
            self.stream_since = math.nan
            if self.opts.lockstep:   # a timed message each period keeps a lockstep simulator going
                self.link.send_named_float("FC_STATE", float(self._state_code()))

    def _state_code(self) -> int:
        codes = {State.WAIT_FC: 0, State.STARTUP: 1, State.READY: 2, State.RUNNING: 3, State.DONE: 5}
        return 4 if self.failsafe_active else codes[self.state]

    def _on_fc_detected(self) -> None:
        fc = self.link.fc
        self.fc_detected_at = self.now
        self._say(f"FcMPC: {fc.conventions.name} FC sysid {fc.sysid} detected, mode {fc.mode_name}")
        self.fc_view.start(fc.conventions.family, fc.conventions.param_bytewise, self.now)
        if self.opts.request_streams:
            self._request_streams()
        self._enter_startup("start-up")

    def _request_streams(self) -> None:
        link = self.link
        mag_msg = self.opts.mag_message or ("HIGHRES_IMU" if link.fc.conventions.param_bytewise else "RAW_IMU")
        link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{mag_msg}"), MAG_STREAM_HZ)
        for name, hz in STREAMS_HZ.items():
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), hz)
        if self.comp_cfg.position_publish == 1:
            link.send_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 2.0)

    # ------------------------------------------------------------------ health
    def _evaluate_health(self) -> list[str]:
        now = self.now
        hb_msg, hb_wall = self.link.heartbeat_age_s()
        problems = self.decoder.last_problem
        if self.source_kinds:
            problems = {k: v for k, v in problems.items()
                        if not (k == "mag" and _MAG in self.source_kinds)
                        and not (k == "attitude" and _ATT in self.source_kinds)}
            problems.update(self.source_problem)
        reasons = self.health.evaluate(
            now, mag_age_s=self.age(_MAG), att_age_s=self.age(_ATT),
            hb_age_msg_s=hb_msg, hb_age_wall_s=hb_wall, mag_detail=problems.get("mag", ""),
            att_detail=problems.get("attitude", ""))
        if self.state in (State.WAIT_FC, State.STARTUP) and not self.link.fc.armed:
            # before engaging there is nothing to stop: report (after the streams had time to
            # start), but do not command anything
            if reasons and not self.failsafe_active and now - self.fc_detected_at > STARTUP_GRACE_S:
                self._say(f"FcMPC: not ready: {reasons[0]}", mavlink.MAV_SEVERITY_WARNING)
            if now - self.fc_detected_at > STARTUP_GRACE_S or not reasons:
                self.failsafe_active = bool(reasons)
            return reasons
        if reasons and not self.failsafe_active:
            self.failsafe_active = True
            self._say(f"FcMPC FAILSAFE: {'; '.join(reasons)}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
            self._record_event("failsafe", "; ".join(reasons))
            self._failsafe_actions()
        elif not reasons and self.failsafe_active and self.health.resumed(now):
            self.failsafe_active = False
            self._say("FcMPC: healthy again, resuming", mavlink.MAV_SEVERITY_NOTICE)
        return reasons if reasons or not self.failsafe_active else ["recovering"]

    def _failsafe_actions(self) -> None:
        if self.state == State.RUNNING:
            self._pause()
        fc = self.link.fc
        if fc.armed and fc.guided:
            self._command_hold(self.now)

    def _command_hold(self, now: float) -> None:
        if now - self.last_hold_cmd >= HOLD_RETRY_S or not math.isfinite(self.last_hold_cmd):
            self.link.send_hold_mode()
            self.last_hold_cmd = now
            self.hold_commanded = True

    def _hold_if_guided(self, now: float) -> None:
        fc = self.link.fc
        if fc.armed and fc.guided:
            self._command_hold(now)

    # ------------------------------------------------------------------ states
    def _enter_startup(self, why: str) -> None:
        self.state = State.STARTUP
        self.startup_begin = self.now
        self.mag.paused = False
        self.mag.mission_offset_s = self.offset_s = 0.0
        self.paused_since = math.nan
        self.mag.clear()
        self._record_event("start" if why == "start-up" else "restart", why)

    def _startup_window(self) -> float:
        return self.opts.startup_s if self.opts.startup_s is not None else self.nav_cfg.period_s

    def _moving(self) -> bool:
        """The vehicle may be moving: armed and not in a hold mode (a pilot or a mission drives it).

        The flight controller's velocity is no evidence: without GPS its INS velocity drifts."""
        fc = self.link.fc
        return fc.armed and not fc.holding and not (fc.guided and self.comp_cfg.arm_enable)

    def _startup(self, now: float, reasons: list[str]) -> None:
        if reasons or self._moving():
            self.startup_begin = now
            self.mag.clear()
            return
        if now - self.startup_begin >= self._startup_window() and len(self.mag.averager):
            if self.fc_view.heading_verdict(now) is None:
                return   # still reading the FC's heading parameters: keep averaging
            self.state = State.READY
            self._say(f"FcMPC: ready, start-up average of {len(self.mag.averager)} samples"
                      + ("" if self.comp_cfg.arm_enable else "; arm in GUIDED/OFFBOARD to start"))

    def _zero_setpoint(self) -> bool:
        att = self.mag.attitude
        course = wrap_2pi(att.yaw_rad) if att is not None else 0.0
        return self._stream(course, 0.0)

    def _stream(self, course_rad: float, speed_mps: float) -> bool:
        limit = self.mission.config.speed_mps if self.mission is not None else self.nav_cfg.speed_mps
        ok = self.link.send_setpoint(course_rad, speed_mps, limit)
        if ok and not math.isfinite(self.stream_since):
            self.stream_since = self.now
        return ok

    def _engage(self, now: float) -> None:
        """GUIDED/OFFBOARD then arm, with retries (only with COMP_ARM_ENABLE = 1)."""
        fc = self.link.fc
        if not self.comp_cfg.arm_enable:
            return
        conv = fc.conventions
        streamed = now - self.stream_since if math.isfinite(self.stream_since) else 0.0
        if not fc.guided:
            if streamed >= conv.offboard_prestream_s and now - self.last_mode_cmd >= COMMAND_RETRY_S:
                self.link.send_guided_mode()
                self.last_mode_cmd = now
        elif not fc.armed:
            self._arm_with_backoff(now)

    def _arm_with_backoff(self, now: float) -> None:
        """Arm; a refusal (COMMAND_ACK) is said once with the FC's reason, and the retry backs off."""
        fc, backoff = self.link.fc, self.fc_view.arming
        arm = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        result = fc.acks.pop(arm, None)
        if result is not None and result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            wait = backoff.refused(self.fc_view.prearm_text)
            self._say(f"FcMPC: arming refused by the FC ({backoff.last_reason or f'result {result}'}); "
                      f"retry in {wait:g} s"[:200], mavlink.MAV_SEVERITY_WARNING)
        if now - self.last_arm_cmd >= backoff.interval_s:
            self.fc_view.prearm_text = ""
            self.link.send_arm(True)
            self.last_arm_cmd = now

    def _feed_position(self, now: float) -> None:
        """GPS_INPUT at the tick rate (COMP_POS_PUB 3), see :mod:`companion.fc_view`.

        While the FC's own GPS has a fix, the feed echoes the FC's GPS-aided position, claiming
        fewer satellites than a real receiver, so the FC keeps its own GPS as primary and its
        arming checks see a healthy second GPS. Once its GPS is lost, the feed flies on from the
        last echo with the commanded velocity and blends towards the navigator's estimate.
        """
        view, feed = self.fc_view, self.fc_view.feed
        if not view.feed_wanted() or self.state == State.WAIT_FC:
            feed.stop()
            return
        pos = self.decoder.fc_position
        fresh = pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S
        if view.gps_has_fix(now):
            if fresh:
                feed.start(now, pos.lat_deg, pos.lon_deg, ECHO_SIGMA_M)
                if view.feeding_own:
                    self._say("FcMPC: FC has GPS again: position feed echoes it", mavlink.MAV_SEVERITY_NOTICE)
                view.feeding_own = False
                self.link.send_gps_input(pos.lat_deg, pos.lon_deg, self.comp_cfg.feed_accuracy_m,
                                         satellites=ECHO_SATELLITES)
            return
        if not view.gps_seen and self.now - self.fc_detected_at < STARTUP_GRACE_S:
            return   # no GPS_RAW_INT yet: do not take a slow stream for a lost GPS
        estimate = self._current_estimate()
        if not feed.started:
            if estimate is None:
                return
            feed.start(now, estimate[0], estimate[1], self._feed_sigma())
        if not view.feeding_own:
            view.feeding_own = True
            if estimate is not None:
                feed.correct_to(now, estimate[0], estimate[1], self._feed_sigma())
            self._say("FcMPC: FC has no GPS: feeding our position (GPS_INPUT)", mavlink.MAV_SEVERITY_NOTICE)
        following = self.state == State.RUNNING and not self.failsafe_active and not math.isfinite(self.paused_since)
        cmd = self.command if following else None
        vn, ve = (cmd.speed_mps * math.cos(cmd.course_rad), cmd.speed_mps * math.sin(cmd.course_rad)) \
            if cmd is not None and not cmd.done else (0.0, 0.0)
        if (vn, ve) != feed.velocity_ne:
            feed.set_velocity(now, vn, ve)
        sample = feed.sample(now)
        if sample is not None:
            self.link.send_gps_input(sample.lat_deg, sample.lon_deg, self.comp_cfg.feed_accuracy_m,
                                     satellites=FEED_SATELLITES)

    def _current_estimate(self) -> tuple[float, float] | None:
        """The navigator's latest position: the mission's estimate, else the start it would use."""
        cmd = self.command
        if cmd is not None and math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg):
            # flown on with the command since its step (mission time stops while paused)
            dt = max(self.mission_time() - self.m0 - cmd.time_s, 0.0) if not cmd.done else 0.0
            lat, lon = offset_position(cmd.est_lat_deg, cmd.est_lon_deg, cmd.speed_mps * math.sin(cmd.course_rad) * dt,
                                       cmd.speed_mps * math.cos(cmd.course_rad) * dt)
            return float(lat), float(lon)
        lat, lon, _ = self._start_position()
        return (lat, lon) if math.isfinite(lat) and math.isfinite(lon) else None

    def _feed_sigma(self) -> float:
        cmd = self.command
        if cmd is not None and math.isfinite(cmd.est_sigma_m):
            return cmd.est_sigma_m
        return math.sqrt(self.nav_cfg.fusion_rc_m2)

    def _ready(self, now: float, reasons: list[str]) -> bool:
        self.mag.drop_before(now - self._startup_window())   # a sliding window while waiting
        if reasons:
            return False
        fc = self.link.fc
        if fc.armed and fc.guided:
            sent = self._zero_setpoint()   # no gap: the FC stops after 3 s without a setpoint
            self._start_mission(now)
            return sent
        sent = self._zero_setpoint()
        self._prepare_mission(now)
        self._engage(now)
        return sent

    def _start_position(self) -> tuple[float, float, str]:
        gps = self.last_gps
        if gps is not None and gps.valid and gps.has_3d_fix and self.now - gps.time_s <= GPS_START_MAX_AGE_S:
            return gps.lat_deg, gps.lon_deg, "GPS"
        if self.restart_from is not None:
            return self.restart_from[0], self.restart_from[1], "last estimate"
        return self.nav_cfg.start_lat_deg, self.nav_cfg.start_lon_deg, "NAV_START"

    def _start_mission(self, now: float) -> None:
        if self._params_dirty:
            self._apply_params()
        lat, lon, source = self._start_position()
        self.elements_code, why = self._resolve_elements(now)
        config = self.nav_cfg.replace(start_lat_deg=float(lat), start_lon_deg=float(lon), elements=self.elements_code)
        self.m0 = self.mission_time(now)
        startup = self.mag.take(self.m0)
        self.bias, calibration = self._calibration(config, startup, source)
        self.mission = self._prepared if self._prepared_fits(config) else Mission(config)
        self.mission.set_bias(self.bias)
        # the error-state filter starts from the known start (a GPS fix, or the declared NAV_START
        # the mission is planned from) and observes the biases itself only at a GPS-known start
        self.mission.set_start_fix(config.gps_sigma_m if source in ("GPS", "NAV_START") else None,
                                   calibrate=source == "GPS")
        self._prepared = None
        self.mission_no += 1
        self.hold_commanded = False
        self.was_following = True
        self.state = State.RUNNING
        self.last_phase = ""
        self._say(f"FcMPC: mission {self.mission_no} start {lat:.4f},{lon:.4f} ({source})")
        self._say(f"FcMPC: elements {ELEMENT_SETS[self.elements_code].label}: {why}"[:200])
        if calibration:
            self._say(f"FcMPC: {calibration}"[:200])
        self._step(self.m0, window_limit_s=0.0, avg=startup)
        estimator = getattr(self.mission, "estimator", None)
        if estimator is not None and estimator.reason:
            self._say(f"FcMPC: position filter: {estimator.reason}"[:200])

    def _prepare_mission(self, now: float) -> None:
        """Build the mission (QP set-up, field model) while waiting to be armed, so the moment of
        arming costs a setpoint tick, not a set-up: at SITL speed-ups 100 ms of set-up was 3 s
        of firmware time without a setpoint, and ArduPilot stopped."""
        if self._params_dirty:
            return
        lat, lon, _ = self._start_position()
        code, _ = self._resolve_elements(now)
        config = self.nav_cfg.replace(start_lat_deg=float(lat), start_lon_deg=float(lon), elements=code)
        if not self._prepared_fits(config):
            self._prepared = Mission(config)

    def _prepared_fits(self, config: NavConfig) -> bool:
        """The prepared mission serves ``config``: the same settings, a start within PREPARED_START_M
        (a drifting boat moves its GPS start every tick; rebuilding each tick starved the link)."""
        prepared = self._prepared
        if prepared is None:
            return False
        old = prepared.config
        same = old.replace(start_lat_deg=config.start_lat_deg, start_lon_deg=config.start_lon_deg) == config
        return same and geodesic_distance_m(old.start_lat_deg, old.start_lon_deg, config.start_lat_deg,
                                            config.start_lon_deg) <= PREPARED_START_M

    def _resolve_elements(self, now: float) -> tuple[int, str]:
        """NAV_ELEMENTS resolved against the heading source: never D with a compass-derived yaw."""
        verdict = self.fc_view.heading_verdict(now)
        requested = self.nav_cfg.elements
        if verdict is None or verdict.compass_derived:
            reason = verdict.reason if verdict is not None else "heading source unknown"
            if requested in (ElementSet.PAPER, ElementSet.WEIGHTED):
                return ElementSet.HEADING_FREE, (f"NAV_ELEMENTS {requested} asks for D, but the FC yaw is "
                                                 f"compass-derived ({reason}): D is no measurement")
            if requested == ElementSet.HORIZONTAL_VERTICAL:
                return requested, f"NAV_ELEMENTS 3, FC yaw compass-derived ({reason})"
            return ElementSet.HEADING_FREE, f"FC yaw is compass-derived ({reason})"
        if requested == 0:
            return ElementSet.PAPER, f"heading independent of the compass ({verdict.reason})"
        return requested, f"NAV_ELEMENTS {requested} ({verdict.reason})"

    def _inclination(self, avg) -> float:
        """I of an average: gravity-referenced (field and accelerometer only) for the heading-free
        elements, so neither a heading nor the FC's attitude estimate enters; else tilt-compensated."""
        heading_free = self.elements_code in (ElementSet.HEADING_FREE, ElementSet.HORIZONTAL_VERTICAL)
        if heading_free and math.isfinite(avg.incl_grav_deg):
            return avg.incl_grav_deg
        return avg.incl_deg

    def _calibration(self, config: NavConfig, startup, source: str) -> tuple[tuple[float, float] | None, str]:
        """Start-up bias = measured minus model at a GPS-known start (NAV_CALIBRATE 1), and its words."""
        if not (config.calibrate and source == "GPS" and startup.valid and math.isfinite(startup.f_nt)):
            return None, "" if not config.calibrate else f"not calibrated (start from {source})"
        elements = ELEMENT_SETS[config.elements]
        model = model_for_date(config.year, WMM_NAMES.get(config.wmm))
        expected = elements.values(model.elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year))
        measured = elements.values(replace(startup, incl_deg=self._inclination(startup)))
        bias = elements.difference(measured, expected)
        units = ["nT" if n == "f_nt" else "deg" for n in elements.names]
        words = ", ".join(f"{ELEMENT_NAMES[n]} {b:+.3f} {u}" if u == "deg" else f"{ELEMENT_NAMES[n]} {b:+.0f} {u}"
                          for n, b, u in zip(elements.names, bias, units))
        return tuple(float(b) for b in bias), f"calibrated at the GPS start: measured - model = {words}"

    def _running(self, now: float, reasons: list[str], dt: float) -> bool:
        fc = self.link.fc
        following = fc.armed and fc.guided
        if self.was_following and not following and not self.hold_commanded:
            # a mode change we did not ask for: the autopilot's own failsafe is waited out and the
            # mission re-engages when it clears; a pilot's or ground station's is respected, and
            # the mission waits until GUIDED/OFFBOARD is selected again
            conv = fc.conventions
            guided = conv.mode_name(conv.custom_mode(conv.guided_main, conv.guided_sub))
            self.fc_failsafe_hold = self.fc_view.fc_failsafe
            why = f"its own failsafe ({self.fc_failsafe_hold}): re-engaging when it clears" \
                if self.fc_failsafe_hold else "mission paused"
            self._say(f"FcMPC: FC left {guided} (now {fc.mode_name}{'' if fc.armed else ', disarmed'}): {why}"[:200],
                      mavlink.MAV_SEVERITY_WARNING)
        if following:
            self.fc_failsafe_hold = ""
        self.was_following = following
        self._advance_dead_reckoning(now, dt, following and not reasons)
        if reasons or not following:
            self._pause()
        else:
            self._resume()
        if reasons:
            return False
        sent = self._stream(self.command.course_rad, self.command.speed_mps) if self.command is not None else False
        if not following:
            if self.hold_commanded or (self.fc_failsafe_hold and not self.fc_view.fc_failsafe):
                self._engage(now)   # our failsafe's hold, or the FC's own failsafe cleared: take it back
            return sent
        if self.mission_time(now) >= self.next_step_m:
            self._step(self.next_step_m)
        return sent

    def _pause(self) -> None:
        if not math.isfinite(self.paused_since):
            self.paused_since = self.now
            self.mag.paused = True

    def _resume(self) -> None:
        self.hold_commanded = False   # following and healthy: later mode changes are the pilot's
        if math.isfinite(self.paused_since):
            self.offset_s += self.now - self.paused_since
            self.paused_since = math.nan
            self.mag.mission_offset_s = self.offset_s
            self.mag.paused = False

    # ------------------------------------------------------------------ INS position
    def _advance_dead_reckoning(self, now: float, dt: float, moving: bool) -> None:
        pos = self.decoder.fc_position
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            self.dr = (now, pos.lat_deg, pos.lon_deg)
            return
        if self.dr is None:
            return
        if moving and self.command is not None and dt > 0.0:
            c, v = self.command.course_rad, self.command.speed_mps
            lat, lon = offset_position(self.dr[1], self.dr[2], v * math.sin(c) * dt, v * math.cos(c) * dt)
            self.dr = (now, float(lat), float(lon))

    def _ins_position(self, now: float) -> tuple[float, float, str]:
        independent, why = self.fc_view.position_independent(now)
        if not independent:   # GPS-aided or our own estimate: never an INS to fuse with
            return math.nan, math.nan, f"none: FC position {why}"
        pos = self.decoder.fc_position
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            return pos.lat_deg, pos.lon_deg, "fc"
        if self.dr is not None:
            return self.dr[1], self.dr[2], "dead_reckoning"
        return math.nan, math.nan, "none"

    # ------------------------------------------------------------------ the control step
    def _step(self, t_k: float, window_limit_s: float | None = None, avg=None) -> None:
        wall0 = time.perf_counter()
        now = self.now
        if self._params_dirty:
            self._apply_params()
        mission = self.mission
        period = mission.config.period_s
        if avg is None:
            avg = self.mag.take(t_k)
        if not avg.valid:
            # nothing to measure (should not happen: a silent magnetometer pauses the mission);
            # keep flying the command and measure again one period later (the core's dead
            # reckoning uses the actual time between steps)
            self.next_step_m = t_k + period
            self._say("FcMPC: no magnetometer samples in the period, step postponed", mavlink.MAV_SEVERITY_WARNING)
            return
        window = avg.window_s(t_k, period if window_limit_s is None else window_limit_s)
        ins_lat, ins_lon, ins_source = self._ins_position(now)
        incl = self._inclination(avg)
        # H and Z from F and the (gravity-referenced) I: no heading enters either
        h_nt, z_nt = avg.f_nt * math.cos(math.radians(incl)), avg.f_nt * math.sin(math.radians(incl))
        meas = Measurement(t_k - self.m0, avg.decl_deg, incl, ins_lat, ins_lon, window, avg.f_nt, h_nt, z_nt)
        core0 = time.perf_counter()
        cmd = mission.step(meas)
        core_latency = time.perf_counter() - core0
        nav_fault = ""
        if not cmd.done and not (math.isfinite(cmd.course_rad) and math.isfinite(cmd.speed_mps)):
            nav_fault = "non-finite command from the navigation core"
        elif not cmd.solver_ok:
            nav_fault = f"solver failure: {cmd.reason}"
        else:
            gap = geodesic_distance_m(cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg, cmd.fix_lon_deg) \
                if all(math.isfinite(v) for v in (cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg,
                                                  cmd.fix_lon_deg)) else math.nan
            if diverged(gap, self.comp_cfg.diverge_m):
                nav_fault = f"estimate diverged: {gap / 1000.0:.1f} km from the geomagnetic fix"
        self._publish(cmd, avg)
        if self.fc_view.feeding_own and cmd.phase == Phase.CRUISE:
            self.fc_view.feed.correct_to(now, cmd.est_lat_deg, cmd.est_lon_deg, self._feed_sigma())
        latency = time.perf_counter() - wall0
        self.step_latency_s.append(latency)
        self.core_latency_s.append(core_latency)
        self._record_step(cmd, meas, avg, ins_source, latency, "step", nav_fault or cmd.reason)
        if nav_fault:
            self._nav_failure(nav_fault, cmd)
            return
        previous = self.command
        if previous is None or abs(previous.course_rad - cmd.course_rad) > 0.02 or previous.speed_mps != cmd.speed_mps:
            self.mag.settle_until_s = now + SETTLE_AFTER_COMMAND_S   # turn and speed transient: no I_g
        self.command = cmd
        if cmd.phase != self.last_phase:
            self._say(f"FcMPC: step {cmd.step} phase {cmd.phase}"
                      + (f", {cmd.remaining_m / 1000.0:.1f} km to go" if math.isfinite(cmd.remaining_m) else "")
                      + (f": {cmd.reason}" if cmd.reason else ""),
                      mavlink.MAV_SEVERITY_NOTICE if cmd.phase != Phase.FAILED else mavlink.MAV_SEVERITY_ERROR)
            self.last_phase = cmd.phase
        if cmd.done:
            self._finish(cmd)
            return
        self.next_step_m = t_k + mission.config.period_s

    def _publish(self, cmd: Command, avg) -> None:
        link = self.link
        for name, value in (("FC_D", avg.decl_deg), ("FC_I", avg.incl_deg), ("FC_F", avg.f_nt), ("FC_ERR", cmd.est_sigma_m),
                            ("FC_REM", cmd.remaining_m), ("FC_SOLV", cmd.solver_time_s), ("FC_STEP", cmd.step)):
            if math.isfinite(value):
                link.send_named_float(name, value)
        if cmd.phase != Phase.CRUISE or not (math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg)):
            return
        sigma = cmd.est_sigma_m if math.isfinite(cmd.est_sigma_m) else math.sqrt(self.nav_cfg.fusion_rc_m2)
        mode = self.comp_cfg.position_publish
        if mode == 0:
            link.send_external_position(cmd.est_lat_deg, cmd.est_lon_deg, sigma)
        elif mode == 1:
            origin = self._local_origin()
            if origin is not None:
                east, north = enu_offset(origin[0], origin[1], cmd.est_lat_deg, cmd.est_lon_deg)
                link.send_odometry(float(north), float(east), sigma)

    def _local_origin(self) -> tuple[float, float] | None:
        """The flight controller's local NED origin from GLOBAL_POSITION_INT and LOCAL_POSITION_NED."""
        pos, local = self.decoder.fc_position, self.local_ned
        if pos is None or local is None or abs(pos.time_s - local[0]) > 1.0:
            return None
        lat, lon = offset_position(pos.lat_deg, pos.lon_deg, -local[2], -local[1])
        return float(lat), float(lon)

    def _nav_failure(self, reason: str, cmd: Command) -> None:
        self._say(f"FcMPC FAILSAFE: {reason}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
        self._hold_if_guided(self.now)
        self.hold_commanded = True
        self.restarts += 1
        if self.restarts > MAX_RESTARTS:
            self.command = cmd
            self._finish(cmd, failed_reason=f"{reason}; gave up after {MAX_RESTARTS} restarts")
            return
        est = (cmd.est_lat_deg, cmd.est_lon_deg)
        if not all(math.isfinite(v) for v in est) and self.command is not None:
            est = (self.command.est_lat_deg, self.command.est_lon_deg)
        self.restart_from = est if all(math.isfinite(v) for v in est) else None
        self.mission = None
        self.command = None
        self._enter_startup(f"restart {self.restarts} after: {reason}")

    def _lingered(self) -> bool:
        """--exit-when-done: ``--linger-s`` of message time passed since the mission ended (the
        companion keeps answering a lockstep simulator meanwhile, so the records show the vehicle
        coming to rest; the FC's INS velocity drifts too much to judge that on board)."""
        return not math.isfinite(self.done_msg_s) or self.now - self.done_msg_s >= self.opts.linger_s

    def _finish(self, cmd: Command, failed_reason: str = "") -> None:
        self.state = State.DONE
        self.done_wall = time.monotonic()
        self.done_msg_s = self.now
        self.stream_since = math.nan
        if failed_reason:
            self._say(f"FcMPC: mission FAILED: {failed_reason}"[:200], mavlink.MAV_SEVERITY_ERROR)
        elif cmd.phase == Phase.ARRIVED:
            self._say(f"FcMPC: arrived after {cmd.step} steps, estimated {cmd.remaining_m:.0f} m to go")
        else:
            self._say(f"FcMPC: mission {cmd.phase}: {cmd.reason}", mavlink.MAV_SEVERITY_ERROR)
        self._record_event("done", failed_reason or cmd.reason or cmd.phase)
        self._hold_if_guided(self.now)

    # ------------------------------------------------------------------ records
    def _record_step(self, cmd: Command, meas: Measurement, avg, ins_source: str, latency: float, event: str,
                     reason: str) -> None:
        if self.recorder is None:
            return
        st = self.mag.stats
        self.recorder.write({
            "wall_time_s": time.time(), "msg_time_s": self.now, "mission_time_s": meas.time_s,
            "mission": self.mission_no, "step": cmd.step, "phase": cmd.phase, "decl_deg": meas.decl_deg,
            "incl_deg": meas.incl_deg, "f_nt": meas.f_nt, "samples": avg.count, "window_s": meas.window_s, "spikes": st.spikes,
            "invalid": st.non_finite + self.invalid_mag, "ins_lat_deg": meas.ins_lat_deg,
            "ins_lon_deg": meas.ins_lon_deg, "ins_source": ins_source, "est_lat_deg": cmd.est_lat_deg,
            "est_lon_deg": cmd.est_lon_deg, "est_sigma_m": cmd.est_sigma_m, "fix_lat_deg": cmd.fix_lat_deg,
            "fix_lon_deg": cmd.fix_lon_deg, "fused": cmd.fused, "remaining_m": cmd.remaining_m,
            "course_deg": math.degrees(cmd.course_rad), "speed_mps": cmd.speed_mps, "solver_ok": cmd.solver_ok,
            "solver_time_s": cmd.solver_time_s, "step_latency_s": latency, "event": event, "reason": reason,
            **self._gps_record()})

    def _gps_record(self) -> dict:
        """GPS at the step, for the record only (a reference where the receiver still has a fix)."""
        gps = self.last_gps
        if gps is None or self.now - gps.time_s > GPS_START_MAX_AGE_S:
            return {"gps_fix": 0}
        return {"gps_fix": gps.fix_type, "gps_lat_deg": gps.lat_deg if gps.fix_type >= 2 else math.nan,
                "gps_lon_deg": gps.lon_deg if gps.fix_type >= 2 else math.nan}

    def _record_event(self, event: str, reason: str) -> None:
        if self.recorder is None:
            return
        self.recorder.write({"wall_time_s": time.time(), "msg_time_s": self.now,
                             "mission_time_s": self.mission_time() - self.m0 if math.isfinite(self.m0) else math.nan,
                             "mission": self.mission_no, "step": self.mission.k if self.mission else 0,
                             "phase": self.state, "event": event, "reason": reason})

    def summary(self) -> dict:
        wall = time.monotonic() - self.wall_start
        lat = self.step_latency_s
        return {
            "state": self.state, "phase": self.command.phase if self.command else "",
            "arrived": bool(self.command and self.command.phase == Phase.ARRIVED),
            "missions": self.mission_no, "restarts": self.restarts,
            "steps": self.command.step if self.command else 0,
            "est_lat_deg": self.command.est_lat_deg if self.command else math.nan,
            "est_lon_deg": self.command.est_lon_deg if self.command else math.nan,
            "est_remaining_m": self.command.remaining_m if self.command else math.nan,
            "msg_time_s": self.now, "wall_s": round(wall, 3),
            "messages_in": self.link.stats.messages_in, "messages_from_fc": self.messages_from_fc,
            "messages_out": self.link.stats.messages_out, "msgs_in_per_wall_s": round(self.link.stats.messages_in / max(wall, 1e-9), 1),
            "bad_frames": self.link.stats.bad_frames, "setpoints_sent": self.link.stats.setpoints_sent,
            "setpoints_refused": self.link.stats.setpoints_refused, "failsafes": self.health.entered,
            "step_latency_median_s": statistics.median(lat) if lat else math.nan,
            "step_latency_p99_s": _percentile(lat, 0.99),
            "core_latency_median_s": statistics.median(self.core_latency_s) if self.core_latency_s else math.nan,
            "mag": {**self.mag.stats.as_dict(), "invalid": self.invalid_mag}, "param_load_error": self.params.load_error,
            "sensors": None if self.sensors is None else {
                "spec": self.opts.sensors, "name": self.sensors.name,
                "kinds": sorted(k.value for k in self.source_kinds),
                "samples": self.sensors.stats.samples, "flagged": self.sensors.stats.flagged,
                "read_errors": self.sensors.stats.read_errors, "last_error": self.sensors.stats.last_error,
                "dropped_no_fc_clock": self.source_dropped_no_clock, "time_resyncs": self.source_time.resyncs,
                "time_offset_s": self.source_time.offset_s, "ended": self.source_ended},
            "fc": {"autopilot": self.link.fc.conventions.name, "sysid": self.link.fc.sysid,
                   "mode": self.link.fc.mode_name, "armed": self.link.fc.armed,
                   "heading": self._heading_summary(), "positions_fed": self.link.stats.positions_fed,
                   "arming_refusals": self.fc_view.arming.refusals},
            "elements": ELEMENT_SETS[self.elements_code].label if self.elements_code else "",
            "bias": list(self.bias) if self.bias is not None else None,
            "events": self.events[-200:], "log_dir": str(self.log_dir),
        }

    def _heading_summary(self) -> str:
        verdict = self.fc_view.heading_verdict(self.now) if self.link.fc.detected else None
        if verdict is None:
            return "unknown"
        return ("compass-derived: " if verdict.compass_derived else "independent: ") + verdict.reason

    def _write_summary(self) -> None:
        try:
            write_summary(self.log_dir / "summary.json", self.summary())
        except OSError as err:  # pragma: no cover
            print(f"fcmpc-companion: cannot write summary: {err}", file=sys.stderr)


def apply_live_config(mission: Mission, new: NavConfig) -> list[str]:
    """Apply a changed NavConfig to a running mission (:meth:`Mission.reconfigure`)."""
    return mission.reconfigure(new)


def benchmark(**kwargs) -> dict:
    """Control-step latency and sustained input rate against the simulator (:mod:`companion.benchmark`)."""
    from companion.benchmark import run

    return run(**kwargs)


# ---------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="fcmpc-companion",
        description="Fc-MPC geomagnetic navigation companion: flies a GPS-free mission over MAVLink "
                    "(ArduPilot GUIDED or PX4 OFFBOARD) as component 191.")
    p.add_argument("--connect", "--master", dest="connect", default="udp:127.0.0.1:14550",
                   help="pymavlink connection: udp:HOST:PORT (listen), udpout:HOST:PORT, tcp:HOST:PORT, "
                        "tcpin:HOST:PORT, or a serial device DEVICE,BAUD; default udp:127.0.0.1:14550")
    p.add_argument("--params", default=None, metavar="FILE",
                   help=".parm file loaded at start and rewritten atomically on every PARAM_SET; it must exist "
                        "unless --params-create is given; default <log-dir>/companion.parm (created)")
    p.add_argument("--params-create", action="store_true",
                   help="start from the defaults when the --params FILE does not exist yet (it is written on "
                        "the first PARAM_SET)")
    p.add_argument("--log-dir", default=None, help="records folder; default out/companion/<time>-<pid>")
    p.add_argument("--sysid", type=int, default=None,
                   help="only follow the flight controller with this system id; default the first one heard")
    p.add_argument("--lockstep", action="store_true",
                   help="send a timed message every setpoint period even when not steering "
                        "(a lockstep simulator waits for it)")
    p.add_argument("--exit-when-done", action="store_true",
                   help="exit when the mission ends (after --linger-s): 0 arrived, 1 failed")
    p.add_argument("--linger-s", type=float, default=0.0, metavar="S",
                   help="with --exit-when-done: keep running this many seconds of message time after the "
                        "mission ended, e.g. until the vehicle has come to rest; default 0")
    p.add_argument("--param-encoding", choices=ENCODINGS, default="auto",
                   help="INT32 parameter values: C cast (ArduPilot), bytewise (PX4), or from the FC; default auto")
    p.add_argument("--mag-message", choices=MAG_MESSAGES, default=None,
                   help="magnetometer message to use; default the first one the FC sends")
    p.add_argument("--sensors", default=None, metavar="SPEC",
                   help="read sensors from this source instead of the FC's streams (kinds it lacks still come "
                        "from the FC): i2c:/dev/i2c-1, ubx:/dev/ttyACM0:115200, dronecan:can0, "
                        "dronecan:virtual:vbus0, replay:log.bin?speed=1, or several joined with +; "
                        "default MAVLink only")
    p.add_argument("--startup-s", type=float, default=None,
                   help="stationary averaging before the first step, s of message time; default NAV_PERIOD_S")
    p.add_argument("--no-tlog", action="store_true", help="do not record companion.tlog")
    p.add_argument("--no-stream-requests", action="store_true",
                   help="do not send MAV_CMD_SET_MESSAGE_INTERVAL (use the FC's configured rates)")
    p.add_argument("--max-wall-s", type=float, default=None, help="exit (code 3) after this many wall seconds")
    p.add_argument("--quiet", action="store_true", help="no status lines on stderr")
    return p


def options_from_args(args: argparse.Namespace) -> AppOptions:
    return AppOptions(connect=args.connect, params=args.params, log_dir=args.log_dir, sysid=args.sysid,
                      lockstep=args.lockstep, exit_when_done=args.exit_when_done, param_encoding=args.param_encoding,
                      mag_message=args.mag_message, startup_s=args.startup_s, tlog=not args.no_tlog,
                      request_streams=not args.no_stream_requests, max_wall_s=args.max_wall_s, quiet=args.quiet,
                      sensors=args.sensors, linger_s=args.linger_s)


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.params is not None and not args.params_create and not Path(args.params).is_file():
        # a typo in a path must not fly the default mission
        raise UsageError(f"--params {args.params}: no such file (give --params-create to start from the "
                         f"defaults and create it)")
    try:
        app = CompanionApp(options_from_args(args))
    except SensorError as err:
        raise UsageError(f"--sensors {args.sensors}: {one_line(err)}") from None
    except (OSError, ValueError) as err:
        raise UsageError(one_line(err)) from None
    if app.params.load_error:
        print(f"fcmpc-companion: parameter file rejected, serving defaults and refusing to steer: "
              f"{app.params.load_error}", file=sys.stderr)
    stopped_by: list[int] = []

    def stop(signum, frame):  # noqa: ARG001
        stopped_by.append(signum)
        app.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        code = app.run()
    except SensorError as err:
        raise UsageError(f"sensor source {args.sensors!r} failed: {one_line(err)}") from None
    except OSError as err:
        raise UsageError(one_line(err)) from None
    if stopped_by and app.exit_code is None:
        return 128 + stopped_by[0]        # stopped before the mission ended: not "arrived"
    return code


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-companion", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())

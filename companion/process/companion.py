"""CompanionApp: the parts of :mod:`companion.process` wired to the link, the receive hook and the loop.

Clocks
    Everything the navigation sees runs on *message time*: the flight controller's
    ``time_boot_ms`` (and SYSTEM_TIME), so a simulator running 1000x faster than real time is
    flown exactly like a vehicle. The setpoint stream (COMP_SP_RATE_HZ), the heartbeat (1 Hz)
    and the control step (NAV_PERIOD_S) are scheduled in message time. Wall time is used only
    for socket waits, the heartbeat's wall-time floor (1 Hz) and judging a flight controller that
    went completely silent (see :mod:`companion.failsafe`).
"""
from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import time
from datetime import datetime
from pathlib import Path

from companion.failsafe import Health, HealthLimits
from companion.fc_view import FcView
from companion.io.link.signing import Signing
from companion.io.link import MavlinkLink, mavlink
from companion.io.param_server import ParamServer
from companion.io.sensors.base import SampleKind, SensorSource
from companion.io.sensors.factory import make_source
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.field import model_for_setting
from companion.nav.magnetometer import MagCalibration, MagProcessor
from companion.nav.mission import Command, Mission, Phase
from companion.params import CompanionConfig, NavConfig
from companion.process.control_step import ControlStep
from companion.process.failsafe_response import FailsafeResponse
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine, State
from companion.process.mission_clock import MissionClock
from companion.process.mode_commands import ModeCommands
from companion.process.operator_commands import OperatorCommands
from companion.process.options import AppOptions
from companion.process.outputs import Outputs
from companion.process.phases import Phases
from companion.nav.plausibility import MagPlausibility
from companion.process.preparation import MissionPreparation
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.registry import READINGS
from companion.sdnotify import Notifier

__all__ = ["CompanionApp", "apply_live_config"]

LINGER_WALL_S = 0.5               # after done, before exiting: let the last messages go
WAITING_REPEAT_WALL_S = 30.0      # repeat "waiting for a heartbeat" while no flight controller is heard


def apply_live_config(mission: Mission, new: NavConfig) -> list[str]:
    """Apply a changed NavConfig to a running mission (:meth:`Mission.reconfigure`)."""
    return mission.reconfigure(new)


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
                                tlog_path=self.log_dir / "companion.tlog" if options.tlog else None,
                                fc_compid=options.fc_compid,
                                signing=Signing.from_file(options.signing_key, options.signing_link_id)
                                if options.signing_key else None)
        self.params = ParamServer(self.link, params_path, on_change=self._param_changed,
                                  encoding=options.param_encoding, clock=lambda: self.now)
        self.params.load()
        self.link.apply_ceiling(self.params.ceiling, tlog_max_bytes=int(self.params.values["LINK_TLOG_MB"] * 1e6))
        self.notifier = Notifier()   # systemd READY/WATCHDOG (a no-op outside systemd)
        self.nav_cfg = NavConfig.from_values(self.params.values)
        self.comp_cfg = CompanionConfig.from_values(self.params.values)
        model_for_setting(self.nav_cfg.year, self.nav_cfg.wmm, self.nav_cfg.nav_map)   # load the coefficients now, not at take-off
        self.decoder = MavlinkDecoder(self.link.clock, options.mag_message, imu=True)   # specific force: I_g
        # --sensors: a sensor source beside the link (built here so a bad spec fails early)
        self.sensors: SensorSource | None = make_source(options.sensors) if options.sensors else None
        self.mag = MagProcessor(MagCalibration.from_mgauss(self.comp_cfg.mag_offset_mgauss, self.comp_cfg.mag_scale,
                                                       self.comp_cfg.mag_soft_xy_xz_yz),
                                self.comp_cfg.spike_nt, track_yaw_offset=self.comp_cfg.trim_max_deg > 0.0)
        self.health = Health(self._limits())
        self.fc_view = FcView(self.comp_cfg.heading_source, self.comp_cfg.position_publish, self.comp_cfg.feed_blend_mps)
        # the parts
        self.machine = PhaseMachine()
        self.clock = MissionClock(self.mag)
        self.modes = ModeCommands()
        self.plausibility = MagPlausibility()
        self.intake = SampleIntake(self, self.sensors)
        self.out = Outputs(self)
        self.failsafe = FailsafeResponse(self)
        self.preparation = MissionPreparation(self)
        self.stepper = ControlStep(self)
        self.phases = Phases(self)
        self.reporting = Reporting(self)
        self.resume = Resume(self, self._state_path())
        self.operator = OperatorCommands(self)
        if self.params.load_error:
            self.health.latch("params", f"broken parameter file, defaults served, will not steer: "
                                        f"{self.params.load_error}")
        # the mission
        self.elements_code = 0          # the element set of the running mission (resolved NAV_ELEMENTS)
        self.bias: tuple[float, float] | None = None
        self.mission: Mission | None = None
        self.mission_no = 0
        self.restarts = 0
        self.restart_from: tuple[float, float] | None = None
        self.command: Command | None = None
        self.last_phase = ""
        self.exit_code: int | None = None
        self.done_wall = self.done_msg_s = math.nan    # wall and message time the mission ended
        self._stop = False
        self.params_dirty = False
        # clocks and timers (message time unless *_wall)
        self.m0 = math.nan              # mission time of the mission start
        self.next_step_m = math.nan
        self.startup_begin = math.nan
        self.fc_detected_at = math.nan
        self.next_tick = -math.inf
        self.local_ned: tuple[float, float, float] | None = None   # (time, north, east) of LOCAL_POSITION_NED
        self.last_tick_time = math.nan
        # statistics
        self.wall_start = time.monotonic()
        self._waiting_said_wall = self.wall_start
        self.messages_from_fc = 0
        self.fc_reboots = 0

    # ------------------------------------------------------------------ what the parts hold
    @property
    def state(self) -> str:
        return self.machine.state

    @property
    def failsafe_active(self) -> bool:
        return self.failsafe.active

    @property
    def paused_since(self) -> float:
        return self.clock.paused_since

    @property
    def last_valid(self) -> dict[SampleKind, float]:
        return self.intake.last_valid

    @property
    def invalid_mag(self) -> int:
        return self.intake.invalid_mag

    @property
    def source_dropped_no_clock(self) -> int:
        return self.intake.dropped_no_clock

    @property
    def events(self) -> list[str]:
        return self.out.events

    # ------------------------------------------------------------------ configuration
    def _state_path(self) -> Path:
        """--state, else beside the --params file (it outlives the run's log folder), else in the log folder."""
        if self.opts.state:
            return Path(self.opts.state)
        if self.opts.params:
            return Path(self.opts.params).with_suffix(".navstate")
        return self.log_dir / "companion.navstate"

    def _limits(self) -> HealthLimits:
        c = self.comp_cfg
        return HealthLimits(c.mag_timeout_s, c.att_timeout_s, c.heartbeat_timeout_s)

    def _param_changed(self, name: str, value) -> None:
        if name in READINGS:   # a reading, not a setting: the control step reads it from the server
            return
        self.params_dirty = True
        if self.state != State.RUNNING:
            self.apply_params()

    def apply_params(self) -> None:
        """Rebuild the configurations from the parameter values (at a control step when running)."""
        self.params_dirty = False
        values = self.params.values
        self.comp_cfg = CompanionConfig.from_values(values)
        self.mag.configure(MagCalibration.from_mgauss(self.comp_cfg.mag_offset_mgauss, self.comp_cfg.mag_scale,
                                                       self.comp_cfg.mag_soft_xy_xz_yz),
                           self.comp_cfg.spike_nt)
        self.mag.track_yaw_offset = self.comp_cfg.trim_max_deg > 0.0
        self.health.limits = self._limits()
        self.fc_view.position_publish = self.comp_cfg.position_publish
        self.fc_view.feed.blend_mps = self.comp_cfg.feed_blend_mps
        new_nav = NavConfig.from_values(values)
        self.nav_cfg = new_nav
        if self.mission is not None and self.state == State.RUNNING:
            deferred = apply_live_config(self.mission, new_nav)
            for name in deferred:
                self.out.say(f"FcMPC: {name} applies to the next mission", mavlink.MAV_SEVERITY_NOTICE)

    # ------------------------------------------------------------------ time
    @property
    def now(self) -> float:
        return self.link.clock.now_s

    def mission_time(self, now: float | None = None) -> float:
        return self.clock.mission_time(self.now if now is None else now)

    def age(self, kind: SampleKind) -> float:
        """Message-time age of the last valid sample of a kind (infinite if none yet)."""
        return self.intake.age(kind, self.now)

    # ------------------------------------------------------------------ main loop
    def open(self) -> None:
        self.intake.open_source()
        try:
            with contextlib.redirect_stdout(io.StringIO()):   # pymavlink prints its TCP retries
                self.link.open()
        except OSError as err:
            self.intake.close_source()
            raise ConnectionError(f"cannot connect to {self.opts.connect}: {err.strerror or err}") from err
        except BaseException:
            self.intake.close_source()
            raise
        self.reporting.open(self.log_dir / "steps.csv")
        self.out.heartbeat()   # a udpout link must speak first
        self.notifier.ready()
        self._waiting_said_wall = time.monotonic()
        if not self.opts.quiet:
            print(f"fcmpc-companion: waiting for a heartbeat on {self.opts.connect}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.link.conn is not None and self.link.fc.detected and self.link.fc.guided and self.link.fc.armed \
                and self.state in (State.RUNNING, State.READY, State.CALIBRATING):
            self.link.send_hold_mode()   # do not leave a vehicle in GUIDED without a companion
        self.reporting.close()
        self.reporting.write_summary()
        self.link.close()
        self.intake.close_source()

    def request_stop(self) -> None:
        self._stop = True

    @property
    def stopping(self) -> bool:
        return self._stop or self.exit_code is not None

    def run(self) -> int:
        self.open()
        try:
            while not self.stopping:
                self.spin()
        finally:
            self.close()
        return self.exit_code if self.exit_code is not None else 0

    def spin(self, wait_s: float = 0.02) -> None:
        """One pass of the loop: what the link has (waiting up to ``wait_s``), the source, the idle hook.
        Against a lockstep simulator what the pass sends leaves together at its end
        (:meth:`MavlinkLink.batched`); to a flight controller each frame goes out as sent: PX4
        forwards what it receives to its other links, and a burst of frames in one datagram lost the
        companion's STATUSTEXT on its way to PX4's ground-station link (one CI run), and PX4 on
        NuttX reads UDP into a 1000-byte buffer."""
        batched = self.link.batched if self.opts.lockstep else contextlib.nullcontext
        if self.link.wait_readable(wait_s):
            for _ in range(256):
                with batched():
                    msgs = self.link.read()
                    for msg in msgs:
                        self.handle(msg)
                if not msgs:
                    break
        with batched():
            if self.sensors is not None:
                self.intake.poll()
            self.idle()
        self.notifier.watchdog()   # a stalled loop is restarted by systemd

    def handle(self, msg) -> None:
        """Receive hook: every message read from the link."""
        link = self.link
        if link.observe(msg):
            self.messages_from_fc += 1
            self.fc_view.packet(msg, link.clock.now_s)
            if link.clock.reboots != self.fc_reboots:
                self.phases.fc_rebooted()
            was_detected = self.state != State.WAIT_FC
            self.intake.decode(msg)
            if msg._type == "LOCAL_POSITION_NED":
                self.local_ned = (msg.time_boot_ms * 1e-3, msg.x, msg.y)
            if (self.link.clock.now_s >= self.next_tick or not was_detected) and self.link.clock.started:
                self.tick()
            self.out.feed_due(self.link.clock.now_s)
        elif not self.params.mavlink_packet(msg):   # PARAM_* are the parameter server's
            self.operator.mavlink_packet(msg)       # COMMAND_LONG to 191: the operator's commands

    def idle(self) -> None:
        """Periodic hook in wall time: heartbeat floor, silent flight controller, exit conditions."""
        wall = time.monotonic()
        for sysid, compid in self.link.new_autopilots():   # reported, never followed
            self.out.say(f"FcMPC: second autopilot {sysid}/{compid} ignored (following {self.link.fc.sysid})",
                         mavlink.MAV_SEVERITY_WARNING)
        if wall - self.out.last_hb_sent_wall >= 1.0:
            self.out.heartbeat()
            if self.state == State.WAIT_FC and wall - self._waiting_said_wall >= WAITING_REPEAT_WALL_S:
                self._waiting_said_wall = wall
                if not self.opts.quiet:
                    print(f"fcmpc-companion: still waiting for a heartbeat on {self.opts.connect} "
                          f"({wall - self.wall_start:.0f} s)", file=sys.stderr, flush=True)
            if self.link.fc.detected and self.link.clock.started:
                self.failsafe.evaluate()   # a silent FC: message time stands still, wall time does not
                if self.failsafe.active and self.state == State.RUNNING:
                    self.failsafe.act()
        self.out.operator_status_due(wall)
        if self.state == State.DONE and self.opts.exit_when_done and wall - self.done_wall >= LINGER_WALL_S \
                and self._lingered():
            self.exit_code = 0 if self.command is not None and self.command.phase == Phase.ARRIVED else 1
        if self.opts.max_wall_s is not None and wall - self.wall_start > self.opts.max_wall_s:
            self.out.say(f"FcMPC: wall-time limit {self.opts.max_wall_s:g} s reached, exiting",
                         mavlink.MAV_SEVERITY_WARNING)
            self.exit_code = 3
        self.reporting.publish_status(wall)   # --http: the status page

    def _lingered(self) -> bool:
        """--exit-when-done: ``--linger-s`` of message time passed since the mission ended (the
        companion keeps answering a lockstep simulator meanwhile, so the records show the vehicle
        coming to rest; the FC's INS velocity drifts too much to judge that on board)."""
        return not math.isfinite(self.done_msg_s) or self.now - self.done_msg_s >= self.opts.linger_s

    # ------------------------------------------------------------------ the control tick
    def tick(self) -> None:
        """Runs at COMP_SP_RATE_HZ of message time (and when the flight controller appears)."""
        now = self.now
        period = 1.0 / self.comp_cfg.setpoint_rate_hz
        self.next_tick = now + period if now - self.next_tick >= period else self.next_tick + period
        if now - self.out.last_hb_sent >= 1.0:
            self.out.heartbeat()
        dt = now - self.last_tick_time if math.isfinite(self.last_tick_time) else 0.0
        self.last_tick_time = now
        if self.state == State.WAIT_FC:
            self.phases.fc_detected()
        self.fc_view.poll_requests(self.link, now)
        self.preparation.forecast.poll()
        reasons = self.failsafe.evaluate()
        sent = self.phases.tick(now, reasons, dt)
        if self.state == State.RUNNING:
            self.resume.maybe_save(now)
        if self.link.fc.detected:
            self.modes.observe(self.link.fc.custom_mode, self.link.fc.last_heartbeat_time_s)   # after the phase saw it
        if not sent:
            self.out.stream_since = math.nan
            if self.opts.lockstep:   # a timed message each period keeps a lockstep simulator going
                self.link.send_named_float("FC_STATE", float(self.machine.code(self.failsafe.active)))

    def summary(self) -> dict:
        return self.reporting.summary()

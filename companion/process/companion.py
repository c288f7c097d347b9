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

from companion.failsafe import Health
from companion.fc_view import FcView
from companion.io.link.signing import Signing
from companion.io.link import MavlinkLink, mavlink
from companion.io.param_server import ParamServer
from companion.io.sensors.factory import make_source
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.field import model_for_setting
from companion.nav.magnetometer import MagProcessor
from companion.nav.mission import Phase
from companion.nav.plausibility import MagPlausibility
from companion.params import CompanionConfig, NavConfig
from companion.process.calibration_turn import CalibrationTurn
from companion.process.control_step import ControlStep
from companion.process.estimate import CurrentEstimate
from companion.process.failsafe_response import FailsafeResponse
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine, State
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.mode_commands import ModeCommands
from companion.process.operator_commands import OperatorCommands
from companion.process.options import AppOptions
from companion.process.outputs import Outputs
from companion.process.phases import Phases
from companion.process.phases.calibrating import CalibratingPhase
from companion.process.phases.done import DonePhase
from companion.process.phases.engage import Engage
from companion.process.phases.ready import ReadyPhase
from companion.process.phases.running import RunningPhase
from companion.process.phases.startup import StartupPhase
from companion.process.phases.wait_fc import WaitFcPhase
from companion.process.preparation import MissionPreparation
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.process.settings import Settings, apply_live_config, health_limits, mag_calibration
from companion.process.status import StatusPublisher, StatusView
from companion.process.summary import Summary
from companion.process.telemetry import Telemetry
from companion.process.voice import Voice
from companion.registry import READINGS
from companion.sdnotify import Notifier

__all__ = ["CompanionApp", "apply_live_config"]

LINGER_WALL_S = 0.5               # after done, before exiting: let the last messages go
WAITING_REPEAT_WALL_S = 30.0      # repeat "waiting for a heartbeat" while no flight controller is heard


class CompanionApp:
    """The companion process: its parts built and wired (each receives what it uses), the receive
    hook, the periodic hooks and :meth:`run` until done (``--exit-when-done``), a signal or
    ``max_wall_s``. It holds no mission state of its own: that is :class:`MissionState`'s."""

    def __init__(self, options: AppOptions) -> None:
        self.opts = opts = options
        if opts.log_dir:
            self.log_dir = Path(opts.log_dir)
        else:
            self.log_dir = Path("out") / "companion" / f"{datetime.now():%Y%m%d-%H%M%S}-{os.getpid()}"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        params_path = opts.params if opts.params is not None else str(self.log_dir / "companion.parm")
        self.link = link = MavlinkLink(opts.connect, opts.sysid,
                                       tlog_path=self.log_dir / "companion.tlog" if opts.tlog else None,
                                       fc_compid=opts.fc_compid,
                                       signing=Signing.from_file(opts.signing_key, opts.signing_link_id)
                                       if opts.signing_key else None)
        msg_clock = link.clock
        self.params = params = ParamServer(link, params_path, on_change=self._param_changed,
                                           encoding=opts.param_encoding, clock=lambda: msg_clock.now_s)
        params.load()
        link.apply_ceiling(params.ceiling, tlog_max_bytes=int(params.values["LINK_TLOG_MB"] * 1e6))
        self.notifier = Notifier()   # systemd READY/WATCHDOG (a no-op outside systemd)
        nav, comp = NavConfig.from_values(params.values), CompanionConfig.from_values(params.values)
        model_for_setting(nav.year, nav.wmm, nav.nav_map)   # load the coefficients now, not at take-off
        self.decoder = decoder = MavlinkDecoder(msg_clock, opts.mag_message, imu=True)   # specific force: I_g
        sensors = make_source(opts.sensors) if opts.sensors else None   # --sensors: a bad spec fails early
        self.mag = mag = MagProcessor(mag_calibration(comp), comp.spike_nt, track_yaw_offset=comp.trim_max_deg > 0.0)
        self.health = health = Health(health_limits(comp))
        self.fc_view = fc_view = FcView(comp.heading_source, comp.position_publish, comp.feed_blend_mps,
                                        comp.feed_accel_limit_mps2)
        # the parts, each given what it uses; the mission's shared state is one record
        self.settings = settings = Settings(params, mag, health, fc_view, nav, comp)
        self.mission_state = state = MissionState()
        self.machine = machine = PhaseMachine()
        self.clock = clock = MissionClock(mag)
        self.modes = modes = ModeCommands()
        self.plausibility = plausibility = MagPlausibility()
        self.voice = voice = Voice(link, opts.quiet)
        self.intake = intake = SampleIntake(sensors, opts.sensors, decoder, mag, msg_clock, settings, state, voice)
        self.preparation = prep = MissionPreparation(settings, state, intake, fc_view, msg_clock, voice,
                                                     opts.startup_s, opts.lockstep)
        self.reporting = reporting = Reporting(msg_clock, clock, state, machine, mag, intake)
        self.resume = resume = Resume(self._state_path(), state, clock, msg_clock, reporting, voice)
        self.failsafe = failsafe = FailsafeResponse(link, health, decoder, intake, state, machine, clock, modes,
                                                    resume, reporting, voice)
        estimate = CurrentEstimate(state, clock, msg_clock, prep, settings)
        self.out = out = Outputs(link, settings, state, mag, decoder, estimate, opts.request_streams, opts.mag_message)
        calturn = CalibrationTurn(settings, mag, params, prep, voice)
        self.telemetry = Telemetry(link, settings, state, machine, failsafe, calturn, clock, decoder, fc_view,
                                   estimate, params, health, voice)
        self.operator = operator = OperatorCommands(link, settings, machine, clock, modes, failsafe, out, reporting,
                                                    voice)
        self.stepper = stepper = ControlStep(settings, state, params, mag, decoder, fc_view, plausibility,
                                             msg_clock, reporting, voice)
        engage = Engage(link, modes, fc_view, operator, out, voice)
        self.phases = Phases(
            machine, state, mag, engage, voice, WaitFcPhase(link, state, fc_view, out, voice),
            StartupPhase(link, settings, state, mag, clock, prep, fc_view, resume, reporting, voice),
            ReadyPhase(link, mag, prep, operator, out, resume, calturn, engage), CalibratingPhase(calturn, out),
            RunningPhase(link, settings, state, mag, clock, stepper, prep, out, estimate, fc_view, modes, operator,
                         engage, failsafe, resume, reporting, voice),
            DonePhase(state, out, failsafe, resume, reporting, voice))
        self.status = StatusPublisher.for_options(   # --http: its port bound now (in use: OSError)
            StatusView(link, machine, state, settings, prep, failsafe, health, intake, decoder, fc_view, voice),
            opts.http, self.log_dir, opts.quiet)
        self.wall_start = time.monotonic()
        self.summarised = Summary(link, machine, state, params, failsafe, stepper, mag, intake, fc_view, plausibility,
                                  resume, modes, operator, voice, prep.forecast, self.log_dir,
                                  self.wall_start)
        if params.load_error:
            health.latch("params", f"broken parameter file, defaults served, will not steer: {params.load_error}")
        self.exit_code: int | None = None
        self._stop = False
        # the loop's timers (message time unless *_wall)
        self.next_tick = -math.inf
        self.last_tick_time = math.nan
        self._waiting_said_wall = self.wall_start
        self.fc_reboots = 0
        self._streams_asked_early = False

    # ------------------------------------------------------------------ what the parts hold
    @property
    def state(self) -> str:
        """The phase (:class:`companion.process.machine.State`)."""
        return self.machine.state

    @property
    def failsafe_active(self) -> bool:
        return self.failsafe.active

    @property
    def messages_from_fc(self) -> int:
        return self.intake.messages_from_fc

    # ------------------------------------------------------------------ configuration
    def _state_path(self) -> Path:
        """--state, else beside the --params file (it outlives the run's log folder), else in the log folder."""
        if self.opts.state:
            return Path(self.opts.state)
        if self.opts.params:
            return Path(self.opts.params).with_suffix(".navstate")
        return self.log_dir / "companion.navstate"

    def _param_changed(self, name: str, value) -> None:
        if name in READINGS:   # a reading, not a setting: the control step reads it from the server
            return
        self.settings.dirty = True
        if self.state != State.RUNNING:   # running: at the next control step
            self.settings.apply()

    # ------------------------------------------------------------------ time
    @property
    def now(self) -> float:
        return self.link.clock.now_s

    def mission_time(self, now: float | None = None) -> float:
        return self.clock.mission_time(self.now if now is None else now)

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
        self.status.start()   # before steps.csv: once the file exists, the page answers
        self.reporting.open(self.log_dir / "steps.csv")
        self.out.heartbeat(self.state, self.failsafe.active)   # a udpout link must speak first
        self.notifier.ready()
        self._waiting_said_wall = time.monotonic()
        if not self.opts.quiet:
            print(f"fcmpc-companion: waiting for a heartbeat on {self.opts.connect}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.link.conn is not None and self.link.fc.detected and self.link.fc.guided and self.link.fc.armed \
                and self.state in (State.RUNNING, State.READY, State.CALIBRATING):
            self.link.send_hold_mode()   # do not leave a vehicle in GUIDED without a companion
        self.reporting.close()
        self.status.stop()
        self.summarised.write()
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
            self.intake.poll()   # --sensors (nothing without)
            self.idle()
        self.notifier.watchdog()   # a stalled loop is restarted by systemd

    def handle(self, msg) -> None:
        """Receive hook: every message read from the link."""
        link = self.link
        if link.observe(msg):
            clock = link.clock
            self.fc_view.packet(msg, clock.now_s)
            if clock.reboots != self.fc_reboots:
                self._fc_rebooted()
            if not self._streams_asked_early and not clock.started and link.fc.detected:
                # the clock starts on a timed message: a port streaming none (every stream group off)
                # would leave WAIT_FC, and its stream requests, waiting for ever
                self._streams_asked_early = True
                self.out.request_streams()
            was_detected = self.state != State.WAIT_FC
            if self.intake.decode(msg):   # the sample path: intake -> magnetometer pipeline -> tick
                self.out.stop_superseded_streams()
            if msg._type == "LOCAL_POSITION_NED":
                self.mission_state.local_ned = (msg.time_boot_ms * 1e-3, msg.x, msg.y)
            now = clock.now_s   # NaN until the clock starts: no tick then
            if (now >= self.next_tick or not was_detected) and now == now:
                self.tick()
            self.telemetry.feed_due(clock.now_s)
        elif not self.params.mavlink_packet(msg):   # PARAM_* are the parameter server's
            self.operator.mavlink_packet(msg)       # COMMAND_LONG to 191: the operator's commands

    def idle(self) -> None:
        """Periodic hook in wall time: heartbeat floor, silent flight controller, exit conditions."""
        wall = time.monotonic()
        for sysid, compid in self.link.new_autopilots():   # reported, never followed
            self.voice.say(f"FcMPC: second autopilot {sysid}/{compid} ignored (following {self.link.fc.sysid})",
                           mavlink.MAV_SEVERITY_WARNING)
        if wall - self.out.last_hb_sent_wall >= 1.0:
            self.out.heartbeat(self.state, self.failsafe.active)
            if self.state == State.WAIT_FC and wall - self._waiting_said_wall >= WAITING_REPEAT_WALL_S:
                self._waiting_said_wall = wall
                if not self.opts.quiet:
                    print(f"fcmpc-companion: still waiting for a heartbeat on {self.opts.connect} "
                          f"({wall - self.wall_start:.0f} s)", file=sys.stderr, flush=True)
            if self.link.fc.detected and self.link.clock.started:
                self.failsafe.evaluate()   # a silent FC: message time stands still, wall time does not
                if self.failsafe.active and self.state == State.RUNNING:
                    self.failsafe.act()
        self.telemetry.operator_status_due(wall)
        state = self.mission_state
        if self.state == State.DONE and self.opts.exit_when_done and wall - state.done_wall >= LINGER_WALL_S \
                and self._lingered():
            self.exit_code = 0 if state.command is not None and state.command.phase == Phase.ARRIVED else 1
        if self.opts.max_wall_s is not None and wall - self.wall_start > self.opts.max_wall_s:
            self.voice.say(f"FcMPC: wall-time limit {self.opts.max_wall_s:g} s reached, exiting",
                           mavlink.MAV_SEVERITY_WARNING)
            self.exit_code = 3
        self.status.maybe_publish(wall)   # --http: the status page, at most every PUBLISH_WALL_S

    def _lingered(self) -> bool:
        """--exit-when-done: ``--linger-s`` of message time passed since the mission ended (the
        companion keeps answering a lockstep simulator meanwhile, so the records show the vehicle
        coming to rest; the FC's INS velocity drifts too much to judge that on board)."""
        done_msg_s = self.mission_state.done_msg_s
        return not math.isfinite(done_msg_s) or self.now - done_msg_s >= self.opts.linger_s

    # ------------------------------------------------------------------ the control tick
    def tick(self) -> None:
        """Runs at COMP_SP_RATE_HZ of message time (and when the flight controller appears)."""
        now = self.now
        period = 1.0 / self.settings.comp.setpoint_rate_hz
        self.next_tick = now + period if now - self.next_tick >= period else self.next_tick + period
        if now - self.out.last_hb_sent >= 1.0:
            self.out.heartbeat(self.state, self.failsafe.active)
        dt = now - self.last_tick_time if math.isfinite(self.last_tick_time) else 0.0
        self.last_tick_time = now
        if self.state == State.WAIT_FC:
            self.phases.fc_heard(now)
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

    def _fc_rebooted(self) -> None:
        """The flight controller's clock went back: every part drops what it timed on the old clock,
        then the phases decide what becomes of the mission (:meth:`Phases.fc_rebooted`)."""
        now, last_old_s = self.now, self.last_tick_time   # no tick ran since: the new clock was only just confirmed
        self.fc_reboots = self.link.clock.reboots
        self.next_tick = -math.inf
        self.last_tick_time = math.nan
        self.mission_state.fc_detected_at = now   # the streams get their start-up grace again
        self.mission_state.local_ned = None
        for part in (self.out, self.telemetry, self.intake, self.failsafe, self.stepper, self.resume):
            part.fc_rebooted()
        self.fc_view.rebooted()
        self.modes.clear()
        self.link.fc.last_heartbeat_time_s = now
        self.mag.attitude = None
        self.mag.settle_until_s = -math.inf
        self.decoder.fc_position = None
        self.out.request_streams()   # a rebooted autopilot forgets the intervals asked for
        self.phases.fc_rebooted(now, last_old_s)

    def summary(self) -> dict:
        return self.summarised.summary()

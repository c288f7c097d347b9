"""What each phase of :mod:`companion.process.machine` does on a control tick, and what its
transitions do.

``startup``  the vehicle is stationary while D and I are averaged over the start-up window
             (default one control period), which becomes the first measurement; a failsafe
             reason or a moving vehicle starts the window again.
``ready``    zero-velocity setpoints (a sliding start-up window meanwhile); with COMP_ARM_ENABLE 1
             GUIDED (ArduPilot) or, after >= 1 s of setpoints, OFFBOARD (PX4), then arm, backing
             off when the FC refuses; with 0 the operator does so. Armed in GUIDED/OFFBOARD: the
             mission starts (``engaged``).
``running``  stream the command; every NAV_PERIOD_S of mission time a control step, whose new
             command is streamed at once (not a tick later). The mission
             pauses whenever the vehicle is not following (failsafe, or not armed in
             GUIDED/OFFBOARD). A mode change the companion did not command is respected: the
             autopilot's own failsafe is waited out, a pilot's or ground station's pauses the
             mission until GUIDED/OFFBOARD is selected again.
``done``     setpoints stop, hold mode is commanded.

Navigation failures hold the vehicle and restart the mission from the last estimate after a new
stationary start-up (at most MAX_RESTARTS restarts). A flight-controller reboot under a running
mission is no navigation failure: the mission goes on from where it was once re-engaged.
"""
from __future__ import annotations

import math
import time

from companion.io.link import mavlink
from companion.nav.elements import ELEMENT_SETS
from companion.nav.mission import Command, Phase, uses_filter
from companion.process.calibration_turn import CalibrationTurn
from companion.process.machine import Event, State
from companion.process.options import MAX_RESTARTS

__all__ = ["COMMAND_RETRY_S", "Phases"]

COMMAND_RETRY_S = 2.0             # message time between retries of mode commands


class Phases:
    """The phase behaviour; the phase itself is ``app.machine.state``."""

    def __init__(self, app) -> None:   # the CompanionApp wiring this part
        self.app = app
        self.last_mode_cmd = -math.inf
        self.last_arm_cmd = -math.inf
        self.fc_failsafe_hold = ""      # the FC's own failsafe that took it out of GUIDED (re-engage when cleared)
        self.our_hold = False           # the FC left GUIDED for a mode we commanded (re-engage when healthy)
        self.was_following = False
        self.calturn = CalibrationTurn(app)    # the magnetometer's calibration circles (COMP_CAL_TURNS)

    def tick(self, now: float, reasons: list[str], dt: float) -> bool:
        """The current phase's work this tick (a phase entered on the way runs too); True if a
        setpoint was sent."""
        app = self.app
        sent = False
        if app.state == State.STARTUP:
            self.startup(now, reasons)
        if app.state == State.READY:
            sent = self.ready(now, reasons)
        if app.state == State.CALIBRATING:
            sent, averaged = self.calturn.tick(now, reasons)
            if averaged:
                self.start_mission(now)
        if app.state == State.RUNNING:
            sent = self.running(now, reasons, dt)
        if app.state == State.DONE:
            app.failsafe.hold_if_guided(now)
        return sent

    # ------------------------------------------------------------------ wait_fc -> startup
    def fc_detected(self) -> None:
        app = self.app
        fc = app.link.fc
        app.fc_detected_at = app.now
        app.out.say(f"FcMPC: {fc.conventions.name} FC sysid {fc.sysid} detected, mode {fc.mode_name}")
        app.fc_view.start(fc.conventions.family, fc.conventions.param_bytewise, app.now)
        if app.opts.request_streams:
            app.out.request_streams()
        self.enter_startup(Event.FC_HEARD, "start-up")
        app.resume.judge_saved()

    def enter_startup(self, event: str, why: str) -> None:
        app = self.app
        app.machine.fire(event)
        app.startup_begin = app.now
        app.clock.reset()
        app.mag.clear()
        app.reporting.record_event("start" if why == "start-up" else "restart", why)

    # ------------------------------------------------------------------ startup
    def moving(self) -> bool:
        """The vehicle may be moving: armed and not in a hold mode (a pilot or a mission drives it).

        The flight controller's velocity is no evidence: without GPS its INS velocity drifts."""
        app = self.app
        fc = app.link.fc
        return fc.armed and not fc.holding and not (fc.guided and app.comp_cfg.arm_enable)

    def startup(self, now: float, reasons: list[str]) -> None:
        app = self.app
        if reasons or self.moving():
            app.startup_begin = now
            app.mag.clear()
            return
        if now - app.startup_begin >= app.preparation.startup_window() and len(app.mag.averager):
            if app.fc_view.heading_verdict(now) is None:
                return   # still reading the FC's heading parameters: keep averaging
            app.machine.fire(Event.AVERAGED)
            app.out.say(f"FcMPC: ready, start-up average of {len(app.mag.averager)} samples"
                        + ("" if app.comp_cfg.arm_enable else "; arm in GUIDED/OFFBOARD to start"))

    # ------------------------------------------------------------------ ready
    def ready(self, now: float, reasons: list[str]) -> bool:
        app = self.app
        app.mag.drop_before(now - app.preparation.startup_window())   # a sliding window while waiting
        if reasons:
            return False
        fc = app.link.fc
        if fc.armed and fc.guided and not app.operator.held:
            sent = app.out.zero_setpoint()   # no gap: the FC stops after 3 s without a setpoint
            if app.resume.pending is not None:
                app.resume.resume_mission(now)
                self.was_following = True
            elif self.calturn.wanted(app.preparation.start_position()[2]):
                app.machine.fire(Event.CALIBRATE)
                self.calturn.enter(now)
            else:
                self.start_mission(now)
            return sent
        sent = app.out.zero_setpoint()
        if app.resume.pending is None:
            app.preparation.prepare(now)
        self.engage(now)
        return sent

    def engage(self, now: float) -> None:
        """GUIDED/OFFBOARD then arm, with retries (only with COMP_ARM_ENABLE = 1)."""
        app = self.app
        fc = app.link.fc
        if not app.operator.engage_allowed():   # COMP_ARM_ENABLE 0 (and no operator's start), or held
            return
        conv = fc.conventions
        since = app.out.stream_since
        streamed = now - since if math.isfinite(since) else 0.0
        if not fc.guided:
            if streamed >= conv.offboard_prestream_s and now - self.last_mode_cmd >= COMMAND_RETRY_S:
                app.link.send_guided_mode()
                app.modes.sent(conv.custom_mode(conv.guided_main, conv.guided_sub), now, "GUIDED")
                self.last_mode_cmd = now
        elif not fc.armed:
            self.arm_with_backoff(now)

    def arm_with_backoff(self, now: float) -> None:
        """Arm; a refusal (COMMAND_ACK) is said once with the FC's reason, and the retry backs off."""
        app = self.app
        fc, backoff = app.link.fc, app.fc_view.arming
        arm = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        result = fc.acks.pop(arm, None)
        if result is not None and result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            wait = backoff.refused(app.fc_view.prearm_text)
            app.out.say(f"FcMPC: arming refused by the FC ({backoff.last_reason or f'result {result}'}); "
                        f"retry in {wait:g} s"[:200], mavlink.MAV_SEVERITY_WARNING)
        if now - self.last_arm_cmd >= backoff.interval_s:
            app.fc_view.prearm_text = ""
            app.link.send_arm(True)
            self.last_arm_cmd = now

    # ------------------------------------------------------------------ ready -> running
    def start_mission(self, now: float) -> None:
        app = self.app
        prep = app.preparation
        if app.params_dirty:
            app.apply_params()
        lat, lon, source = prep.start_position()
        app.elements_code, why = prep.resolve_elements(now)
        config = prep.mission_config(lat, lon, app.elements_code)
        app.m0 = app.mission_time(now)
        startup = app.mag.take(app.m0)
        app.bias, calibration = prep.calibration(config, startup, source)
        app.mission = prep.take_mission(config)
        app.mission.set_bias(app.bias)
        # the error-state filter starts from the known start (a GPS fix, or the declared NAV_START
        # the mission is planned from), a position measurement with FUS_GPS_M, and observes the
        # biases there with the start-up average: the start it already trusts to FUS_GPS_M is as
        # good for the bias states as for the position. Without that calibration the bias states
        # (prior FUS_B0) are first pinned one step later against the INS-predicted position
        # (1-sigma 2.5 km after 360 s of a 10 m/s velocity error), and what they absorb then stays
        # as an offset: closed loop against the stand-in (no GPS, NAV_START) the short mission
        # ended 0.9 km off against 0.3 km in-process, which calibrates; in-process without the
        # calibration, 0.9 km. Table 3's constant bias (set_bias) stays GPS-only.
        app.mission.set_start_fix(config.gps_sigma_m if source in ("GPS", "NAV_START") else None,
                                  calibrate=source in ("GPS", "NAV_START"))
        app.mission_no += 1
        app.resume.new_mission()
        self.was_following = True
        app.machine.fire(Event.ENGAGED)
        app.last_phase = ""
        app.out.say(f"FcMPC: mission {app.mission_no} start {lat:.4f},{lon:.4f} ({source})")
        elements = ELEMENT_SETS[app.elements_code]
        aside = f"; {elements.f_condition}" if uses_filter(config) and elements.f_condition else ""
        app.out.say(f"FcMPC: elements {elements.label}: {why}{aside}"[:200])
        if calibration:
            app.out.say(f"FcMPC: {calibration}"[:200])
        app.stepper.step(app.m0, window_limit_s=0.0, avg=startup)
        say_how_it_navigates(app, config)

    # ------------------------------------------------------------------ running
    def running(self, now: float, reasons: list[str], dt: float) -> bool:
        app = self.app
        fc = app.link.fc
        following = fc.armed and fc.guided
        if self.was_following and not following and not fc.guided and app.modes.confirm(fc.custom_mode, fc.last_heartbeat_time_s):
            self.our_hold = True   # the FC shows a mode we commanded (however late): ours to take back
        elif self.was_following and not following:
            # a mode change we did not ask for: the autopilot's own failsafe is waited out and the
            # mission re-engages when it clears; a pilot's or ground station's is respected, and
            # the mission waits until GUIDED/OFFBOARD is selected again
            conv = fc.conventions
            guided = conv.mode_name(conv.custom_mode(conv.guided_main, conv.guided_sub))
            self.fc_failsafe_hold = app.fc_view.fc_failsafe
            why = f"its own failsafe ({self.fc_failsafe_hold}): re-engaging when it clears" \
                if self.fc_failsafe_hold else "mission paused"
            app.out.say(f"FcMPC: FC left {guided} (now {fc.mode_name}{'' if fc.armed else ', disarmed'}): {why}"[:200],
                        mavlink.MAV_SEVERITY_WARNING)
        if following:
            self.fc_failsafe_hold = ""
            self.our_hold = False
            if not self.was_following and app.command is not None and app.command.speed_mps > 0.0:
                app.mag.yaw_offset.new_course(now)   # moving again after a hold: a new record for the trim
        self.was_following = following
        flying = following and not app.operator.held     # the operator's hold counts as not following
        app.stepper.advance_dead_reckoning(now, dt, flying and not reasons)
        if reasons or not flying:
            app.clock.pause(app.now)
        else:
            app.clock.resume(app.now)   # pending mode commands stay: a late HOLD of ours is still ours
        if reasons:
            return False
        if app.operator.held:
            return app.operator.held_tick(now, following)
        # the stream first: its cadence is the FC's proof of life (PX4 leaves OFFBOARD after
        # COM_OF_LOSS_T without one), whatever the step below costs
        sent = app.out.stream_command(app.command) if app.command is not None else False
        if not following:
            if self.our_hold or (self.fc_failsafe_hold and not app.fc_view.fc_failsafe):
                self.engage(now)   # our failsafe's hold, or the FC's own failsafe cleared: take it back
            return sent
        if app.mission_time(now) >= app.next_step_m:
            previous = app.command
            app.stepper.step(app.next_step_m)
            if app.state == State.RUNNING and app.command is not None and app.command is not previous:
                # the step's new command goes out now, not a tick (1 / COMP_SP_RATE_HZ) later
                sent = app.out.stream_command(app.command) or sent
        return sent

    # ------------------------------------------------------------------ running -> startup / done
    def nav_failure(self, reason: str, cmd: Command) -> None:
        app = self.app
        app.out.say(f"FcMPC FAILSAFE: {reason}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
        app.failsafe.hold_if_guided(app.now)
        app.restarts += 1
        if app.restarts > MAX_RESTARTS:
            app.command = cmd
            self.finish(cmd, failed_reason=f"{reason}; gave up after {MAX_RESTARTS} restarts", event=Event.GAVE_UP)
            return
        est = (cmd.est_lat_deg, cmd.est_lon_deg)
        if not all(math.isfinite(v) for v in est) and app.command is not None:
            est = (app.command.est_lat_deg, app.command.est_lon_deg)
        app.restart_from = est if all(math.isfinite(v) for v in est) else None
        app.mission = None
        app.command = None
        self.enter_startup(Event.NAV_FAILED, f"restart {app.restarts} after: {reason}")

    def finish(self, cmd: Command, failed_reason: str = "", event: str = Event.ENDED) -> None:
        app = self.app
        app.machine.fire(event)
        app.done_wall = time.monotonic()
        app.done_msg_s = app.now
        app.out.stream_since = math.nan
        if failed_reason:
            app.out.say(f"FcMPC: mission FAILED: {failed_reason}"[:200], mavlink.MAV_SEVERITY_ERROR)
        elif cmd.phase == Phase.ARRIVED:
            app.out.say(f"FcMPC: arrived after {cmd.step} steps, estimated {cmd.remaining_m:.0f} m to go")
        else:
            app.out.say(f"FcMPC: mission {cmd.phase}: {cmd.reason}", mavlink.MAV_SEVERITY_ERROR)
        app.reporting.record_event("done", failed_reason or cmd.reason or cmd.phase)
        app.resume.save(finished=True)
        app.failsafe.hold_if_guided(app.now)

    # ------------------------------------------------------------------ any -> startup
    def fc_rebooted(self) -> None:
        """The flight controller's clock went back (it rebooted): everything timed on its old clock is
        void, and it comes back disarmed. A running mission goes on, from its last estimate with its
        filter and step clock (:meth:`Resume.continue_after_reboot`): no new start-up average, no
        probing again, and not a navigation failure (it uses none of MAX_RESTARTS). Otherwise the
        start-up begins again (a pending resume is kept: its times are relative to the mission)."""
        app = self.app
        last_old_s = app.last_tick_time     # no tick ran since: the new clock was only just confirmed
        app.fc_reboots = app.link.clock.reboots
        app.next_tick = -math.inf
        app.last_tick_time = math.nan
        app.fc_detected_at = app.now        # the streams get their start-up grace again
        app.out.last_hb_sent = -math.inf
        app.out.next_feed_s = -math.inf
        app.intake.last_valid.clear()
        self.last_mode_cmd = self.last_arm_cmd = app.failsafe.last_hold_cmd = -math.inf
        app.modes.clear()
        self.our_hold = False
        self.fc_failsafe_hold = ""
        app.link.fc.last_heartbeat_time_s = app.now
        app.mag.attitude = None
        app.mag.settle_until_s = -math.inf
        app.decoder.fc_position = None
        app.local_ned = None
        app.stepper.dr = None
        app.fc_view.rebooted()
        app.resume.last_save_s = -math.inf
        if app.opts.request_streams:
            app.out.request_streams()       # a rebooted autopilot forgets the intervals asked for
        reason = "flight controller rebooted (its clock went back)"
        running = app.state == State.RUNNING and app.mission is not None and app.command is not None \
            and math.isfinite(last_old_s)
        if running:
            app.resume.continue_after_reboot(last_old_s)
            app.out.say(f"FcMPC: {reason}: mission {app.mission_no} goes on from its last estimate at step "
                        f"{app.command.step} once re-armed"[:200], mavlink.MAV_SEVERITY_WARNING)
        elif app.state == State.RUNNING and app.command is not None:   # no tick on the old clock to go on from
            self.nav_failure(reason, app.command)
            return
        elif app.state in (State.STARTUP, State.READY, State.CALIBRATING, State.RUNNING):
            app.out.say(f"FcMPC: {reason}", mavlink.MAV_SEVERITY_WARNING)
            app.mag.recorder = None
            app.mission = None
        else:
            return
        self.enter_startup(Event.FC_REBOOTED, reason)
        if app.resume.pending is not None:
            app.machine.fire(Event.RESUMED)


def say_how_it_navigates(app, config) -> None:
    """After the mission's first step: the position filter it runs, the ring current it removes,
    and what it steers by, each in a STATUSTEXT."""
    estimator = getattr(app.mission, "estimator", None) if app.mission is not None else None
    if estimator is not None and estimator.reason:
        app.out.say(f"FcMPC: position filter: {estimator.reason}"[:200])
    if estimator is not None and estimator.ring_current_removed:
        app.out.say(f"FcMPC: ring current removed: NAV_SYMH {estimator.symh_reference_nt:g} nT at the start, "
                    f"its change x FUS_SYMH_K {config.symh_ratio:g} along H"[:200])
    trim = app.comp_cfg.trim_max_deg
    app.out.say(f"FcMPC: steering: the measured heading, course trimmed by the FC's yaw error up to {trim:g} deg"
                if trim > 0.0 else "FcMPC: steering: the FC's yaw (COMP_TRIM_DEG 0)")

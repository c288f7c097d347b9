"""``summary.json``: the run in one record, read from the parts at the end (and by tests, any time).

A view over the whole house: it reads each part it names and changes none.
"""
from __future__ import annotations

import math
import statistics
import sys
import time
from dataclasses import asdict
from pathlib import Path

from companion.fc_view import FcView
from companion.io.link import MavlinkLink
from companion.io.param_server import ParamServer
from companion.io.records import write_summary
from companion.nav.elements import ELEMENT_SETS
from companion.nav.magnetometer import MagProcessor
from companion.nav.metrics import percentile
from companion.nav.mission import Phase
from companion.process.control_step import ControlStep
from companion.process.failsafe_response import FailsafeResponse
from companion.process.forecast import RouteForecast
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine
from companion.process.mission_state import MissionState
from companion.process.mode_commands import ModeCommands
from companion.process.operator_commands import OperatorCommands
from companion.nav.plausibility import MagPlausibility
from companion.process.resume import Resume
from companion.process.voice import Voice

__all__ = ["Summary"]


class Summary:
    """:meth:`summary` (a dict) and :meth:`write` (``summary.json`` in ``log_dir``)."""

    def __init__(self, link: MavlinkLink, machine: PhaseMachine, state: MissionState, params: ParamServer,
                 failsafe: FailsafeResponse, stepper: ControlStep, mag: MagProcessor, intake: SampleIntake, fc_view: FcView,
                 plausibility: MagPlausibility, resume: Resume, modes: ModeCommands, operator: OperatorCommands,
                 voice: Voice, forecast: RouteForecast, log_dir: Path, wall_start: float) -> None:
        self.link = link
        self.machine = machine
        self.mission_state = state
        self.params = params
        self.failsafe = failsafe
        self.stepper = stepper
        self.mag = mag
        self.intake = intake
        self.fc_view = fc_view
        self.plausibility = plausibility
        self.resume = resume
        self.modes = modes
        self.operator = operator
        self.voice = voice
        self.forecast = forecast
        self.log_dir = log_dir
        self.wall_start = wall_start     # monotonic wall time the process started

    def summary(self) -> dict:
        state, link, intake = self.mission_state, self.link, self.intake
        wall = time.monotonic() - self.wall_start
        lat, core = self.stepper.step_latency_s, self.stepper.core_latency_s
        cmd, stats, fc = state.command, link.stats, link.fc
        return {
            "state": self.machine.state, "phase": cmd.phase if cmd else "",
            "arrived": bool(cmd and cmd.phase == Phase.ARRIVED),
            "missions": state.mission_no, "restarts": state.restarts,
            "steps": cmd.step if cmd else 0,
            "est_lat_deg": cmd.est_lat_deg if cmd else math.nan,
            "est_lon_deg": cmd.est_lon_deg if cmd else math.nan,
            "est_remaining_m": cmd.remaining_m if cmd else math.nan,
            "msg_time_s": link.clock.now_s, "wall_s": round(wall, 3),
            "messages_in": stats.messages_in, "messages_from_fc": intake.messages_from_fc,
            "messages_out": stats.messages_out, "msgs_in_per_wall_s": round(stats.messages_in / max(wall, 1e-9), 1),
            "bad_frames": stats.bad_frames, "setpoints_sent": stats.setpoints_sent,
            "setpoints_refused": stats.setpoints_refused, "failsafes": self.failsafe.entered,
            "step_latency_median_s": statistics.median(lat) if lat else math.nan,
            "step_latency_p99_s": percentile(lat, 0.99),
            "core_latency_median_s": statistics.median(core) if core else math.nan,
            "mag": {**self.mag.stats.as_dict(), "invalid": intake.invalid_mag},
            "param_load_error": self.params.load_error,
            "sensors": intake.summary(),
            "link": {**link.counters(), "param_sets_from_strangers": self.params.sets_from_strangers},
            "fc": {"autopilot": fc.conventions.name, "sysid": fc.sysid, "mode": fc.mode_name, "armed": fc.armed,
                   "heading": self.heading_summary(), "positions_fed": stats.positions_fed,
                   "arming_refusals": self.fc_view.arming.refusals},
            "elements": ELEMENT_SETS[state.elements_code].label if state.elements_code else "",
            "bias": list(state.bias) if state.bias is not None else None, "calibration": state.calibration,
            "mag_excluded_steps": self.plausibility.excluded, "resumed_from": self.resume.resumed_from,
            # the current mission's rejections: periods the navigator rejected, fixes beyond its gate
            "nav_rejected": {"periods": getattr(state.mission, "rejected_measurements", 0),
                             "fixes": getattr(state.mission, "rejected_fixes", 0)},
            "mode_commands": {"confirmed": self.modes.confirmed, "expired": self.modes.expired,
                              "pending": sorted(p.name for p in self.modes.pending.values())},
            "operator": {"held": self.operator.held, "start_requested": self.operator.start_requested,
                         "commands": self.operator.received},
            # what the operator was told before flying (companion.process.forecast), as said
            "route_prediction": asdict(self.forecast.said) if self.forecast.said is not None else None,
            "events": self.voice.events[-200:], "log_dir": str(self.log_dir),
        }

    def heading_summary(self) -> str:
        verdict = self.fc_view.heading_verdict(self.link.clock.now_s) if self.link.fc.detected else None
        if verdict is None:
            return "unknown"
        return ("compass-derived: " if verdict.compass_derived else "independent: ") + verdict.reason

    def write(self) -> None:
        try:
            write_summary(self.log_dir / "summary.json", self.summary())
        except OSError as err:  # pragma: no cover
            print(f"fcmpc-companion: cannot write summary: {err}", file=sys.stderr)

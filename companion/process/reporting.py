"""Records (``--log-dir``): a row of ``steps.csv`` per control step and per event (``summary.json``
is :mod:`companion.process.summary`'s).

The files' formats are :mod:`companion.io.records`'s; this part says what goes in them.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

from companion.io.link.clock import MessageClock
from companion.io.records import StepRecorder
from companion.nav.magnetometer import MagProcessor
from companion.nav.mission import Command, Measurement
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.options import GPS_START_MAX_AGE_S
from companion.nav.plausibility import Judgement

__all__ = ["Reporting", "plausibility_record"]


class Reporting:
    """steps.csv, open between :meth:`open` and :meth:`close`."""

    def __init__(self, msg_clock: MessageClock, clock: MissionClock, state: MissionState, machine: PhaseMachine,
                 mag: MagProcessor, intake: SampleIntake) -> None:
        self.msg_clock = msg_clock
        self.clock = clock
        self.mission_state = state
        self.machine = machine
        self.mag = mag
        self.intake = intake
        self.recorder: StepRecorder | None = None

    def open(self, path: Path) -> None:
        self.recorder = StepRecorder(path)

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()

    def record_step(self, cmd: Command, meas: Measurement, avg, ins_source: str, latency: float, event: str,
                    reason: str, sent_course_rad: float, judgement: Judgement | None) -> None:
        """A control step's row: ``sent_course_rad`` the course streamed for ``cmd`` (trimmed),
        ``judgement`` the period's plausibility verdict (None: not judged)."""
        if self.recorder is None:
            return
        st = self.mag.stats
        self.recorder.write({
            "wall_time_s": time.time(), "msg_time_s": self.msg_clock.now_s, "mission_time_s": meas.time_s,
            "mission": self.mission_state.mission_no, "step": cmd.step, "phase": cmd.phase, "decl_deg": meas.decl_deg,
            "incl_deg": meas.incl_deg, "f_nt": meas.f_nt, "samples": avg.count, "window_s": meas.window_s, "spikes": st.spikes,
            "invalid": st.non_finite + self.intake.invalid_mag, "ins_lat_deg": meas.ins_lat_deg,
            "ins_lon_deg": meas.ins_lon_deg, "ins_source": ins_source, "est_lat_deg": cmd.est_lat_deg,
            "est_lon_deg": cmd.est_lon_deg, "est_sigma_m": cmd.est_sigma_m, "fix_lat_deg": cmd.fix_lat_deg,
            "fix_lon_deg": cmd.fix_lon_deg, "fused": cmd.fused, "remaining_m": cmd.remaining_m,
            "course_deg": math.degrees(cmd.course_rad), "speed_mps": cmd.speed_mps, "solver_ok": cmd.solver_ok,
            "solver_time_s": cmd.solver_time_s, "step_latency_s": latency, "event": event, "reason": reason,
            "mag_heading_deg": meas.mag_heading_deg, "sent_course_deg": math.degrees(sent_course_rad),
            **self.gps_record(), **plausibility_record(meas, judgement)})

    def gps_record(self) -> dict:
        """GPS at the step, for the record only (a reference where the receiver still has a fix)."""
        gps = self.intake.last_gps
        if gps is None or self.msg_clock.now_s - gps.time_s > GPS_START_MAX_AGE_S:
            return {"gps_fix": 0}
        return {"gps_fix": gps.fix_type, "gps_lat_deg": gps.lat_deg if gps.fix_type >= 2 else math.nan,
                "gps_lon_deg": gps.lon_deg if gps.fix_type >= 2 else math.nan}

    def record_event(self, event: str, reason: str, **columns: float) -> None:
        """One row of ``steps.csv`` for an event; ``columns``: more of its columns (e.g. the
        measurement of an excluded step, so a reader can tell why it jumped)."""
        if self.recorder is None:
            return
        state, now = self.mission_state, self.msg_clock.now_s
        self.recorder.write({"wall_time_s": time.time(), "msg_time_s": now,
                             "mission_time_s": self.clock.mission_time(now) - state.m0 if math.isfinite(state.m0)
                             else math.nan,
                             "mission": state.mission_no, "step": state.mission.k if state.mission else 0,
                             "phase": self.machine.state, "event": event, "reason": reason, **columns})


def plausibility_record(meas: Measurement, judged: Judgement | None) -> dict:
    """The inclination's standard error and the period's plausibility verdict (jump, bound, noise
    term): the same columns for a step flown and for a period excluded."""
    return {"incl_se_deg": meas.incl_se_deg,
            "jump_m": judged.jump_m if judged else math.nan, "bound_m": judged.bound_m if judged else math.nan,
            "noise_m": judged.noise_m if judged else math.nan}

"""Records (``--log-dir``): a row of ``steps.csv`` per control step and per event, and ``summary.json``;
with ``--http`` the status page, which shows the state and serves the records (:mod:`companion.process.status`).

The files' formats are :mod:`companion.io.records`'s; this part says what goes in them.
"""
from __future__ import annotations

import math
import statistics
import sys
import time
from pathlib import Path

from companion.io.records import StepRecorder, write_summary
from companion.nav.elements import ELEMENT_SETS
from companion.nav.mission import Command, Measurement, Phase
from companion.process.options import GPS_START_MAX_AGE_S
from companion.process.status import StatusPublisher

__all__ = ["Reporting", "percentile"]


def percentile(values: list[float], q: float) -> float:
    """The ``q``-quantile by the nearest-rank rule (NaN for no values).

    >>> percentile([3.0, 1.0, 2.0], 0.5), percentile([], 0.5)
    (2.0, nan)
    """
    if not values:
        return math.nan
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))
    return ordered[k]


class Reporting:
    """steps.csv (open between :meth:`open` and :meth:`close`) and summary.json."""

    def __init__(self, app) -> None:   # the CompanionApp wiring this part
        self.app = app
        self.recorder: StepRecorder | None = None
        self.status = StatusPublisher.for_options(app)   # --http: its port bound now (in use: OSError)

    def open(self, path: Path) -> None:
        self.status.start()   # before steps.csv: once the file exists, the page answers
        self.recorder = StepRecorder(path)

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
        self.status.stop()

    def publish_status(self, wall: float) -> None:
        """The loop's idle hook: the status page's snapshot, at most every PUBLISH_WALL_S."""
        self.status.maybe_publish(wall)

    def record_step(self, cmd: Command, meas: Measurement, avg, ins_source: str, latency: float, event: str,
                    reason: str) -> None:
        app = self.app
        if self.recorder is None:
            return
        st = app.mag.stats
        self.recorder.write({
            "wall_time_s": time.time(), "msg_time_s": app.now, "mission_time_s": meas.time_s,
            "mission": app.mission_no, "step": cmd.step, "phase": cmd.phase, "decl_deg": meas.decl_deg,
            "incl_deg": meas.incl_deg, "f_nt": meas.f_nt, "samples": avg.count, "window_s": meas.window_s, "spikes": st.spikes,
            "invalid": st.non_finite + app.intake.invalid_mag, "ins_lat_deg": meas.ins_lat_deg,
            "ins_lon_deg": meas.ins_lon_deg, "ins_source": ins_source, "est_lat_deg": cmd.est_lat_deg,
            "est_lon_deg": cmd.est_lon_deg, "est_sigma_m": cmd.est_sigma_m, "fix_lat_deg": cmd.fix_lat_deg,
            "fix_lon_deg": cmd.fix_lon_deg, "fused": cmd.fused, "remaining_m": cmd.remaining_m,
            "course_deg": math.degrees(cmd.course_rad), "speed_mps": cmd.speed_mps, "solver_ok": cmd.solver_ok,
            "solver_time_s": cmd.solver_time_s, "step_latency_s": latency, "event": event, "reason": reason,
            "mag_heading_deg": meas.mag_heading_deg, "sent_course_deg": math.degrees(app.out.course_to_send(cmd)),
            **self.gps_record(), **self.plausibility_record(meas)})

    def plausibility_record(self, meas: Measurement) -> dict:
        """The inclination's standard error and the period's plausibility verdict (jump, bound, noise
        term): the same columns for a step flown and for a period excluded."""
        judged = self.app.stepper.judgement
        return {"incl_se_deg": meas.incl_se_deg,
                "jump_m": judged.jump_m if judged else math.nan, "bound_m": judged.bound_m if judged else math.nan,
                "noise_m": judged.noise_m if judged else math.nan}

    def gps_record(self) -> dict:
        """GPS at the step, for the record only (a reference where the receiver still has a fix)."""
        app = self.app
        gps = app.intake.last_gps
        if gps is None or app.now - gps.time_s > GPS_START_MAX_AGE_S:
            return {"gps_fix": 0}
        return {"gps_fix": gps.fix_type, "gps_lat_deg": gps.lat_deg if gps.fix_type >= 2 else math.nan,
                "gps_lon_deg": gps.lon_deg if gps.fix_type >= 2 else math.nan}

    def record_event(self, event: str, reason: str, **columns: float) -> None:
        """One row of ``steps.csv`` for an event; ``columns``: more of its columns (e.g. the
        measurement of an excluded step, so a reader can tell why it jumped)."""
        app = self.app
        if self.recorder is None:
            return
        self.recorder.write({"wall_time_s": time.time(), "msg_time_s": app.now,
                             "mission_time_s": app.mission_time() - app.m0 if math.isfinite(app.m0) else math.nan,
                             "mission": app.mission_no, "step": app.mission.k if app.mission else 0,
                             "phase": app.state, "event": event, "reason": reason, **columns})

    def summary(self) -> dict:
        app = self.app
        wall = time.monotonic() - app.wall_start
        lat, core = app.stepper.step_latency_s, app.stepper.core_latency_s
        cmd, stats = app.command, app.link.stats
        return {
            "state": app.state, "phase": cmd.phase if cmd else "",
            "arrived": bool(cmd and cmd.phase == Phase.ARRIVED),
            "missions": app.mission_no, "restarts": app.restarts,
            "steps": cmd.step if cmd else 0,
            "est_lat_deg": cmd.est_lat_deg if cmd else math.nan,
            "est_lon_deg": cmd.est_lon_deg if cmd else math.nan,
            "est_remaining_m": cmd.remaining_m if cmd else math.nan,
            "msg_time_s": app.now, "wall_s": round(wall, 3),
            "messages_in": stats.messages_in, "messages_from_fc": app.messages_from_fc,
            "messages_out": stats.messages_out, "msgs_in_per_wall_s": round(stats.messages_in / max(wall, 1e-9), 1),
            "bad_frames": stats.bad_frames, "setpoints_sent": stats.setpoints_sent,
            "setpoints_refused": stats.setpoints_refused, "failsafes": app.health.entered,
            "step_latency_median_s": statistics.median(lat) if lat else math.nan,
            "step_latency_p99_s": percentile(lat, 0.99),
            "core_latency_median_s": statistics.median(core) if core else math.nan,
            "mag": {**app.mag.stats.as_dict(), "invalid": app.intake.invalid_mag},
            "param_load_error": app.params.load_error,
            "sensors": app.intake.summary(),
            "link": {**app.link.counters(), "param_sets_from_strangers": app.params.sets_from_strangers},
            "fc": {"autopilot": app.link.fc.conventions.name, "sysid": app.link.fc.sysid,
                   "mode": app.link.fc.mode_name, "armed": app.link.fc.armed,
                   "heading": self.heading_summary(), "positions_fed": stats.positions_fed,
                   "arming_refusals": app.fc_view.arming.refusals},
            "elements": ELEMENT_SETS[app.elements_code].label if app.elements_code else "",
            "bias": list(app.bias) if app.bias is not None else None,
            "mag_excluded_steps": app.plausibility.excluded, "resumed_from": app.resume.resumed_from,
            # the current mission's rejections: periods the navigator rejected, fixes beyond its gate
            "nav_rejected": {"periods": getattr(app.mission, "rejected_measurements", 0),
                             "fixes": getattr(app.mission, "rejected_fixes", 0)},
            "mode_commands": {"confirmed": app.modes.confirmed, "expired": app.modes.expired,
                              "pending": sorted(p.name for p in app.modes.pending.values())},
            "operator": {"held": app.operator.held, "start_requested": app.operator.start_requested,
                         "commands": app.operator.received},
            "events": app.out.events[-200:], "log_dir": str(app.log_dir),
        }

    def heading_summary(self) -> str:
        app = self.app
        verdict = app.fc_view.heading_verdict(app.now) if app.link.fc.detected else None
        if verdict is None:
            return "unknown"
        return ("compass-derived: " if verdict.compass_derived else "independent: ") + verdict.reason

    def write_summary(self) -> None:
        try:
            write_summary(self.app.log_dir / "summary.json", self.summary())
        except OSError as err:  # pragma: no cover
            print(f"fcmpc-companion: cannot write summary: {err}", file=sys.stderr)

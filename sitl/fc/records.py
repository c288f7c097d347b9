"""The stand-in's records: ``truth.csv`` (the truth only the simulator knows), the tlog and the summary.

``truth.csv`` (:class:`sitl.truthlog.TruthLog`) gets one row per ``1 / log_rate_hz`` simulated
seconds: true and commanded motion, the flight controller's solution and its error, the field
and its storm part, the companion's estimate when it sends one, the active faults and the
remaining distance. The tlog holds every frame sent and received, stamped with the scenario's
start plus simulated time. The summary (counters, rates, final state) goes to
``summary.json`` and, unless quiet, to stderr. Records default to ``out/sitl/<scenario>-<time>-<pid>``.
"""
from __future__ import annotations

import json
import math
import os
import sys
from datetime import datetime
from pathlib import Path

from companion import wrap_2pi
from companion.nav.geo import geodesic_inverse
from sitl.truthlog import TlogWriter, TruthLog
from sitl.world.magnetic import decl_incl_from_ned

__all__ = ["Records", "format_summary", "write_summary"]


class Records:
    """The run's folder, its truth log and its tlog (each optional)."""

    def __init__(self, config, scenario_name: str) -> None:
        self.log_dir = self._resolve_log_dir(config, scenario_name)
        self.truth_log = TruthLog(self.log_dir / "truth.csv") if config.truth_log else None
        tlog_path = config.tlog
        if tlog_path is not None:
            tlog_path = self.log_dir / "sitl.tlog" if tlog_path == "" else Path(tlog_path)
        self.tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        self.last_log_us = -1

    @staticmethod
    def _resolve_log_dir(config, scenario_name: str) -> Path:
        if config.log_dir:
            path = Path(config.log_dir)
        else:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            path = Path("out") / "sitl" / f"{scenario_name}-{stamp}-{os.getpid()}"
        if config.truth_log or config.tlog == "":
            path.mkdir(parents=True, exist_ok=True)
        return path

    @property
    def enabled(self) -> bool:
        return self.truth_log is not None or self.tlog is not None

    def write_truth(self, vehicle, guidance, faults) -> None:
        """One truth.csv row at the vehicle's clock time."""
        v = vehicle
        s = v.state
        t = v.clock.time_s
        if v.field_us < 0:
            v.update_field()
        fc_lat, fc_lon = v.fc_position()
        err_e, err_n = v.nav.error_m(t, s.lat_deg, s.lon_deg)
        decl, incl = decl_incl_from_ned(*v.field)
        att = v.true_attitude()
        g = guidance
        sc = v.scenario
        # Vincenty (within 0.1 mm): geographiclib's Inverse here was a tenth of the simulator's time
        remaining = geodesic_inverse(s.lat_deg, s.lon_deg, sc.dest_lat_deg, sc.dest_lon_deg)[0]
        est = v.ext_estimate
        self.last_log_us = v.clock.t_us
        self.truth_log.write({
            "time_s": t, "lat_deg": s.lat_deg, "lon_deg": s.lon_deg,
            "course_deg": math.degrees(s.course_rad), "speed_mps": s.speed_mps,
            "vn_mps": s.vel_north_mps, "ve_mps": s.vel_east_mps,
            "roll_deg": math.degrees(att.roll_rad), "pitch_deg": math.degrees(att.pitch_rad),
            "cmd_course_deg": math.degrees(wrap_2pi(v.cmd[0])), "cmd_speed_mps": float(v.cmd[1]),
            "mode": g.mode, "armed": int(g.armed), "fc_lat_deg": fc_lat, "fc_lon_deg": fc_lon,
            "fc_err_e_m": float(err_e), "fc_err_n_m": float(err_n), "gps_fix": int(v.gps_fix),
            "field_n_nt": v.field[0], "field_e_nt": v.field[1], "field_d_nt": v.field[2],
            "dist_n_nt": v.dist[0], "dist_e_nt": v.dist[1], "dist_d_nt": v.dist[2],
            "decl_deg": float(decl), "incl_deg": float(incl), "distance_m": s.distance_m,
            "remaining_m": remaining,
            "est_lat_deg": est[0] if est else None, "est_lon_deg": est[1] if est else None,
            "faults": faults.describe(), "boot_s": v.clock.boot_ms * 1e-3,
        })

    def finish(self, vehicle, guidance, faults) -> None:
        """A last truth row at the final instant (if not just written), then close the files."""
        try:
            if self.truth_log is not None and self.last_log_us != vehicle.clock.t_us:
                self.write_truth(vehicle, guidance, faults)
        except Exception:  # pragma: no cover - never lose the summary for a log row
            pass
        for record in (self.truth_log, self.tlog):
            if record is not None:
                record.close()


def write_summary(summary: dict, path: str | None) -> None:
    """Write the summary as JSON (an error is reported, never raised: the run is over)."""
    if not path:
        return
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    except OSError as err:
        print(f"fcmpc-sitl: cannot write {path}: {err}", file=sys.stderr)


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

"""The evaluation's results: one dataclass per table row and the whole evaluation."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fcmpc.replay.segments import Segments

__all__ = ["DIRow", "WindowRecord", "FixRow", "InsRow", "FusedRow", "HeadingRow", "ReplayEvaluation"]

@dataclass
class DIRow:
    segment: str
    start_s: float
    end_s: float
    n: int
    decl_meas_deg: float
    decl_wmm_deg: float
    decl_bias_deg: float
    decl_std_deg: float
    incl_meas_deg: float
    incl_wmm_deg: float
    incl_bias_deg: float
    incl_std_deg: float
    f_bias_nt: float
    judged: bool


@dataclass
class WindowRecord:
    """One averaging window of the navigation span, for one window length."""

    window_s: float
    start_s: float
    end_s: float
    centre_s: float
    count: int
    decl_deg: float
    incl_deg: float
    err_decl_deg: float
    err_incl_deg: float
    predicted_m: float
    predicted_noise_m: float = math.nan
    fix_error_m: float = math.nan
    fix_failed: str = ""
    ins_error_m: float = math.nan
    fused_error_m: float = math.nan
    fused_sigma_m: float = math.nan
    command_phase: str = ""
    command_course_deg: float = math.nan
    flown_course_deg: float = math.nan
    ideal_course_deg: float = math.nan
    mission_est_error_m: float = math.nan
    decl_se_deg: float = math.nan      # the standard errors of the window's D and I from its scatter
    incl_se_deg: float = math.nan


@dataclass
class FixRow:
    window_s: float
    n: int
    failed: int
    err_decl_mean_deg: float
    err_decl_std_deg: float
    err_incl_mean_deg: float
    err_incl_std_deg: float
    fix_median_m: float
    fix_p90_m: float
    predicted_median_m: float
    predicted_p90_m: float
    ratio_median: float
    ratio_min: float
    ratio_max: float
    predicted_noise_median_m: float


@dataclass
class InsRow:
    name: str
    start_s: float
    errors_m: dict[str, float]


@dataclass
class FusedRow:
    window_s: float
    steps: int
    fused_median_m: float
    fused_p90_m: float
    fused_final_m: float
    ins_median_m: float
    fix_median_m: float
    sigma_final_m: float


@dataclass
class HeadingRow:
    window_s: float
    steps: int
    compared: int
    median_abs_diff_deg: float
    ideal_median_abs_diff_deg: float
    final_phase: str
    reason: str
    est_error_median_m: float
    excluded: int = 0            # windows the navigator's plausibility judge excluded (the last command flew on)


@dataclass
class ReplayEvaluation:
    log: str
    format: str
    model: str
    model_note: str
    date: str | None
    decimal_year: float
    mag_instance: int
    counts: dict[str, int]
    first_s: dict[str, float]
    last_s: dict[str, float]
    flagged: dict[str, int]
    truncated: bool
    end_detail: str
    segments: Segments
    gradient_deg_per_km: list[list[float]]
    gradient_singular_deg_per_km: list[float]
    wmm_at_start: dict[str, float]
    spikes_rejected: int
    di_rows: list[DIRow]
    fix_rows: list[FixRow]
    ins_rows: list[InsRow]
    fused_rows: list[FusedRow]
    heading_rows: list[HeadingRow]
    windows: list[WindowRecord]
    mission_note: str
    prior_offset_m: tuple[float, float]
    mag_rate_hz: float = math.nan
    source_note: str = ""
    date_source: str = ""
    date_note: str = ""
    boot: int = 0
    boots: int = 1
    imu_rate_hz: float = math.nan
    f_ratio: float = math.nan
    warnings: list[str] = field(default_factory=list)
    flight: int = 0  # 1-based number of the flight in its boot; 0 for a recording that is not a flight
    flights: int = 0
    # the magnetometer calibration fitted on the boot and applied (fcmpc-replay's default): its
    # description or why it was refused, and the fix rows (one per window length) before it
    calibration: str = ""
    fix_rows_before: list[FixRow] = field(default_factory=list)
    # time series for the plots (not in summary.json)
    series: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def span_s(self) -> tuple[float, float]:
        return min(self.first_s.values()), max(self.last_s.values())

    @property
    def is_flight(self) -> bool:
        """True when the judged span is airborne (a take-off was found)."""
        return self.segments.takeoff_s is not None

    @property
    def uncalibrated(self) -> bool:
        return any(w.startswith("UNCALIBRATED") for w in self.warnings)

    def di_row(self, segment: str) -> DIRow | None:
        return next((r for r in self.di_rows if r.segment == segment), None)

    def fix_row(self, window_s: float) -> FixRow | None:
        return next((r for r in self.fix_rows if r.window_s == window_s), None)

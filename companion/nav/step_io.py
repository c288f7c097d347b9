"""What one step of the mission takes in and gives out: :class:`Measurement`, :class:`Command`, :class:`Phase`.

Plain frozen data, so the companion, the simulator and the Monte Carlo build and read them
without the mission itself (:mod:`companion.nav.mission` re-exports all three). Units per
:mod:`companion`: angles in degrees where a name says so, else radians; courses from north,
clockwise; positions in degrees, distances in metres, speeds in m/s, time in message seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Command", "Measurement", "Phase"]


class Phase:
    PROBE_1 = "probe1"
    PROBE_2 = "probe2"
    CRUISE = "cruise"
    HOLD = "hold"            # a bad measurement: stop and wait for the next one
    ARRIVED = "arrived"
    FAILED = "failed"


@dataclass(frozen=True)
class Measurement:
    """Inputs of one step.

    ``time_s``: message time at the end of the step. ``decl_deg``, ``incl_deg``, ``f_nt``: D, I
    and the total intensity F averaged over the last ``window_s`` seconds (0: an instantaneous
    value); the mission uses the two of its element set (NAV_ELEMENTS) and refers them to the
    centre of that window, half a window back along the move. INS position in degrees, NaN when
    the source has none (or when it is not independent of this navigator: GPS-aided, or our
    own estimate fed back).

    ``decl_se_deg`` ... ``z_se_nt``: the standard error of each period average, measured from the
    period's own scatter (NaN when not measured); the error-state filter takes its measurement
    noise from them (``FUS_R_SRC`` 1, :meth:`ElementSet.standard_errors`).

    ``mag_heading_deg``: the magnetic heading the vehicle held over the period, from its own
    magnetometer levelled by its accelerometer (:mod:`companion.nav.heading`), NaN when not
    measured; with ``NAV_DR_HDG`` 1 the mission dead-reckons the period on it plus the model's D.

    ``kp``: the planetary geomagnetic index Kp (0-9) a space-weather service gives for now, NaN
    when none reaches the vehicle; at or above ``FUS_KP_ON`` the navigation filter takes a
    storm as on (:mod:`companion.nav.disturbance`). ``symh_nt``: the ring-current index SYM-H
    (nT) over the period, NaN when none reaches the vehicle; the filter removes the ring current's
    change since the start from the elements (:mod:`companion.nav.ring_current`).
    """

    time_s: float
    decl_deg: float
    incl_deg: float
    ins_lat_deg: float = math.nan
    ins_lon_deg: float = math.nan
    window_s: float = 0.0
    f_nt: float = math.nan
    h_nt: float = math.nan
    z_nt: float = math.nan
    decl_se_deg: float = math.nan
    incl_se_deg: float = math.nan
    f_se_nt: float = math.nan
    h_se_nt: float = math.nan
    z_se_nt: float = math.nan
    mag_heading_deg: float = math.nan
    kp: float = math.nan
    symh_nt: float = math.nan

    @property
    def has_ins(self) -> bool:
        """The measurement carries an (independent) INS position."""
        return math.isfinite(self.ins_lat_deg) and math.isfinite(self.ins_lon_deg)


@dataclass(frozen=True)
class Command:
    """Output of one step: fly ``course_rad`` at ``speed_mps`` until the next step."""

    time_s: float
    step: int
    phase: str
    course_rad: float
    speed_mps: float
    done: bool
    est_lat_deg: float
    est_lon_deg: float
    est_sigma_m: float
    remaining_m: float
    theta_rad: float = math.nan
    u_first_mps: tuple[float, float] = (math.nan, math.nan)
    compensation_mps: tuple[float, float] = (0.0, 0.0)
    fix_lat_deg: float = math.nan
    fix_lon_deg: float = math.nan
    fused: bool = False
    solver_ok: bool = True
    solver_time_s: float = 0.0
    reason: str = ""
    est_cov_en_m2: tuple[float, float, float] = (math.nan, math.nan, math.nan)   # ee, en, nn
    nis: float = math.nan           # the filter's normalised innovation squared this step
    disturbed: bool = False         # the filter judges a disturbance active (bias noise raised)
    bias: tuple[float, ...] = ()    # estimated element biases, measured minus model
    next_fix_sigma_m: float = math.nan   # est_sigma_m against the next fix (Table 3: less the shared model error)
    fix_cov_en_m2: tuple[float, float, float] = (math.nan, math.nan, math.nan)   # the fix's own (filter: biases + noise)

"""What a period must be for the navigation core to take it, what its step must leave, and the answer when not.

The core never raises on a measurement (:meth:`companion.nav.mission.Mission.step`): a period
outside the domain below is rejected before the step (:func:`screen`); a step that raised one of
:data:`MEASUREMENT_ERRORS` on the way, or left a command or state that cannot stand
(:func:`unsound`), is taken back and its period rejected, answered by :func:`held_command`: the
last command flown on, so the next step dead-reckons over the whole gap as after a period the
caller excluded. Programmer errors (TypeError, AttributeError, a bad configuration at
construction) still raise.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from companion import course_from_theta
from companion.nav.field import PositionFixError
from companion.nav.geo import offset_position
from companion.nav.step_io import Command, Measurement, Phase

__all__ = ["ELEMENT_DOMAIN", "MEASUREMENT_ERRORS", "REJECTED", "finite_filter", "held_command", "on_earth", "screen",
           "unsound"]

REJECTED = "measurement rejected"   # the reason's start when a step rejected its period
# What a measurement can make the core raise on its way (the field model asked beyond a pole, a
# covariance no longer positive definite, an overflow, non-finite QP data, a fix that did not
# converge). numpy's LinAlgError is a ValueError.
MEASUREMENT_ERRORS = (ValueError, ArithmeticError, PositionFixError)
# Where a measured element can lie (element units): beyond, no magnetometer on the Earth measured
# it (the Earth's field is 22,000-67,000 nT; 1e6 nT is beyond a magnetometer's range).
ELEMENT_DOMAIN = {"decl_deg": (-360.0, 360.0), "incl_deg": (-90.0, 90.0), "f_nt": (1.0, 1e6), "h_nt": (0.0, 1e6),
                  "z_nt": (-1e6, 1e6)}
KP_RANGE = (0.0, 9.0)                # a Kp outside is no reading: taken as none
SYMH_LOWEST_NT = -5000.0             # a SYM-H below is no reading (the 1859 storm's Dst: -850 to -1760 nT)


def on_earth(lat_deg: float, lon_deg: float) -> bool:
    """A position the field model can be asked at: finite, latitude within +-90 deg."""
    return abs(lat_deg) <= 90.0 and math.isfinite(lon_deg)


def screen(meas: Measurement, names: tuple[str, ...], values: np.ndarray,
           last_time_s: float | None) -> tuple[Measurement, str]:
    """(the period, why it is rejected: "" when it is not). ``names``, ``values``: the elements the
    mission measures and their values in the period; ``last_time_s``: the last step's time (None:
    none yet). Its time and window must be finite and its time advance; the elements finite and
    inside :data:`ELEMENT_DOMAIN`; an INS position on the Earth (latitude within +-90 deg,
    longitude within one wrap, +-360). A space-weather reading outside its range is no reading.

    >>> screen(Measurement(10.0, 4.0, 95.0), ("decl_deg", "incl_deg"), np.array([4.0, 95.0]), 0.0)[1]
    'incl_deg 95 outside [-90, 90]'
    """
    if not (math.isfinite(meas.time_s) and math.isfinite(meas.window_s)):
        return meas, "non-finite measurement time or window"
    for name, value in zip(names, values.tolist()):
        low, high = ELEMENT_DOMAIN[name]
        if not low <= value <= high:   # NaN too
            return meas, f"{name} {value:.6g} outside [{low:g}, {high:g}]"
    if last_time_s is not None and meas.time_s <= last_time_s:
        return meas, "measurement time did not advance"
    if meas.has_ins and not (abs(meas.ins_lat_deg) <= 90.0 and abs(meas.ins_lon_deg) <= 360.0):
        return meas, f"INS position ({meas.ins_lat_deg:.6g}, {meas.ins_lon_deg:.6g}) deg off the Earth"
    kp_off = math.isfinite(meas.kp) and not KP_RANGE[0] <= meas.kp <= KP_RANGE[1]
    symh_off = math.isfinite(meas.symh_nt) and meas.symh_nt < SYMH_LOWEST_NT
    if kp_off or symh_off:
        meas = replace(meas, kp=math.nan if kp_off else meas.kp, symh_nt=math.nan if symh_off else meas.symh_nt)
    return meas, ""


def finite_filter(kf) -> bool:
    """A Kalman filter (filterpy's) whose state and covariance are finite numbers."""
    return bool(np.isfinite(kf.x).all() and np.isfinite(kf.P).all())


def unsound(command: Command, speed_mps: float, state_finite: bool) -> str:
    """Why a step's result cannot stand ("" when it can): a non-finite command or one beyond
    [0, ``speed_mps``], an estimate off the Earth, a state no longer finite (``state_finite``)."""
    if not (math.isfinite(command.course_rad) and 0.0 <= command.speed_mps <= speed_mps * (1.0 + 1e-9)):
        return f"command course {command.course_rad!r} rad, speed {command.speed_mps!r} m/s"
    if not on_earth(command.est_lat_deg, command.est_lon_deg):
        return f"the estimate left the Earth: ({command.est_lat_deg:.6g}, {command.est_lon_deg:.6g}) deg"
    if not state_finite:
        return "the position filter's state or covariance is no longer finite"
    return ""


def held_command(time_s: float, why: str, last, est: tuple[float, float], step: int, speed_mps: float,
                 fields: dict) -> Command:
    """The answer to a rejected period at ``time_s``: phase HOLD, the reason :data:`REJECTED`: ``why``,
    the last command (``last``: the mission's last step, None before the first: no move) flown on
    within ``speed_mps``, the estimate ``est`` dead-reckoned along it to ``time_s`` (kept where
    that would leave the Earth); ``fields``: the filter's own (its covariance, biases)."""
    time_s = time_s if math.isfinite(time_s) else math.nan
    (lat, lon), course, speed = est, 0.0, 0.0
    if last is not None:
        course = course_from_theta(last.theta_rad)
        flown = last.speed_mps if math.isfinite(last.speed_mps) else float(np.hypot(*last.velocity_en))
        speed = min(flown, speed_mps)
        if time_s > last.time_s:
            moved = last.velocity_en * (time_s - last.time_s)
            there = tuple(float(v) for v in offset_position(lat, lon, float(moved[0]), float(moved[1])))
            lat, lon = there if on_earth(*there) else (lat, lon)
    return Command(**{**dict(time_s=time_s, step=step, phase=Phase.HOLD, course_rad=course, speed_mps=speed,
                             done=False, est_lat_deg=lat, est_lon_deg=lon, est_sigma_m=math.nan, remaining_m=math.nan,
                             solver_ok=True, reason=f"{REJECTED}: {why}"[:150]), **fields})

"""The magnetometer's calibration manoeuvre before the mission (issue 47, COMP_CAL_TURNS).

A boat or a ground vehicle cannot be tumbled for a full 3-D calibration, and a calibration made
standing still misses the motor's field. So, with a GPS fix where it stands (fresh, or older while
the vehicle has stayed at rest since: :meth:`MissionPreparation.calibration_fix`), once armed in
GUIDED/OFFBOARD the companion drives ``COMP_CAL_TURNS`` slow full circles at the cruise speed
(the course turning at ``COMP_CAL_DPS``), records every kept magnetometer sample with the
accelerometer and gyro of its instant, and fits the hard iron and the horizontal soft iron to the
field model's H and Z at the start, levelled by the specific force with the circle's centripetal
acceleration (gyro x the cruise speed) removed
(:func:`companion.nav.circle_level.fit_circle_calibration`; the flight controller's roll and
pitch only for a sample without the IMU: ArduPilot's EKF tilt was 1.4 deg off on the circle in
lockstep, and a fit levelled with it made the mission's inclination err with the heading) (:func:`companion.nav.calibration.fit_level_calibration`; the motor's field at cruise
becomes part of the hard iron). The fit, chained onto the MAG_* the samples were corrected with,
is written to MAG_* (so the ground station sees it and the file keeps it) and said in STATUSTEXT;
then one more circle is driven with the new calibration and its average, taken with the motor
running as it will in the mission, is the start-up measurement. A full circle ends where it
began, so the mission starts at the GPS-known start. A refused fit is said with its reason and
the mission starts on the stationary start-up average taken before arming, with MAG_* unchanged.
"""
from __future__ import annotations

import math

import numpy as np

from companion.io.link import mavlink
from companion.io.param_server import ParamServer
from companion.nav.calibration import CalibrationRefused, chained, registry_values
from companion.nav.circle_level import CIRCLE_COLUMNS, fit_circle_calibration
from companion.nav.field import model_for_setting
from companion.nav.magnetometer import MagProcessor
from companion.params import validate
from companion.process.preparation import MissionPreparation
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["CalibrationTurn"]

_NAN3 = (math.nan, math.nan, math.nan)
CAL_SETTLE_S = 45.0
"""The first seconds of the circles, left out of the fit: the speed-up from rest (0.5 m/s^2 tilts the
specific force by 3 deg) and the flight controller's transient after arming. ArduPilot in lockstep,
20 and 60 km legs: the fit's residual 323 and 343 nT rms with them, 104 and 130 without the first
30 s; at 1.5 deg/s, 45 s still leaves 292 deg of heading."""


class CalibrationTurn:
    """The manoeuvre's state; the calibrating phase (:mod:`companion.process.phases.calibrating`)
    drives it and streams the velocity it returns."""

    def __init__(self, settings: Settings, mag: MagProcessor, params: ParamServer, preparation: MissionPreparation,
                 voice: Voice) -> None:
        self.settings = settings
        self.mag = mag
        self.params = params
        self.preparation = preparation
        self.voice = voice
        self.done = False            # once per process: a restart or a reboot does not circle again
        self.t0 = math.nan
        self.fitted = False          # the fit is applied; the last circle is the start-up average
        self.samples: list[tuple[float, ...]] = []   # CIRCLE_COLUMNS: body field (3), roll, pitch, force (3), gyro (3)
        self.times: list[float] = []
        self.fix = (math.nan, math.nan)   # where the field model is evaluated (wanted() latches it)

    def wanted(self) -> bool:
        """A calibration manoeuvre before this mission: asked for, not yet flown, and a place for the
        field model (:meth:`MissionPreparation.calibration_fix`: a fresh GPS fix, or the last one with
        the vehicle at rest since). Asked for but without that place, a WARNING says why before the
        mission starts, the summary keeps it, and the mission flies on with MAG_* unchanged: a
        GPS-denied start is this module's purpose, and a fix may never come back."""
        if self.settings.comp.cal_turns <= 0 or self.done:
            return False
        fix, why = self.preparation.calibration_fix()
        if fix is None:
            self.done = True
            self._outcome(f"skipped: {why}")
            self.voice.say(f"FcMPC: calibration circle skipped, MAG_* unchanged: {why}"[:200],
                           mavlink.MAV_SEVERITY_WARNING)
            return False
        self.fix = fix
        self._outcome(f"circling at {fix[0]:.4f},{fix[1]:.4f}: {why}")
        return True

    def _outcome(self, words: str) -> None:
        """What became of the calibration asked for (summary.json's ``calibration``)."""
        self.preparation.mission_state.calibration = words

    def enter(self, now: float) -> None:
        comp = self.settings.comp
        self.t0, self.fitted, self.samples, self.times = now, False, [], []
        self.mag.recorder = self._record
        self.voice.say(f"FcMPC: calibrating the magnetometer: {comp.cal_turns} circle(s) at "
                       f"{comp.cal_rate_dps:g} deg/s, then one for the start-up average")

    def _record(self, time_s: float, calibrated, roll: float, pitch: float, imu=None) -> None:
        force, gyro = (imu[1], imu[2]) if imu is not None else (_NAN3, _NAN3)
        self.samples.append((*calibrated, roll, pitch, *force, *gyro))
        self.times.append(time_s)

    def turned_rad(self, now: float) -> float:
        return math.radians(self.settings.comp.cal_rate_dps) * (now - self.t0)

    def tick(self, now: float, reasons: list[str]) -> tuple[tuple[float, float] | None, bool]:
        """(this tick's velocity on the circle to stream, None: none; finished: the start-up
        average is ready)."""
        if reasons:
            return None, False
        turns = self.settings.comp.cal_turns
        turned = self.turned_rad(now)
        if not self.fitted and turned >= 2.0 * math.pi * turns:
            self._fit()
        if self.fitted and turned >= 2.0 * math.pi * (turns + 1):
            self.mag.recorder = None
            self.done = True
            return None, True
        return self.velocity(now), False

    def velocity(self, now: float) -> tuple[float, float]:
        """(course from north, rad; speed, m/s) on the circle now: turning right from north."""
        return self.turned_rad(now) % (2.0 * math.pi), self.settings.nav.speed_mps

    def _fit(self) -> None:
        self.fitted = True
        self.mag.recorder = None
        lat, lon = self.fix   # not the start now: the GPS may have been cut during the circle
        c = self.settings.nav
        model = model_for_setting(c.year, c.wmm).elements(lat, lon, c.alt_m, c.year)
        rows = np.array(self.samples, dtype=float).reshape(-1, CIRCLE_COLUMNS)
        rows = rows[np.array(self.times, dtype=float) >= self.t0 + CAL_SETTLE_S]   # past the speed-up
        try:
            fit, by_accelerometer = fit_circle_calibration(rows, c.speed_mps, float(model.h_nt), float(model.z_nt))
            values = {name: validate(name, value) for name, value in
                      registry_values(chained(self.mag.calibration, fit)).items()}
        except (CalibrationRefused, ValueError) as err:
            self._outcome(f"refused: {str(err).splitlines()[0]}")
            self.voice.say(f"FcMPC: magnetometer calibration refused, MAG_* unchanged: {str(err).splitlines()[0]}"[:200],
                           mavlink.MAV_SEVERITY_WARNING)
            return
        for name, value in values.items():
            self.params.set_value(name, value)
        self.settings.apply()
        self._outcome(f"fitted at {lat:.4f},{lon:.4f}: residual {fit.residual_nt:.0f} nT rms")
        self.mag.clear()          # the start-up average: the next circle, with the new calibration
        ofs = ", ".join(f"{values[f'MAG_OFS_{a}']:+.0f}" for a in "XYZ")
        level = "accelerometer" if by_accelerometer else "attitude"
        self.voice.say(f"FcMPC: magnetometer calibrated on {len(rows)} samples: residual {fit.residual_nt:.0f} nT rms, "
                       f"{100.0 * fit.cell_share:.0f} % of headings, level by {level}; MAG_OFS {ofs} mG, soft iron "
                       f"{values['MAG_SCALE_X']:.3f} {values['MAG_SCALE_Y']:.3f} {values['MAG_SOFT_XY']:+.3f}"[:200])

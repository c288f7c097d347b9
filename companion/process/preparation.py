"""Start-up and mission preparation: where the mission starts, on which elements, with which bias.

The start is the GPS fix if the receiver has a 3D fix, else the last estimate after a restart,
else NAV_START_LAT/LON. The element set is NAV_ELEMENTS resolved against the flight controller's
heading source (never D with a compass-derived yaw). With a GPS-known start and NAV_CALIBRATE 1,
the start-up average minus the model there becomes the bias subtracted from every measurement.
The mission (QP set-up, field model) is built while waiting to be armed (:meth:`prepare`).
"""
from __future__ import annotations

import math
from dataclasses import replace

from companion.fc_view import FcView
from companion.io.link.clock import MessageClock
from companion.nav.elements import ELEMENT_NAMES, ELEMENT_SETS, ElementSet, resolve_elements
from companion.nav.field import model_for_setting
from companion.nav.geo import geodesic_inverse
from companion.nav.mission import Mission
from companion.nav.period import measured_inclination
from companion.params import NavConfig
from companion.process.forecast import RouteForecast
from companion.process.intake import SampleIntake
from companion.process.mission_state import MissionState
from companion.process.options import FC_POSITION_MAX_AGE_S, GPS_START_MAX_AGE_S
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["AT_REST_M", "AT_REST_MPS", "PREPARED_START_M", "MissionPreparation"]

PREPARED_START_M = 100.0          # a mission built while READY serves a start this close
AT_REST_M = 500.0
"""A vehicle whose flight controller puts it this close to its last GPS fix (and slower than
AT_REST_MPS) has not moved since: the fix still places the calibration's field model. The World
Magnetic Model's field changes by a few nT per km (the Pacific start, northward: F 4.8, H -2.6,
Z 9.6 nT/km, I 0.012 deg/km), so 500 m moves the model's H and Z by <= 5 nT against the circle
fit's residual of 100-300 nT."""
AT_REST_MPS = 0.5                 # and the FC's ground speed below this (a moored boat's drift)


class MissionPreparation:
    """The start of the next mission, and the mission built for it in advance."""

    def __init__(self, settings: Settings, state: MissionState, intake: SampleIntake, fc_view: FcView,
                 msg_clock: MessageClock, voice: Voice, startup_s: float | None, lockstep: bool) -> None:
        """``startup_s``: --startup-s (None: NAV_PERIOD_S); ``lockstep``: the forecast runs inline."""
        self.settings = settings
        self.mission_state = state
        self.intake = intake
        self.fc_view = fc_view
        self.msg_clock = msg_clock
        self.startup_s = startup_s
        self.prepared: Mission | None = None   # built while READY, used at arming if nothing changed
        self._prepared_for = None              # the NavConfig (parameters) it was last found to serve
        self.forecast = RouteForecast(voice.say, inline=lockstep)   # the route said before it

    def startup_window(self) -> float:
        """Seconds of stationary averaging before the first step (--startup-s, else NAV_PERIOD_S)."""
        return self.startup_s if self.startup_s is not None else self.settings.nav.period_s

    def start_position(self) -> tuple[float, float, str]:
        """(lat, lon, what it is): the GPS fix, the last estimate after a restart, or NAV_START."""
        gps = self.intake.last_gps
        if gps is not None and gps.valid and gps.has_3d_fix and self.msg_clock.now_s - gps.time_s <= GPS_START_MAX_AGE_S:
            return gps.lat_deg, gps.lon_deg, "GPS"
        restart_from = self.mission_state.restart_from
        if restart_from is not None:
            return restart_from[0], restart_from[1], "last estimate"
        nav = self.settings.nav
        return nav.start_lat_deg, nav.start_lon_deg, "NAV_START"

    def calibration_fix(self) -> tuple[tuple[float, float] | None, str]:
        """((lat, lon) at which the magnetometer calibration evaluates the field model, or None;
        what it is, or why there is none). A fix fresh enough for the start (GPS_START_MAX_AGE_S),
        or an older one while the flight controller's position (GLOBAL_POSITION_INT, fresh) is
        within AT_REST_M of it at under AT_REST_MPS and is the FC's own (GPS-aided or free inertial, not our GPS_INPUT fed back): a vehicle on its mooring whose arming was
        delayed past the GPS cut (ArduPilot in lockstep, seed 1007: four refusals "GPS 1: not healthy",
        the fix's own time more than 5 s old at arming while GPS_RAW_INT still said 3D).
        The mission's start keeps GPS_START_MAX_AGE_S (:meth:`start_position`)."""
        gps, now = self.intake.last_fix, self.msg_clock.now_s
        if gps is None:
            return None, "no GPS fix since the companion started"
        age = now - gps.time_s
        if age <= GPS_START_MAX_AGE_S:
            return (gps.lat_deg, gps.lon_deg), "the GPS fix"
        independent, why = self.fc_view.position_independent(now)
        if not (independent or self.fc_view.gps_has_fix(now)):   # our own fed estimate: no evidence of rest
            return None, f"the last GPS fix is {age:.0f} s old and the FC position is {why}"
        pos = self.intake.decoder.fc_position
        if pos is None or not now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            return None, f"the last GPS fix is {age:.0f} s old and no FC position tells whether the vehicle moved since"
        moved = geodesic_inverse(gps.lat_deg, gps.lon_deg, pos.lat_deg, pos.lon_deg)[0]
        speed = math.hypot(pos.vn_mps, pos.ve_mps)
        words = f"the FC position {moved:.0f} m from it at {speed:.1f} m/s"
        if not (moved <= AT_REST_M and speed <= AT_REST_MPS):
            return None, f"the last GPS fix is {age:.0f} s old and the vehicle moved since ({words})"
        return (gps.lat_deg, gps.lon_deg), f"the GPS fix of {age:.0f} s ago, at rest since ({words})"

    def prepare(self, now: float) -> None:
        """Build the mission (QP set-up, field model) while waiting to be armed, so the moment of
        arming costs a setpoint tick, not a set-up: at SITL speed-ups 100 ms of set-up was 3 s
        of firmware time without a setpoint, and ArduPilot stopped."""
        if self.settings.dirty:
            return
        lat, lon, _ = self.start_position()
        code, _ = self.resolve_elements(now)
        prepared = self.prepared
        if prepared is not None and self.settings.nav is self._prepared_for and code == prepared.config.elements \
                and self._near(prepared.config, lat, lon):
            return   # a READY tick that asks what the last one did: no configuration built to compare
        config = self.mission_config(lat, lon, code)
        if not self.fits(config):
            self.prepared = Mission(config)
            self.forecast.request(config)
        self._prepared_for = self.settings.nav   # (a parameter change builds a new NavConfig)

    def mission_config(self, lat: float, lon: float, elements: int) -> NavConfig:
        """The mission's settings: NAV_* from the parameters, this start, the resolved element set."""
        return self.settings.nav.replace(start_lat_deg=float(lat), start_lon_deg=float(lon), elements=elements)

    def fits(self, config: NavConfig) -> bool:
        """The prepared mission serves ``config``: the same settings, a start within PREPARED_START_M
        (a drifting boat moves its GPS start every tick; rebuilding each tick starved the link)."""
        prepared = self.prepared
        if prepared is None:
            return False
        old = prepared.config
        same = old.replace(start_lat_deg=config.start_lat_deg, start_lon_deg=config.start_lon_deg) == config
        return same and self._near(old, config.start_lat_deg, config.start_lon_deg)

    @staticmethod
    def _near(config: NavConfig, lat: float, lon: float) -> bool:
        """The start (lat, lon) is within PREPARED_START_M of ``config``'s."""
        return geodesic_inverse(config.start_lat_deg, config.start_lon_deg, lat, lon)[0] <= PREPARED_START_M

    def take_mission(self, config: NavConfig) -> Mission:
        """The prepared mission if it serves ``config``, else a new one; nothing stays prepared."""
        mission = self.prepared if self.fits(config) else Mission(config)
        self.prepared = None
        return mission

    def resolve_elements(self, now: float) -> tuple[int, str]:
        """NAV_ELEMENTS resolved against the heading source: never D with a compass-derived yaw."""
        verdict = self.fc_view.heading_verdict(now)
        requested = self.settings.nav.elements
        compass = verdict is None or verdict.compass_derived
        code = resolve_elements(requested, compass)
        if compass:
            reason = verdict.reason if verdict is not None else "heading source unknown"
            if requested in (ElementSet.PAPER, ElementSet.WEIGHTED, ElementSet.WEIGHTED_WHEN_QUIET):
                return code, (f"NAV_ELEMENTS {requested} asks for D, but the FC yaw is "
                              f"compass-derived ({reason}): D is no measurement")
            if requested == ElementSet.HORIZONTAL_VERTICAL:
                return code, f"NAV_ELEMENTS 3, FC yaw compass-derived ({reason})"
            return code, f"FC yaw is compass-derived ({reason})"
        if requested == 0:
            return code, f"heading independent of the compass ({verdict.reason})"
        return code, f"NAV_ELEMENTS {requested} ({verdict.reason})"

    def inclination(self, avg) -> float:
        """I of an average as the navigator measures it (:func:`companion.nav.period.measured_inclination`)."""
        heading_free = self.mission_state.elements_code in (ElementSet.HEADING_FREE, ElementSet.HORIZONTAL_VERTICAL)
        return measured_inclination(avg, heading_free)[0]

    def calibration(self, config: NavConfig, startup, source: str) -> tuple[tuple[float, ...] | None, str]:
        """Start-up bias = measured minus model at a GPS-known start (NAV_CALIBRATE 1), and its words."""
        if not (config.calibrate and source == "GPS" and startup.valid and math.isfinite(startup.f_nt)):
            return None, "" if not config.calibrate else f"not calibrated (start from {source})"
        elements = ELEMENT_SETS[config.elements]
        model = model_for_setting(config.year, config.wmm, config.nav_map)
        expected = elements.values(model.elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year))
        measured = elements.values(replace(startup, incl_deg=self.inclination(startup)))
        bias = elements.difference(measured, expected)
        units = ["nT" if n == "f_nt" else "deg" for n in elements.names]
        words = ", ".join(f"{ELEMENT_NAMES[n]} {b:+.3f} {u}" if u == "deg" else f"{ELEMENT_NAMES[n]} {b:+.0f} {u}"
                          for n, b, u in zip(elements.names, bias, units))
        return tuple(float(b) for b in bias), f"calibrated at the GPS start: measured - model = {words}"

"""Feeding the companion's position to a flight controller that has lost its GPS.

Without GPS, ArduPilot's EKF3 and PX4's EKF2 stop aiding: ArduPilot reports an EKF variance
failsafe within seconds and switches to HOLD. The companion then supplies its own estimate as a
MAVLink GPS (GPS_INPUT; ArduPilot ``GPS2_TYPE 14``, PX4 through its MAVLink GPS driver), so the
flight controller stays healthy and keeps executing the companion's velocity setpoints.

What the flight controller does with it (measured on ArduPilot Rover SITL, see
``../shared/ardupilot/README.md`` and the README's "Flying with ArduPilot"):

* it trusts a GPS to 100 m at best, whatever accuracy we claim, so position noise becomes
  velocity error: the fed position must be *smooth*;
* a step of a few km fails its innovation gate (a glitch, then a variance failsafe): a new
  estimate is *blended in* at ``blend_mps`` instead of stepped.

:class:`PositionFeed` is the pure part: an anchor (time, position), the velocity the vehicle is
commanded to fly, and the correction still to be blended in. ``position(t)`` is the anchor
moved by the velocity, plus the correction applied so far, which grows by at most
``blend_mps * dt`` per call. When the feed starts (GPS just lost), it starts at the flight
controller's last GPS-aided position and velocity, so there is no step at the switch-over, and
blends towards the companion's estimate from there.

A new command does not step the fed velocity: it turns towards it at no more than ``accel_mps2``,
as the vehicle does. A fed track with a corner is an acceleration the flight controller's IMU
never measured, and its EKF explains the difference with its tilt and gyro-bias states (measured on
PX4 in lockstep: a 90-degree corner at 3 m/s left a 0.9 mrad/s pitch gyro bias; the tilt error
then grew to 13 deg in 7 minutes and the vertical accelerometer bias to its 0.4 m/s^2 limit,
"High Accelerometer Bias" and a failsafe).

How the feed reaches each flight controller (:func:`send_feed`, measured on the real firmware):

* ArduPilot: GPS_INPUT (``GPS2_TYPE 14``), :meth:`companion.io.link.MavlinkLink.send_gps_input`.
* PX4 (SITL with SIH, v1.17 main of 2026-05): GPS_INPUT was ignored (no second receiver appeared
  in GPS2_RAW, with or without ``MAV_USEHILGPS``, from the FC's or a ground station's system id);
  ExternalNav (ODOMETRY with ``EKF2_EV_CTRL 1``) did not take over position after GPS loss (EKF2
  flags without a position within 20 s). HIL_GPS with ``MAV_USEHILGPS 1``, sent with the
  flight controller's own system id (``mavlink_receiver.cpp`` accepts HIL_GPS outside HIL mode
  only then), appears as its second receiver (GPS2_RAW) and EKF2 kept its position solution
  when SIH's receiver lost its fix. ``eph``/``epv`` carry the claimed accuracy in cm, which
  must pass ``EKF2_REQ_EPH``/``EKF2_REQ_EPV`` (``params/px4-rover.params``).

Everything is in message time; positions in degrees, offsets in metres east/north.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from companion.nav.geo import enu_offset, metres_per_degree, offset_position

__all__ = ["GPS_EPOCH_UNIX_S", "GPS_LEAP_S", "FeedSample", "PositionFeed", "feed_message_name", "gps_week_time",
           "send_feed", "send_hil_gps", "turn_towards"]

GPS_EPOCH_UNIX_S = 315964800.0   # 1980-01-06T00:00:00Z
GPS_LEAP_S = 18.0                # GPS - UTC since 2017-01-01
WEEK_S = 604800.0


def gps_week_time(unix_s: float) -> tuple[int, int]:
    """(GPS week, milliseconds of the week) of a UNIX time.

    >>> gps_week_time(1715364000.0)   # 2024-05-10T18:00:00Z
    (2313, 496818000)
    """
    gps_s = unix_s - GPS_EPOCH_UNIX_S + GPS_LEAP_S
    week = int(gps_s // WEEK_S)
    return week, int(round((gps_s - week * WEEK_S) * 1000.0))


class FeedSample(NamedTuple):
    """One fed position: degrees, the 1-sigma we claim (m), and the velocity (m/s, north/east).
    A named tuple: ten are made a second, and a frozen dataclass costs four times as much to make."""

    time_s: float
    lat_deg: float
    lon_deg: float
    sigma_m: float
    vn_mps: float
    ve_mps: float


TURN_STEP_S = 0.1     # the feed's own rate: a turn is integrated in steps of one sample
TURN_MIN_MPS = 0.5    # below this speed a velocity changes along a straight line, not by turning


def turn_towards(velocity_ne: tuple[float, float], target_ne: tuple[float, float],
                 change_mps: float) -> tuple[float, float]:
    """``velocity_ne`` changed towards ``target_ne`` by at most ``change_mps`` of turn (speed times
    the angle turned) and as much of speed: a vehicle turning at its lateral acceleration while
    it speeds up or slows down, not cutting the corner through a lower speed.

    >>> [round(v, 3) for v in turn_towards((3.0, 0.0), (0.0, 3.0), 0.3)]   # a tenth of a radian
    [2.985, 0.3]
    """
    (vn, ve), (tn, te) = velocity_ne, target_ne
    speed, target = math.hypot(vn, ve), math.hypot(tn, te)
    if speed < TURN_MIN_MPS or target < TURN_MIN_MPS:
        gap = math.hypot(tn - vn, te - ve)
        if gap <= change_mps:
            return target_ne
        return vn + (tn - vn) * change_mps / gap, ve + (te - ve) * change_mps / gap
    course, wanted = math.atan2(ve, vn), math.atan2(te, tn)
    left = (wanted - course + math.pi) % (2.0 * math.pi) - math.pi
    turn = math.copysign(min(abs(left), change_mps / speed), left)
    new_speed = speed + math.copysign(min(abs(target - speed), change_mps), target - speed)
    if turn == left and new_speed == target:
        return target_ne
    return new_speed * math.cos(course + turn), new_speed * math.sin(course + turn)


class PositionFeed:
    """A smooth position for the flight controller: anchor + velocity * t + blended correction."""

    def __init__(self, blend_mps: float = 0.5, accel_mps2: float = math.inf) -> None:
        if not blend_mps > 0.0:
            raise ValueError(f"blend_mps must be positive, got {blend_mps}")
        if not accel_mps2 > 0.0:
            raise ValueError(f"accel_mps2 must be positive, got {accel_mps2}")
        self.blend_mps = blend_mps
        self.accel_mps2 = accel_mps2
        self.anchor: tuple[float, float, float] | None = None    # (time, lat, lon)
        self.velocity_ne = (0.0, 0.0)     # the velocity flown from the anchor on ...
        self.target_ne = (0.0, 0.0)       # ... turning towards the commanded one at accel_mps2
        self.applied_en = [0.0, 0.0]
        self.pending_en = [0.0, 0.0]
        self.sigma_m = math.nan
        self.last_time_s = math.nan
        self._anchor_scale: tuple[float, tuple[float, float]] | None = None   # (anchor latitude, metres per degree)

    @property
    def started(self) -> bool:
        return self.anchor is not None

    def start(self, time_s: float, lat_deg: float, lon_deg: float, sigma_m: float,
              velocity_ne: tuple[float, float] = (0.0, 0.0)) -> None:
        """Begin at a position and velocity (the FC's last GPS-aided ones) with nothing to blend yet."""
        self.anchor = (time_s, lat_deg, lon_deg)
        self.velocity_ne = self.target_ne = tuple(float(v) if math.isfinite(v) else 0.0 for v in velocity_ne)
        self.applied_en, self.pending_en = [0.0, 0.0], [0.0, 0.0]
        self.sigma_m = sigma_m
        self.last_time_s = time_s

    def stop(self) -> None:
        self.anchor = None

    def _raw(self, time_s: float) -> tuple[float, float]:
        t0, lat0, lon0 = self.anchor
        dt = time_s - t0
        east = self.velocity_ne[1] * dt + self.applied_en[0]
        north = self.velocity_ne[0] * dt + self.applied_en[1]
        scale = self._anchor_scale
        if scale is None or scale[0] != lat0:   # the anchor moved: its metres per degree, once per anchor
            scale = self._anchor_scale = (lat0, metres_per_degree(lat0))
        lat, lon = offset_position(lat0, lon0, east, north, scale[1])
        return float(lat), float(lon)

    def _reanchor(self, time_s: float) -> None:
        """Move the anchor to ``time_s``, the velocity turning towards the target on the way
        (:func:`turn_towards` in steps of :data:`TURN_STEP_S`, then the target)."""
        t0, lat0, lon0 = self.anchor
        dt = max(time_s - t0, 0.0)
        north = east = 0.0
        if math.isinf(self.accel_mps2):      # no limit: the new velocity from its command's time on
            self.velocity_ne = self.target_ne
        while dt > 0.0 and self.velocity_ne != self.target_ne:
            step = min(dt, TURN_STEP_S)
            before = self.velocity_ne
            self.velocity_ne = turn_towards(before, self.target_ne, self.accel_mps2 * step)
            north += 0.5 * (before[0] + self.velocity_ne[0]) * step
            east += 0.5 * (before[1] + self.velocity_ne[1]) * step
            dt -= step
        north += self.velocity_ne[0] * dt
        east += self.velocity_ne[1] * dt
        lat, lon = offset_position(lat0, lon0, east + self.applied_en[0], north + self.applied_en[1])
        self.anchor = (time_s, float(lat), float(lon))
        self.applied_en = [0.0, 0.0]

    def set_velocity(self, time_s: float, vn_mps: float, ve_mps: float) -> None:
        """Fly on towards a new commanded velocity from ``time_s`` (re-anchors, no jump)."""
        if self.anchor is None:
            return
        self._reanchor(time_s)
        self.target_ne = (vn_mps if math.isfinite(vn_mps) else 0.0, ve_mps if math.isfinite(ve_mps) else 0.0)

    def correct_to(self, time_s: float, lat_deg: float, lon_deg: float, sigma_m: float) -> float:
        """The companion's estimate at ``time_s``: blend the difference in; returns its size (m)."""
        if self.anchor is None or not (math.isfinite(lat_deg) and math.isfinite(lon_deg)):
            return math.nan
        self._reanchor(time_s)
        lat, lon = self._raw(time_s)
        east, north = enu_offset(lat, lon, lat_deg, lon_deg)
        self.pending_en = [float(east), float(north)]
        if math.isfinite(sigma_m):
            self.sigma_m = sigma_m
        return math.hypot(east, north)

    def sample(self, time_s: float) -> FeedSample | None:
        """The position to send at ``time_s``, blending at most ``blend_mps`` since the last call."""
        if self.anchor is None:
            return None
        dt = max(time_s - self.last_time_s, 0.0) if math.isfinite(self.last_time_s) else 0.0
        self.last_time_s = time_s
        size = math.hypot(*self.pending_en)
        if size > 0.0:
            take = min(1.0, self.blend_mps * dt / size)
            for k in (0, 1):
                self.applied_en[k] += take * self.pending_en[k]
                self.pending_en[k] -= take * self.pending_en[k]
        if self.velocity_ne != self.target_ne:
            self._reanchor(time_s)
        lat, lon = self._raw(time_s)
        return FeedSample(time_s, lat, lon, self.sigma_m, self.velocity_ne[0], self.velocity_ne[1])

    @property
    def pending_m(self) -> float:
        return math.hypot(*self.pending_en)


def feed_message_name(family: str) -> str:
    """The message that carries the feed to an autopilot family ("ardupilot", "px4")."""
    return "HIL_GPS" if family == "px4" else "GPS_INPUT"


def send_hil_gps(link, lat_deg: float, lon_deg: float, sigma_m: float, vn_mps: float = 0.0, ve_mps: float = 0.0,
                 satellites: int = 10, alt_m: float = 0.0) -> bool:
    """HIL_GPS for PX4 (``MAV_USEHILGPS 1``), from the link's system id, which is the flight
    controller's once it is detected. ``sigma_m`` goes out as ``eph`` and ``epv`` (cm), the
    velocity (m/s, north/east) as ``vn``/``ve`` (cm/s); time is the flight controller's UTC
    (SYSTEM_TIME), as on a real receiver."""
    if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
        return False
    clock = link.clock
    if clock.unix_minus_boot_s is None or not clock.started:
        return False
    accuracy_cm = round(min(float(sigma_m) if math.isfinite(sigma_m) and sigma_m > 0.0 else 100.0, 600.0) * 100)
    vn = vn_mps if math.isfinite(vn_mps) else 0.0
    ve = ve_mps if math.isfinite(ve_mps) else 0.0
    speed = math.hypot(vn, ve)
    cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100) % 36000 if speed > 0.1 else 65535
    lon = ((lon_deg + 180.0) % 360.0) - 180.0
    link.send_hil_gps(int((clock.now_s + clock.unix_minus_boot_s) * 1e6), 3, round(lat_deg * 1e7),
                      round(lon * 1e7), round(alt_m * 1000.0), accuracy_cm, accuracy_cm,
                      round(speed * 100), round(vn * 100), round(ve * 100), 0, cog, satellites, 1, 0)
    link.stats.positions_fed += 1
    return True


def send_feed(link, family: str, lat_deg: float, lon_deg: float, sigma_m: float, satellites: int,
              vn_mps: float = 0.0, ve_mps: float = 0.0) -> bool:
    """One feed sample to the flight controller in the message its family accepts (see above)."""
    if family == "px4":
        return send_hil_gps(link, lat_deg, lon_deg, sigma_m, vn_mps, ve_mps, satellites)
    return link.send_gps_input(lat_deg, lon_deg, sigma_m, satellites=satellites)


def send_echo(link, family: str, pos, now_s: float, sigma_m: float, satellites: int) -> bool:
    """The echo of the flight controller's own GPS-aided position (``pos``: GLOBAL_POSITION_INT as
    :class:`~companion.io.sensors.mavlink_source.FcPosition`) while its GPS has a fix.

    PX4 blends its receivers' positions *and velocities* (``SENS_GPS_MASK``), and its yaw estimator
    uses the blended velocity: an echo standing still at the last 1 Hz position while the rover
    drives would be blended in as a wrong velocity. So on PX4 the echo carries the velocity and is
    flown on from its time stamp; ArduPilot's GPS_INPUT echo stays the position as reported.
    """
    if family != "px4":
        return link.send_gps_input(pos.lat_deg, pos.lon_deg, sigma_m, satellites=satellites)
    vn = pos.vn_mps if math.isfinite(pos.vn_mps) else 0.0
    ve = pos.ve_mps if math.isfinite(pos.ve_mps) else 0.0
    dt = min(max(now_s - pos.time_s, 0.0), 2.0)
    lat, lon = offset_position(pos.lat_deg, pos.lon_deg, ve * dt, vn * dt)
    return send_hil_gps(link, float(lat), float(lon), sigma_m, vn, ve, satellites)

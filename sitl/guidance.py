"""Flight modes, arming and guided setpoints of the simulated autopilot (no sockets, no clocks).

Two conventions are offered, chosen by the server's ``--autopilot``:

ArduPilot Rover (``MAV_AUTOPILOT_ARDUPILOTMEGA``)
    custom modes MANUAL 0, HOLD 4, LOITER 5, AUTO 10, RTL 11, GUIDED 15, INITIALISING 16.
    Setpoints move the vehicle only when armed and in GUIDED. Velocity setpoints time out
    (default 3 s of simulated time, like Rover's guided velocity timeout): the vehicle stops,
    stays in GUIDED and resumes on the next setpoint.
PX4 (``MAV_AUTOPILOT_PX4``)
    ``custom_mode`` carries the main mode in bits 16-23 and the sub mode in bits 24-31:
    MANUAL 1, POSCTL 3, AUTO 4 (LOITER 3, MISSION 4, RTL 5), OFFBOARD 6. Setpoints are stored
    in any mode; OFFBOARD is refused unless a valid setpoint arrived within the offboard
    timeout (default 1 s, PX4's ``COM_OF_LOSS_T``), and when setpoints stop in OFFBOARD the
    vehicle falls back to AUTO.LOITER (hold).

Behaviour of the modes for a boat: MANUAL, HOLD, LOITER, POSCTL, AUTO.LOITER stop (no RC
input); GUIDED/OFFBOARD follow setpoints; RTL drives back to the home position at the cruise
speed; AUTO/AUTO.MISSION are refused (no mission). ``Guidance.command`` turns all this into
the (course, speed) the kinematics of :mod:`sitl.world.vehicle` track.

Results are MAVLink ``MAV_RESULT`` values; messages for STATUSTEXT queue in ``events``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion import wrap_2pi
from companion.nav.geo import enu_offset, offset_position
from sitl.world.vehicle import VehicleLimits

__all__ = ["Dialect", "ARDUPILOT", "PX4", "DIALECTS", "Guidance", "SetpointError", "PositionTarget",
           "interpret_position_target", "MAV_RESULT_ACCEPTED", "MAV_RESULT_TEMPORARILY_REJECTED",
           "MAV_RESULT_DENIED", "MAV_RESULT_UNSUPPORTED", "MAV_RESULT_FAILED"]

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_GUIDED_ENABLED = 8
MAV_MODE_FLAG_STABILIZE_ENABLED = 16
MAV_MODE_FLAG_MANUAL_INPUT_ENABLED = 64
MAV_MODE_FLAG_SAFETY_ARMED = 128

# STATUSTEXT severities
SEVERITY_CRITICAL = 2
SEVERITY_ERROR = 3
SEVERITY_WARNING = 4
SEVERITY_NOTICE = 5
SEVERITY_INFO = 6


@dataclass(frozen=True)
class Dialect:
    """One autopilot's mode numbering and guided-mode rules."""

    name: str
    autopilot: int
    modes: dict                      # mode name -> custom_mode (uint32 as in HEARTBEAT)
    behaviour: dict                  # mode name -> "stop" | "guided" | "rtl" | "mission" | "init"
    guided_mode: str
    hold_mode: str
    rtl_mode: str
    boot_mode: str                   # reported until the autopilot is ready
    ready_mode: str                  # entered when ready
    setpoint_timeout_s: float        # default velocity-setpoint timeout
    needs_setpoints_for_guided: bool  # PX4: OFFBOARD only with a live setpoint stream
    hold_on_setpoint_loss: bool      # PX4: switch to hold; ArduPilot: stop in GUIDED
    setpoints_outside_guided: str    # "ignore" (ArduPilot, counted) | "store" (PX4)
    version: int                     # AUTOPILOT_VERSION.flight_sw_version

    def custom_mode(self, mode: str) -> int:
        return self.modes[mode]

    def mode_from_custom(self, custom_mode: int) -> str | None:
        """Mode name of a HEARTBEAT/SET_MODE ``custom_mode`` (None if unknown)."""
        for name, value in self.modes.items():
            if value == custom_mode:
                return name
        return None

    def mode_from_command(self, param2: float, param3: float) -> str | None:
        """Mode name of MAV_CMD_DO_SET_MODE's custom mode (param2) and, for PX4, sub mode (param3)."""
        if not (math.isfinite(param2) and math.isfinite(param3)):
            return None
        if self.autopilot == MAV_AUTOPILOT_PX4:
            main, sub = int(param2), int(param3)
            if main != 4:
                sub = 0
            return self.mode_from_custom((main << 16) | (sub << 24))
        if param2 != int(param2):
            return None
        return self.mode_from_custom(int(param2))

    def base_mode(self, mode: str, armed: bool) -> int:
        flags = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.behaviour.get(mode) in ("guided", "rtl", "mission"):
            flags |= MAV_MODE_FLAG_GUIDED_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED
        elif mode == "MANUAL":
            flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        else:
            flags |= MAV_MODE_FLAG_STABILIZE_ENABLED
        if armed:
            flags |= MAV_MODE_FLAG_SAFETY_ARMED
        return flags


def _px4(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


ARDUPILOT = Dialect(
    name="ardupilot", autopilot=MAV_AUTOPILOT_ARDUPILOTMEGA,
    modes={"MANUAL": 0, "HOLD": 4, "LOITER": 5, "AUTO": 10, "RTL": 11, "GUIDED": 15, "INITIALISING": 16},
    behaviour={"MANUAL": "stop", "HOLD": "stop", "LOITER": "stop", "AUTO": "mission", "RTL": "rtl",
               "GUIDED": "guided", "INITIALISING": "init"},
    guided_mode="GUIDED", hold_mode="HOLD", rtl_mode="RTL", boot_mode="INITIALISING", ready_mode="HOLD",
    setpoint_timeout_s=3.0, needs_setpoints_for_guided=False, hold_on_setpoint_loss=False,
    setpoints_outside_guided="ignore", version=(4 << 24) | (5 << 16) | (7 << 8) | 255,
)

PX4 = Dialect(
    name="px4", autopilot=MAV_AUTOPILOT_PX4,
    modes={"MANUAL": _px4(1), "POSCTL": _px4(3), "AUTO.LOITER": _px4(4, 3), "AUTO.MISSION": _px4(4, 4),
           "AUTO.RTL": _px4(4, 5), "OFFBOARD": _px4(6)},
    behaviour={"MANUAL": "stop", "POSCTL": "stop", "AUTO.LOITER": "stop", "AUTO.MISSION": "mission",
               "AUTO.RTL": "rtl", "OFFBOARD": "guided"},
    guided_mode="OFFBOARD", hold_mode="AUTO.LOITER", rtl_mode="AUTO.RTL", boot_mode="AUTO.LOITER",
    ready_mode="AUTO.LOITER", setpoint_timeout_s=1.0, needs_setpoints_for_guided=True,
    hold_on_setpoint_loss=True, setpoints_outside_guided="store",
    version=(1 << 24) | (15 << 16) | (0 << 8) | 255,
)

DIALECTS = {"ardupilot": ARDUPILOT, "px4": PX4}


class SetpointError(ValueError):
    """A setpoint that is refused; ``reason`` is one of nan, limit, frame, empty, unsupported."""

    def __init__(self, reason: str, text: str) -> None:
        super().__init__(text)
        self.reason = reason


@dataclass(frozen=True)
class PositionTarget:
    """A decoded SET_POSITION_TARGET_*: what to do, in the autopilot's own (FC) coordinates.

    ``course_rad``/``speed_mps`` are None when not commanded; ``lat_deg``/``lon_deg`` when a
    position target was given (then velocity is not used).
    """

    course_rad: float | None = None
    speed_mps: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None


# type_mask bits (POSITION_TARGET_TYPEMASK)
_IGNORE_X, _IGNORE_Y = 1, 2
_IGNORE_VX, _IGNORE_VY = 8, 16
_IGNORE_YAW = 1024
_IGNORE_YAW_RATE = 2048
_GLOBAL_FRAMES = {0, 3, 5, 6, 10, 11}
_LOCAL_FRAMES = {1, 7}           # LOCAL_NED, LOCAL_OFFSET_NED
_BODY_FRAMES = {8, 9, 12}        # BODY_NED (velocity in body axes, ArduPilot), BODY_OFFSET_NED, BODY_FRD


def interpret_position_target(*, frame: int, type_mask: int, vx: float, vy: float, yaw: float,
                              max_speed_mps: float, current_yaw_rad: float, fc_lat_deg: float, fc_lon_deg: float,
                              origin: tuple[float, float], lat_deg: float | None = None,
                              lon_deg: float | None = None, x_m: float | None = None,
                              y_m: float | None = None) -> PositionTarget:
    """Decode a SET_POSITION_TARGET_GLOBAL_INT (``lat_deg``/``lon_deg``) or _LOCAL_NED (``x_m``/``y_m``).

    Honours ``type_mask``: position used only if X and Y are not ignored; velocity (vx north,
    vy east, m/s; body axes in body frames) only if VX and VY are not ignored; yaw (rad from
    north, clockwise) only if YAW is not ignored, and then it sets the course, otherwise the
    course is that of the velocity. Raises :class:`SetpointError` for NaN/inf in a used field,
    a speed above ``max_speed_mps``, an unsupported frame, or a mask that leaves nothing to do.
    """
    use_pos = not (type_mask & _IGNORE_X) and not (type_mask & _IGNORE_Y)
    use_vel = not (type_mask & _IGNORE_VX) and not (type_mask & _IGNORE_VY)
    use_yaw = not (type_mask & _IGNORE_YAW)
    is_global = lat_deg is not None
    if is_global and frame not in _GLOBAL_FRAMES:
        raise SetpointError("frame", f"frame {frame} not supported for GLOBAL_INT")
    if not is_global and frame not in _LOCAL_FRAMES | _BODY_FRAMES:
        raise SetpointError("frame", f"frame {frame} not supported for LOCAL_NED")
    used = []
    if use_pos:
        used += [lat_deg, lon_deg] if is_global else [x_m, y_m]
    if use_vel:
        used += [vx, vy]
    if use_yaw:
        used.append(yaw)
    if not used:
        if not (type_mask & _IGNORE_YAW_RATE):
            raise SetpointError("unsupported", "yaw-rate-only setpoints are not supported")
        raise SetpointError("empty", "type_mask ignores position, velocity and yaw")
    if not all(v is not None and math.isfinite(v) for v in used):
        raise SetpointError("nan", "NaN/inf in setpoint")
    lat = lon = None
    if use_pos:
        if is_global:
            lat, lon = float(lat_deg), float(lon_deg)
        else:
            north, east = float(x_m), float(y_m)
            if frame in _BODY_FRAMES:
                c, s = math.cos(current_yaw_rad), math.sin(current_yaw_rad)
                north, east = c * north - s * east, s * north + c * east
            base = origin if frame == 1 else (fc_lat_deg, fc_lon_deg)
            lat, lon = (float(v) for v in offset_position(base[0], base[1], east, north))
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
            raise SetpointError("limit", f"position {lat:.6f},{lon:.6f} out of range")
    course = speed = None
    if use_vel:
        north, east = float(vx), float(vy)
        if frame in _BODY_FRAMES:
            c, s = math.cos(current_yaw_rad), math.sin(current_yaw_rad)
            north, east = c * north - s * east, s * north + c * east
        speed = math.hypot(north, east)
        if speed > max_speed_mps * 1.001:
            raise SetpointError("limit", f"speed {speed:.1f} m/s above limit {max_speed_mps:.1f}")
        if speed > 1e-6:
            course = wrap_2pi(math.atan2(east, north))
    if use_yaw:
        if abs(yaw) > 4.0 * math.pi:
            raise SetpointError("limit", f"yaw {yaw:.2f} rad out of range")
        course = wrap_2pi(float(yaw))
    if lat is not None:
        return PositionTarget(lat_deg=lat, lon_deg=lon)
    return PositionTarget(course_rad=course, speed_mps=speed)


class Guidance:
    """Mode, arming and the guided command of one simulated vehicle.

    ``command(time_s, ...)`` returns the (course_rad, speed_mps) to track now and applies the
    setpoint timeout. All times are simulated seconds.
    """

    def __init__(self, dialect: Dialect, limits: VehicleLimits, cruise_speed_mps: float,
                 setpoint_timeout_s: float | None = None, arrive_radius_m: float = 2.0) -> None:
        self.dialect = dialect
        self.limits = limits
        self.cruise_speed_mps = min(cruise_speed_mps, limits.max_speed_mps)
        self.setpoint_timeout_s = dialect.setpoint_timeout_s if setpoint_timeout_s is None else setpoint_timeout_s
        self.arrive_radius_m = arrive_radius_m
        self.ready = False
        self.armed = False
        self.mode = dialect.boot_mode
        self.home: tuple[float, float] | None = None
        self.events: list[tuple[int, str]] = []
        self.counters: dict[str, int] = {}
        self._course: float | None = None      # guided course target (rad), None = hold current
        self._speed = 0.0                      # guided speed target (m/s)
        self._timed = False                    # the current guided target times out
        self._last_velocity_s = -math.inf      # last valid velocity setpoint (sim s)
        self._last_setpoint_s = -math.inf      # last valid setpoint of any kind
        self._goto: tuple[float, float] | None = None
        self._stopped_reason = ""

    # -- state -------------------------------------------------------------------------
    def _count(self, key: str) -> None:
        self.counters[key] = self.counters.get(key, 0) + 1

    def _say(self, severity: int, text: str) -> None:
        self.events.append((severity, text))

    def set_ready(self) -> None:
        """Initialisation finished: enter the dialect's ready mode."""
        if not self.ready:
            self.ready = True
            self.mode = self.dialect.ready_mode
            self._say(SEVERITY_INFO, f"SITL ready, mode {self.mode}")

    def reboot(self) -> None:
        """The autopilot boots again: disarmed, initialising (the boot mode) until :meth:`set_ready`,
        no guided target. The home position and the parameters are kept, as on a real autopilot."""
        self.ready = False
        self.armed = False
        self.mode = self.dialect.boot_mode
        self._reset_guided()
        self._last_velocity_s = self._last_setpoint_s = -math.inf
        self._stopped_reason = ""

    @property
    def behaviour(self) -> str:
        return self.dialect.behaviour.get(self.mode, "stop")

    @property
    def custom_mode(self) -> int:
        return self.dialect.custom_mode(self.mode)

    @property
    def base_mode(self) -> int:
        return self.dialect.base_mode(self.mode, self.armed)

    def _reset_guided(self) -> None:
        self._course, self._speed, self._timed, self._goto = None, 0.0, False, None

    # -- commands ----------------------------------------------------------------------
    def request_arm(self, arm: bool, time_s: float) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM: MAV_RESULT."""
        if not arm:
            if self.armed:
                self.armed = False
                self._reset_guided()
                self._say(SEVERITY_INFO, "Disarmed")
            return MAV_RESULT_ACCEPTED
        if self.armed:
            return MAV_RESULT_ACCEPTED
        if not self.ready:
            self._say(SEVERITY_CRITICAL, "Arm: system initialising")
            return MAV_RESULT_TEMPORARILY_REJECTED
        if self.behaviour == "guided" and self.dialect.needs_setpoints_for_guided and \
                time_s - self._last_setpoint_s > self.setpoint_timeout_s:
            self._say(SEVERITY_CRITICAL, "Arm: no offboard setpoints")
            return MAV_RESULT_FAILED
        self.armed = True
        self._reset_guided()
        self._say(SEVERITY_INFO, f"Armed in {self.mode}")
        return MAV_RESULT_ACCEPTED

    def request_mode(self, mode: str | None, time_s: float, what: str = "") -> int:
        """Change mode (None = unknown number): MAV_RESULT."""
        if mode is None:
            self._say(SEVERITY_WARNING, f"Unknown mode {what}".strip())
            return MAV_RESULT_FAILED
        if not self.ready:
            self._say(SEVERITY_WARNING, "Mode change refused: initialising")
            return MAV_RESULT_TEMPORARILY_REJECTED
        kind = self.dialect.behaviour.get(mode, "stop")
        if kind == "init":
            return MAV_RESULT_FAILED
        if kind == "mission":
            self._say(SEVERITY_WARNING, f"{mode}: no mission loaded")
            return MAV_RESULT_FAILED
        if kind == "guided" and self.dialect.needs_setpoints_for_guided and \
                time_s - self._last_setpoint_s > self.setpoint_timeout_s:
            self._say(SEVERITY_WARNING, f"{mode} refused: no setpoints streaming")
            return MAV_RESULT_DENIED
        if mode != self.mode:
            previous = self.mode
            self.mode = mode
            keep_streamed = kind == "guided" and self.dialect.setpoints_outside_guided == "store"  # PX4
            if not keep_streamed and (kind == "guided" or self.dialect.behaviour.get(previous) == "guided"):
                self._reset_guided()
            self._say(SEVERITY_INFO, f"Mode {mode}")
        return MAV_RESULT_ACCEPTED

    def start_cruise(self, course_rad: float, speed_mps: float) -> None:
        """Arm, enter the guided mode and hold this course and speed (no timeout): ``--cruise``."""
        self.armed = True
        self.mode = self.dialect.guided_mode
        self._reset_guided()
        self._course, self._speed = wrap_2pi(course_rad), min(max(speed_mps, 0.0), self.limits.max_speed_mps)
        self._say(SEVERITY_INFO, f"Cruise {math.degrees(self._course):.0f} deg {self._speed:.1f} m/s in {self.mode}")

    def _guided_active(self) -> bool:
        return self.armed and self.behaviour == "guided"

    def accept_setpoint(self, time_s: float) -> bool:
        """Whether a setpoint now moves/affects the vehicle; counts the ignored ones."""
        if self._guided_active() or self.dialect.setpoints_outside_guided == "store":
            return True
        self._count("setpoints_ignored_mode")
        return False

    def apply_target(self, target: PositionTarget, time_s: float) -> None:
        """Apply a decoded SET_POSITION_TARGET (caller checked :meth:`accept_setpoint`)."""
        self._last_setpoint_s = time_s
        if target.lat_deg is not None:
            self._goto = (target.lat_deg, target.lon_deg)
            self._timed = False
            self._count("setpoints_position")
            return
        self._goto = None
        if target.speed_mps is not None:
            self._speed = target.speed_mps
            self._last_velocity_s = time_s
            self._timed = True
            self._stopped_reason = ""
        if target.course_rad is not None:
            self._course = target.course_rad
        self._count("setpoints_velocity")

    def change_speed(self, speed_mps: float) -> int:
        """MAV_CMD_GUIDED_CHANGE_SPEED / DO_CHANGE_SPEED (persistent, no timeout)."""
        if not math.isfinite(speed_mps) or speed_mps < 0.0 or speed_mps > self.limits.max_speed_mps * 1.001:
            self._count("commands_bad_value")
            return MAV_RESULT_DENIED
        if self.behaviour == "rtl":
            self.cruise_speed_mps = speed_mps
            return MAV_RESULT_ACCEPTED
        if not self._guided_active():
            return MAV_RESULT_DENIED
        self._goto = None
        self._speed, self._timed, self._stopped_reason = speed_mps, False, ""
        return MAV_RESULT_ACCEPTED

    def change_heading(self, course_rad: float) -> int:
        """MAV_CMD_GUIDED_CHANGE_HEADING (persistent, no timeout)."""
        if not math.isfinite(course_rad):
            self._count("commands_bad_value")
            return MAV_RESULT_DENIED
        if not self._guided_active():
            return MAV_RESULT_DENIED
        self._goto = None
        self._course, self._timed, self._stopped_reason = wrap_2pi(course_rad), False, ""
        return MAV_RESULT_ACCEPTED

    # -- the command tracked by the kinematics --------------------------------------------
    def command(self, time_s: float, course_rad: float, fc_lat_deg: float, fc_lon_deg: float) -> tuple[float, float]:
        """(course_rad, speed_mps) to track now, given the current course and FC position."""
        if not self.armed:
            return course_rad, 0.0
        kind = self.behaviour
        if kind == "guided":
            if self._timed and time_s - self._last_velocity_s > self.setpoint_timeout_s:
                self._timed = False
                self._speed = 0.0
                self._count("setpoint_timeouts")
                if self.dialect.hold_on_setpoint_loss:
                    self.mode = self.dialect.hold_mode
                    self._reset_guided()
                    self._say(SEVERITY_CRITICAL, f"Offboard lost: no setpoint for {self.setpoint_timeout_s:g}s, Hold")
                    return course_rad, 0.0
                self._say(SEVERITY_WARNING, f"GUIDED: setpoint timeout {self.setpoint_timeout_s:g}s, stopping")
            if self._goto is not None:
                return self._drive_to(self._goto, course_rad, fc_lat_deg, fc_lon_deg, self.cruise_speed_mps)
            return (course_rad if self._course is None else self._course), self._speed
        if kind == "rtl" and self.home is not None:
            return self._drive_to(self.home, course_rad, fc_lat_deg, fc_lon_deg, self.cruise_speed_mps)
        return course_rad, 0.0

    def _drive_to(self, target: tuple[float, float], course_rad: float, fc_lat: float, fc_lon: float,
                  speed: float) -> tuple[float, float]:
        east, north = (float(v) for v in enu_offset(fc_lat, fc_lon, target[0], target[1]))
        distance = math.hypot(east, north)
        if distance <= self.arrive_radius_m:
            return course_rad, 0.0
        # slow down on the last stretch so the kinematics' deceleration can stop on the target
        v_stop = math.sqrt(2.0 * self.limits.accel_mps2 * max(0.0, distance - self.arrive_radius_m))
        return wrap_2pi(math.atan2(east, north)), min(speed, v_stop)

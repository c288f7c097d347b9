"""Flight-controller conventions (ArduPilot, PX4), what its HEARTBEAT told us, and the setpoint guard.

=====================  ==============================  ====================================
                       ArduPilot (Rover)               PX4
=====================  ==============================  ====================================
follow setpoints       GUIDED (custom_mode 15)         OFFBOARD (main 6, ``custom_mode`` bits
                                                       16-23), only after >= 1 s of setpoints
hold                   HOLD (4)                        AUTO.LOITER (main 4, sub 3 in bits 24-31)
mode change            MAV_CMD_DO_SET_MODE(1, 15)      MAV_CMD_DO_SET_MODE(1, 6, 0)
parameter INT32 value  C cast (float holds the value)  bytewise (float holds the int's bits)
=====================  ==============================  ====================================

Setpoints: SET_POSITION_TARGET_GLOBAL_INT in MAV_FRAME_GLOBAL_INT, ``vx`` north, ``vy`` east,
``vz`` 0. The ``type_mask`` follows the autopilot (:attr:`FcConventions.setpoint_mask`):

* ArduPilot Rover and boats: **velocity only** (3527, yaw ignored). With a yaw in the message,
  Rover's GUIDED takes the sign of the north component as the direction of travel and reverses
  on every southward course (measured on ArduPilot SITL: 62,973 of 64,413 moving seconds
  backwards); with velocity alone it steers to the velocity's direction and drives forward
  (ArduPilot ``Rover/mode_guided.cpp``, ``GCS_MAVLink_Rover.cpp`` handle_set_position_target).
* PX4: velocity + yaw (2503, ``yaw`` the course in (-pi, pi]): the offboard controllers take
  the yaw as the heading to hold, and it equals the velocity's direction, so forward on every
  course (PX4 ``mavlink_receiver.cpp`` handle_message_set_position_target_global_int).
* ArduPilot Plane does not follow velocity setpoints in GUIDED (it flies to a position or takes
  MAV_CMD_GUIDED_CHANGE_HEADING); not supported here yet.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink.mavutil is imported: MAVLink 2

from pymavlink import mavutil

from companion import wrap_pi

__all__ = [
    "ARDUPILOT",
    "COMPANION_COMPONENT",
    "PX4",
    "VELOCITY_ONLY_TYPE_MASK",
    "VELOCITY_YAW_TYPE_MASK",
    "FcConventions",
    "FcState",
    "Setpoint",
    "UnsafeSetpoint",
    "conventions_for",
    "guard_setpoint",
    "mavlink",
]

mavlink = mavutil.mavlink
COMPANION_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
VELOCITY_YAW_TYPE_MASK = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)  # = 2503: velocity + yaw
VELOCITY_ONLY_TYPE_MASK = VELOCITY_YAW_TYPE_MASK | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE   # = 3527


# --- the last guard before a setpoint leaves -------------------------------------------------
class UnsafeSetpoint(ValueError):
    """A setpoint that must not be sent (NaN, infinite, negative or above the speed limit)."""


@dataclass(frozen=True)
class Setpoint:
    """Velocity north/east (m/s) and yaw (rad, (-pi, pi]) of one SET_POSITION_TARGET message."""

    vn_mps: float
    ve_mps: float
    yaw_rad: float


def guard_setpoint(course_rad: float, speed_mps: float, max_speed_mps: float) -> Setpoint:
    """The setpoint for flying ``course_rad`` at ``speed_mps``, or :class:`UnsafeSetpoint`.

    Refuses anything non-finite, a negative speed, or a speed above ``max_speed_mps`` (which
    must itself be finite and positive). A tiny excess from float rounding (1e-9) is clipped.

    >>> s = guard_setpoint(math.pi / 2, 10.0, 13.9)
    >>> round(s.vn_mps, 9), round(s.ve_mps, 9), round(s.yaw_rad, 9)
    (0.0, 10.0, 1.570796327)
    """
    for name, value in (("course", course_rad), ("speed", speed_mps), ("speed limit", max_speed_mps)):
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise UnsafeSetpoint(f"{name} {value!r} is not finite")
    if max_speed_mps <= 0.0:
        raise UnsafeSetpoint(f"speed limit {max_speed_mps!r} must be positive")
    if speed_mps < 0.0:
        raise UnsafeSetpoint(f"speed {speed_mps!r} is negative")
    if speed_mps > max_speed_mps * (1.0 + 1e-9):
        raise UnsafeSetpoint(f"speed {speed_mps:.3f} m/s above the limit {max_speed_mps:.3f} m/s")
    speed = min(float(speed_mps), float(max_speed_mps))
    yaw = wrap_pi(float(course_rad))
    if yaw <= -math.pi:
        yaw = math.pi
    setpoint = Setpoint(speed * math.cos(yaw), speed * math.sin(yaw), yaw)
    if not all(math.isfinite(v) for v in (setpoint.vn_mps, setpoint.ve_mps, setpoint.yaw_rad)):
        raise UnsafeSetpoint(f"setpoint {setpoint} is not finite")  # pragma: no cover - belt and braces
    return setpoint


# --- flight-controller conventions ------------------------------------------------------------
@dataclass(frozen=True)
class FcConventions:
    """Mode numbers and parameter encoding of one autopilot family."""

    name: str
    autopilot: int
    guided_main: int
    guided_sub: int
    hold_main: int
    hold_sub: int
    param_bytewise: bool
    offboard_prestream_s: float   # setpoints to stream before switching to the guided mode
    setpoint_mask: int            # SET_POSITION_TARGET type_mask this autopilot reads as a course
    family: str                   # "ardupilot" or "px4": which of its parameters to read

    def custom_mode(self, main: int, sub: int) -> int:
        if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return (main << 16) | (sub << 24)
        return main

    def split_mode(self, custom_mode: int) -> tuple[int, int]:
        if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        return custom_mode, 0

    def is_guided(self, custom_mode: int) -> bool:
        return self.split_mode(custom_mode)[0] == self.guided_main

    def is_hold(self, custom_mode: int) -> bool:
        main, sub = self.split_mode(custom_mode)
        if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return main == self.hold_main and sub == self.hold_sub
        return main in (self.hold_main, 5)  # Rover LOITER holds too

    def mode_name(self, custom_mode: int) -> str:
        main, sub = self.split_mode(custom_mode)
        if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            names = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD", 7: "STABILIZED"}
            subs = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND"}
            text = names.get(main, f"MODE{main}")
            return f"{text}.{subs.get(sub, sub)}" if main == 4 and sub else text
        names = {0: "MANUAL", 1: "ACRO", 3: "STEERING", 4: "HOLD", 5: "LOITER", 6: "FOLLOW", 7: "SIMPLE",
                 10: "AUTO", 11: "RTL", 12: "SMART_RTL", 15: "GUIDED", 16: "INITIALISING"}
        return names.get(main, f"MODE{main}")


ARDUPILOT = FcConventions("ArduPilot", mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 15, 0, 4, 0,
                          param_bytewise=False, offboard_prestream_s=0.0,
                          setpoint_mask=VELOCITY_ONLY_TYPE_MASK, family="ardupilot")
PX4 = FcConventions("PX4", mavlink.MAV_AUTOPILOT_PX4, 6, 0, 4, 3, param_bytewise=True, offboard_prestream_s=1.0,
                    setpoint_mask=VELOCITY_YAW_TYPE_MASK, family="px4")


def conventions_for(autopilot: int) -> FcConventions:
    """PX4 for MAV_AUTOPILOT_PX4, else ArduPilot's (the common dialect of most others)."""
    return PX4 if autopilot == mavlink.MAV_AUTOPILOT_PX4 else ARDUPILOT


@dataclass
class FcState:
    """What the flight controller's HEARTBEAT and COMMAND_ACKs told us."""

    sysid: int = 0
    compid: int = 0
    conventions: FcConventions = ARDUPILOT
    vehicle_type: int = 0
    base_mode: int = 0
    custom_mode: int = 0
    system_status: int = 0
    last_heartbeat_time_s: float = -math.inf     # message time of the last heartbeat
    last_heartbeat_listened_s: float = -math.inf  # the link's listening clock at the last heartbeat
    last_message_wall_s: float = -math.inf       # wall time of the last message of any kind
    heartbeats: int = 0
    acks: dict[int, int] = field(default_factory=dict)   # command -> last MAV_RESULT

    @property
    def detected(self) -> bool:
        return self.heartbeats > 0

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def guided(self) -> bool:
        return self.detected and self.conventions.is_guided(self.custom_mode)

    @property
    def holding(self) -> bool:
        return self.detected and self.conventions.is_hold(self.custom_mode)

    @property
    def mode_name(self) -> str:
        return self.conventions.mode_name(self.custom_mode) if self.detected else "unknown"

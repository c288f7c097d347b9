"""The stand-in's flight-controller parameters: names, types, ranges and defaults, per autopilot.

ArduPilot Rover names (``--autopilot ardupilot``, the default)::

    SYSID_THISMAV    our MAVLink system id (read-only)
    FRAME_CLASS      2 = boat (read-only)
    CRUISE_SPEED     m/s, speed of RTL and position targets            [0, vehicle max]
    GUID_TIMEOUT     s, velocity setpoint timeout in GUIDED            [0.1, 60]
    WP_SPEED         m/s, waypoint speed, 0 = CRUISE_SPEED (kept, no waypoints here)
    EK3_SRC1_YAW     EKF3 yaw source: 0 none, 1 compass, 2 GPS (dual-antenna yaw),
                     3 GPS with compass fallback, 6 external nav, 8 GSF
                     (ArduPilot's AP_NavEKF_Source::SourceYaw); default the source the world's
                     yaw really comes from (the scenario's heading source): "magnetic" -> 1
                     compass, "ins" and "true" -> 6 external nav (an INS or a heading sensor
                     outside the FC; never 2: GPS is denied, so no GNSS yaw)
    COMPASS_USE      1 = the EKF uses the compass
    GPS1_TYPE        0 none, 1 auto, ... 26 (ArduPilot's GPS driver types); default 1
    GPS2_TYPE        the same for a second receiver; default 0
    ARMING_CHECK     bitmask of pre-arm checks, 1 = all
    FS_EKF_ACTION    EKF failsafe: 0 disabled, 1 RTL, 2 Hold
    SIM_GPS1_ENABLE  1 = the simulated GPS delivers; 0 denies GPS like a ``gps_off`` fault
    SIM_SPEEDUP      the simulator's speed-up (read-only)

PX4 names (``--autopilot px4``)::

    MAV_SYS_ID       our MAVLink system id (read-only)
    COM_OF_LOSS_T    s, offboard setpoint timeout                      [0.1, 60]
    EKF2_MAG_TYPE    0 automatic, 1 magnetic heading, 5 none, 6 init; "magnetic" -> 1,
                     "true"/"ins" -> 5 (heading from elsewhere)
    EKF2_GPS_CTRL    bitmask: 1 lon/lat, 2 altitude, 4 3D velocity, 8 dual-antenna heading; 7
                     (no GNSS heading: GPS is denied)
    EKF2_EV_CTRL     bitmask: 1 horizontal position, 2 vertical position, 4 3D velocity, 8 yaw;
                     "true"/"ins" -> 8 (the yaw from outside the FC), "magnetic" -> 0
    SIM_GPS1_ENABLE  as above (a simulator switch, kept under the same name)

Only CRUISE_SPEED, GUID_TIMEOUT / COM_OF_LOSS_T and SIM_GPS1_ENABLE change what the simulator
does; the others are reported and range-checked as a real autopilot would, so tools that read
the vehicle's configuration (which heading source the FC's ATTITUDE yaw comes from) see it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["HEADING_SOURCES", "MAV_PARAM_TYPE_INT32", "MAV_PARAM_TYPE_REAL32", "ParamSpec", "ardupilot_params",
           "heading_source_of", "px4_params"]

MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32 = 6, 9
HEADING_SOURCES = ("true", "ins", "magnetic")
# what each heading source of the world is to the FC's EKF: the compass, or a yaw from outside the FC
# (the INS, or the paper's true-heading sensor), never a GNSS yaw: the stand-in's GPS has no fix
_EK3_SRC1_YAW = {"true": 6, "ins": 6, "magnetic": 1}
_EKF2_MAG_TYPE = {"true": 5, "ins": 5, "magnetic": 1}
_EKF2_EV_CTRL = {"true": 8, "ins": 8, "magnetic": 0}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: MAVLink type, start value, and what may be written (None: read-only)."""

    name: str
    kind: int                                  # MAV_PARAM_TYPE_INT32 or MAV_PARAM_TYPE_REAL32
    default: float
    minimum: float | None = None               # None: read-only
    maximum: float | None = None
    choices: tuple[int, ...] = ()              # an enumeration's allowed values (empty: the range)
    doc: str = ""

    def __post_init__(self) -> None:
        if len(self.name) > 16:
            raise ValueError(f"parameter name {self.name!r} is longer than MAVLink's 16 characters")

    @property
    def writable(self) -> bool:
        return self.minimum is not None

    def rule(self) -> str:
        """The allowed values, for messages."""
        if not self.writable:
            return "read-only"
        if self.choices:
            return "one of " + ", ".join(str(c) for c in self.choices)
        kind = "integer in" if self.kind == MAV_PARAM_TYPE_INT32 else "in"
        return f"{kind} [{self.minimum:g}, {self.maximum:g}]"

    def accepts(self, value: float) -> bool:
        if not self.writable or value != value or value in (float("inf"), float("-inf")):
            return False
        if self.kind == MAV_PARAM_TYPE_INT32 and value != int(value):
            return False
        if self.choices:
            return int(value) in self.choices
        return self.minimum <= value <= self.maximum


def heading_source_of(scenario) -> str:
    """The scenario's declared heading source, read tolerantly: ``[attitude]`` or ``[sensors]``
    ``heading_source`` (attribute or mapping key), else the scenario's own attribute, else "true".

    Raises:
        ValueError: a declared source that is not one of :data:`HEADING_SOURCES`.
    """
    value = None
    for section in ("attitude", "sensors"):
        part = getattr(scenario, section, None)
        if part is None:
            continue
        value = getattr(part, "heading_source", None)
        if value is None and isinstance(part, Mapping):
            value = part.get("heading_source")
        if value is not None:
            break
    if value is None:
        value = getattr(scenario, "heading_source", None)
    source = "true" if value is None else str(value).lower()
    if source not in HEADING_SOURCES:
        raise ValueError(f"scenario heading_source {value!r}: expected one of {', '.join(HEADING_SOURCES)}")
    return source


def _int(name: str, default: int, lo: int, hi: int, choices: tuple[int, ...] = (), doc: str = "") -> ParamSpec:
    return ParamSpec(name, MAV_PARAM_TYPE_INT32, float(default), float(lo), float(hi), choices, doc)


def _real(name: str, default: float, lo: float | None, hi: float | None, doc: str = "") -> ParamSpec:
    return ParamSpec(name, MAV_PARAM_TYPE_REAL32, float(default), lo, hi, (), doc)


def _read_only(name: str, kind: int, value: float, doc: str = "") -> ParamSpec:
    return ParamSpec(name, kind, float(value), None, None, (), doc)


def ardupilot_params(*, sysid: int, cruise_speed_mps: float, setpoint_timeout_s: float, max_speed_mps: float,
                     speedup: float, heading_source: str) -> tuple[ParamSpec, ...]:
    """ArduPilot Rover's names, in the order PARAM_REQUEST_LIST sends them (index = position)."""
    return (
        _read_only("SYSID_THISMAV", MAV_PARAM_TYPE_INT32, sysid, "MAVLink system id"),
        _read_only("FRAME_CLASS", MAV_PARAM_TYPE_INT32, 2, "2 = boat"),
        _real("CRUISE_SPEED", cruise_speed_mps, 0.0, max_speed_mps, "m/s, RTL and position targets"),
        _real("GUID_TIMEOUT", setpoint_timeout_s, 0.1, 60.0, "s, velocity setpoint timeout"),
        _read_only("SIM_SPEEDUP", MAV_PARAM_TYPE_REAL32, speedup, "simulated s per wall s"),
        _int("EK3_SRC1_YAW", _EK3_SRC1_YAW[heading_source], 0, 8, (0, 1, 2, 3, 6, 8),
             "0 none, 1 compass, 2 GPS, 3 GPS+compass fallback, 6 external nav, 8 GSF"),
        _int("COMPASS_USE", 1, 0, 1, (0, 1), "1 = EKF uses the compass"),
        _real("WP_SPEED", 0.0, 0.0, max_speed_mps, "m/s, 0 = CRUISE_SPEED"),
        _int("GPS1_TYPE", 1, 0, 26, (), "GPS driver, 0 none, 1 auto"),
        _int("GPS2_TYPE", 0, 0, 26, (), "second GPS driver, 0 none"),
        _int("ARMING_CHECK", 1, 0, (1 << 24) - 1, (), "pre-arm check bitmask, 1 = all"),
        _int("FS_EKF_ACTION", 1, 0, 2, (0, 1, 2), "EKF failsafe: 0 disabled, 1 RTL, 2 Hold"),
        _int("SIM_GPS1_ENABLE", 1, 0, 1, (0, 1), "0 = the simulated GPS has no fix"),
    )


def px4_params(*, sysid: int, setpoint_timeout_s: float, heading_source: str, **_ignored) -> tuple[ParamSpec, ...]:
    """PX4's names, in the order PARAM_REQUEST_LIST sends them (index = position)."""
    return (
        _read_only("MAV_SYS_ID", MAV_PARAM_TYPE_INT32, sysid, "MAVLink system id"),
        _real("COM_OF_LOSS_T", setpoint_timeout_s, 0.1, 60.0, "s, offboard setpoint timeout"),
        _int("EKF2_MAG_TYPE", _EKF2_MAG_TYPE[heading_source], 0, 6, (0, 1, 5, 6),
             "0 automatic, 1 magnetic heading, 5 none, 6 init"),
        _int("EKF2_GPS_CTRL", 7, 0, 15, (), "1 lon/lat, 2 alt, 4 vel, 8 dual-antenna yaw"),
        _int("EKF2_EV_CTRL", _EKF2_EV_CTRL[heading_source], 0, 15, (), "1 hor. pos, 2 vert. pos, 4 vel, 8 yaw"),
        _int("SIM_GPS1_ENABLE", 1, 0, 1, (0, 1), "0 = the simulated GPS has no fix"),
    )

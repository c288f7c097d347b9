"""The companion's MAVLink edge: connection, identity, flight-controller conventions, outputs.

One :class:`MavlinkLink` owns one pymavlink connection (``udp:``/``udpin:`` listen,
``udpout:`` send first, ``tcp:`` client, ``tcpin:`` server, a serial device as ``DEVICE,BAUD``).
It speaks MAVLink 2 as component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) of the flight controller's
system, reads frames in bulk (``parse_buffer``; pymavlink's UDP ``recv_msg`` returns one message
per datagram read), records both directions to a ``.tlog``, and offers one send helper per
output. It holds no navigation state: the application (:mod:`companion.app`) decides *what*
to send; this module decides *how*, and refuses what must never go out (:func:`guard_setpoint`).

Flight-controller conventions (from its HEARTBEAT, :class:`FcConventions`):

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
``vz`` 0; ``time_boot_ms`` is the latest flight-controller time seen (a lockstep simulator
paces its clock on it). The ``type_mask`` follows the autopilot (:attr:`FcConventions.setpoint_mask`):

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
import select
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink.mavutil is imported: MAVLink 2

from pymavlink import mavutil  # noqa: E402

from companion import wrap_pi  # noqa: E402
from companion.io.position_feed import gps_week_time  # noqa: E402

__all__ = [
    "mavlink",
    "COMPANION_COMPONENT",
    "VELOCITY_YAW_TYPE_MASK",
    "VELOCITY_ONLY_TYPE_MASK",
    "UnsafeSetpoint",
    "Setpoint",
    "guard_setpoint",
    "FcConventions",
    "ARDUPILOT",
    "PX4",
    "FcState",
    "MessageClock",
    "parse_connection",
    "MavlinkLink",
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
GPS_INPUT_IGNORE = (mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ | mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT
                    | mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY)
STATUSTEXT_CHUNK = 50
EXT_POS_TIME_WRAP_S = 250.0   # MAV_CMD_EXTERNAL_POSITION_ESTIMATE param1: wrap <= 250 s


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
    last_heartbeat_wall_s: float = -math.inf     # wall (monotonic) time of the last heartbeat
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


class MessageClock:
    """Message time (s since the flight controller booted) from its ``time_boot_ms``/``time_usec``.

    Monotonic: a smaller stamp (reordered datagram) never moves it back; a jump back by more than
    ``reboot_s`` is reported as a reboot through :attr:`reboots` and restarts the clock.
    ``time_usec`` values that are UNIX time (> 1e15 us, e.g. GPS_RAW_INT) are converted with
    SYSTEM_TIME's pairing of UNIX and boot time.
    """

    UNIX_USEC_LIMIT = 1_000_000_000_000_000   # ~31.7 years after boot; larger means UNIX time

    def __init__(self, reboot_s: float = 10.0) -> None:
        self.now_s = math.nan
        self.unix_minus_boot_s: float | None = None
        self.reboot_s = reboot_s
        self.reboots = 0

    @property
    def started(self) -> bool:
        return math.isfinite(self.now_s)

    def observe_boot_ms(self, time_boot_ms: int) -> float:
        return self._observe(time_boot_ms * 1e-3)

    def stamp_usec(self, time_usec: int) -> float | None:
        """Boot time in s of a ``time_usec`` field (boot or UNIX), None if it cannot be placed."""
        if 0 < time_usec < self.UNIX_USEC_LIMIT:
            return time_usec * 1e-6
        if time_usec and self.unix_minus_boot_s is not None:
            return time_usec * 1e-6 - self.unix_minus_boot_s
        return None

    def observe_system_time(self, time_unix_usec: int, time_boot_ms: int) -> float:
        if time_unix_usec:
            self.unix_minus_boot_s = time_unix_usec * 1e-6 - time_boot_ms * 1e-3
        return self.observe_boot_ms(time_boot_ms)

    def _observe(self, t: float) -> float:
        if not math.isfinite(self.now_s) or t > self.now_s:
            self.now_s = t
        elif t < self.now_s - self.reboot_s:
            self.reboots += 1
            self.now_s = t
        return self.now_s


def parse_connection(text: str) -> tuple[str, int]:
    """(pymavlink device, baud) of a connection string; serial as ``DEVICE,BAUD`` or ``DEVICE:BAUD``.

    >>> parse_connection("/dev/ttyAMA0,921600"), parse_connection("udp:127.0.0.1:14550")
    (('/dev/ttyAMA0', 921600), ('udp:127.0.0.1:14550', 115200))
    """
    text = text.strip()
    for sep in (",", ":"):
        if (text.startswith(("/", "COM", "com")) and sep in text):
            device, _, baud = text.rpartition(sep)
            if baud.isdigit():
                return device, int(baud)
    return text, 115200


# --- the link ---------------------------------------------------------------------------------
@dataclass
class LinkStats:
    messages_in: int = 0
    bytes_in: int = 0
    bad_frames: int = 0
    messages_out: int = 0
    setpoints_sent: int = 0
    setpoints_refused: int = 0
    positions_fed: int = 0
    last_refusal: str = ""


class MavlinkLink:
    """One MAVLink connection of the companion (component 191)."""

    def __init__(self, connect: str, sysid: int | None = None, component: int = COMPANION_COMPONENT,
                 tlog_path: str | os.PathLike | None = None, wall_clock: Callable[[], float] = time.monotonic) -> None:
        self.connect_text = connect
        self.fixed_sysid = sysid
        self.component = component
        self.tlog_path = Path(tlog_path) if tlog_path else None
        self.wall = wall_clock
        self.fc = FcState()
        self.clock = MessageClock()
        self.stats = LinkStats()
        self.conn = None
        self._tlog = None
        self._statustext_id = 0

    # --- connection -------------------------------------------------------------------------
    def open(self) -> None:
        device, baud = parse_connection(self.connect_text)
        self.conn = mavutil.mavlink_connection(device, baud=baud, source_system=self.fixed_sysid or 1,
                                               source_component=self.component, autoreconnect=True)
        if hasattr(self.conn, "port") and hasattr(self.conn.port, "setsockopt"):
            import socket
            try:
                self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            except OSError:  # pragma: no cover - platform limits
                pass
        if self.tlog_path is not None:
            self.tlog_path.parent.mkdir(parents=True, exist_ok=True)
            self._tlog = open(self.tlog_path, "wb", buffering=1 << 16)
            self.conn.mav.set_send_callback(self._log_sent)

    def close(self) -> None:
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:  # pragma: no cover
                pass
            self.conn = None

    def __enter__(self) -> MavlinkLink:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def mav(self):
        return self.conn.mav

    @property
    def sysid(self) -> int:
        return self.conn.mav.srcSystem

    def _log_sent(self, msg) -> None:
        self.stats.messages_out += 1
        if self._tlog is not None:
            self._tlog.write(struct.pack(">Q", int(time.time() * 1e6) & ~3) + msg.get_msgbuf())

    # --- receiving ----------------------------------------------------------------------------
    def wait_readable(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` wall seconds for bytes to read (the parser may also hold some)."""
        if self.conn.mav.buf_len() > 0:
            return True
        fd = getattr(self.conn, "fd", None)
        if fd is None:  # pragma: no cover - connections without a file descriptor
            time.sleep(timeout_s)
            return True
        try:
            readable, _, _ = select.select([fd], [], [], max(timeout_s, 0.0))
        except (OSError, ValueError):
            return False
        return bool(readable)

    def read(self, max_bytes: int = 1 << 16) -> list:
        """Messages parsed from what can be read now without waiting (one datagram or chunk)."""
        conn = self.conn
        try:
            data = conn.recv(max_bytes) if not isinstance(conn, mavutil.mavudp) else conn.recv()
        except (OSError, ConnectionError):
            data = b""
        if data:
            self.stats.bytes_in += len(data)
        try:
            msgs = conn.mav.parse_buffer(data if data else b"") or []
        except Exception:  # noqa: BLE001 - a corrupt frame must not stop the companion
            self.stats.bad_frames += 1
            return []
        out = []
        tlog = self._tlog
        stamp = struct.pack(">Q", int(time.time() * 1e6) & ~3) if tlog is not None else b""
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.stats.bad_frames += 1
                continue
            if tlog is not None:
                tlog.write(stamp + msg.get_msgbuf())
            out.append(msg)
        self.stats.messages_in += len(out)
        return out

    def observe(self, msg) -> bool:
        """Update flight-controller state and message time; True if ``msg`` is from the FC.

        The flight controller is the first system whose component sends a HEARTBEAT with a real
        autopilot (not MAV_AUTOPILOT_INVALID); its system id becomes ours unless fixed.
        """
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        fc = self.fc
        mtype = msg.get_type()
        if not fc.detected:
            if mtype != "HEARTBEAT" or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                return False
            if self.fixed_sysid is not None and src_sys != self.fixed_sysid:
                return False
            fc.sysid, fc.compid = src_sys, src_comp
            fc.conventions = conventions_for(msg.autopilot)
            self.conn.mav.srcSystem = src_sys
            self.conn.target_system, self.conn.target_component = src_sys, src_comp
        if src_sys != fc.sysid or src_comp != fc.compid:
            return False
        now_wall = self.wall()
        fc.last_message_wall_s = now_wall
        clock = self.clock
        boot_ms = getattr(msg, "time_boot_ms", None)
        if mtype == "SYSTEM_TIME":
            clock.observe_system_time(msg.time_unix_usec, msg.time_boot_ms)
        elif boot_ms is not None:
            clock.observe_boot_ms(boot_ms)
        if fc.heartbeats and not math.isfinite(fc.last_heartbeat_time_s) and clock.started:
            fc.last_heartbeat_time_s = clock.now_s   # the heartbeat came before the first time stamp
        if mtype == "HEARTBEAT":
            fc.heartbeats += 1
            fc.vehicle_type = msg.type
            fc.base_mode, fc.custom_mode, fc.system_status = msg.base_mode, msg.custom_mode, msg.system_status
            fc.last_heartbeat_time_s = clock.now_s
            fc.last_heartbeat_wall_s = now_wall
        elif mtype == "COMMAND_ACK" and getattr(msg, "target_component", 0) in (0, self.component):
            fc.acks[msg.command] = msg.result
        return True

    def heartbeat_age_s(self) -> tuple[float, float]:
        """(message-time age, wall-time age) of the FC's last heartbeat."""
        msg_age = self.clock.now_s - self.fc.last_heartbeat_time_s if self.clock.started else math.inf
        return msg_age, self.wall() - self.fc.last_heartbeat_wall_s

    # --- sending ------------------------------------------------------------------------------
    def time_boot_ms(self) -> int:
        return int(self.clock.now_s * 1000.0) & 0xFFFFFFFF if self.clock.started else 0

    def send_heartbeat(self, state: int = mavlink.MAV_STATE_ACTIVE) -> None:
        self.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, state)

    def send_setpoint(self, course_rad: float, speed_mps: float, max_speed_mps: float) -> bool:
        """SET_POSITION_TARGET_GLOBAL_INT (velocity, with the yaw where the autopilot wants it), or
        nothing if :func:`guard_setpoint` refuses."""
        try:
            sp = guard_setpoint(course_rad, speed_mps, max_speed_mps)
        except UnsafeSetpoint as err:
            self.stats.setpoints_refused += 1
            self.stats.last_refusal = str(err)
            return False
        self.mav.set_position_target_global_int_send(
            self.time_boot_ms(), self.fc.sysid, self.fc.compid, mavlink.MAV_FRAME_GLOBAL_INT,
            self.fc.conventions.setpoint_mask, 0, 0, 0.0, sp.vn_mps, sp.ve_mps, 0.0, 0.0, 0.0, 0.0, sp.yaw_rad, 0.0)
        self.stats.setpoints_sent += 1
        return True

    def send_command_long(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.fc.acks.pop(command, None)
        self.mav.command_long_send(self.fc.sysid, self.fc.compid, command, 0, *p[:7])

    def send_set_mode(self, main: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE with the custom main/sub mode of the detected autopilot."""
        conv = self.fc.conventions
        if conv.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            self.send_command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)
        else:
            self.send_command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main)

    def send_guided_mode(self) -> None:
        c = self.fc.conventions
        self.send_set_mode(c.guided_main, c.guided_sub)

    def send_hold_mode(self) -> None:
        c = self.fc.conventions
        self.send_set_mode(c.hold_main, c.hold_sub)

    def send_arm(self, arm: bool = True) -> None:
        self.send_command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0)

    def send_message_interval(self, message_id: int, rate_hz: float) -> None:
        interval_us = -1.0 if rate_hz < 0 else (0.0 if rate_hz == 0 else 1e6 / rate_hz)
        self.send_command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float(message_id), interval_us)

    def send_statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT, split into 50-character chunks with a shared id when longer."""
        data = text.encode("utf-8", errors="replace")
        if len(data) <= STATUSTEXT_CHUNK:
            self.mav.statustext_send(severity, data, 0, 0)
            return
        self._statustext_id = (self._statustext_id % 65535) + 1
        chunks = [data[i:i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
        for seq, chunk in enumerate(chunks):
            self.mav.statustext_send(severity, chunk, self._statustext_id, seq)
        if len(chunks[-1]) == STATUSTEXT_CHUNK:
            self.mav.statustext_send(severity, b"", self._statustext_id, len(chunks))

    def send_named_float(self, name: str, value: float) -> None:
        if len(name) > 10:
            raise ValueError(f"NAMED_VALUE_FLOAT name {name!r} longer than 10 characters")
        self.mav.named_value_float_send(self.time_boot_ms(), name.encode("ascii"), float(value))

    def send_external_position(self, lat_deg: float, lon_deg: float, sigma_m: float) -> bool:
        """MAV_CMD_EXTERNAL_POSITION_ESTIMATE as COMMAND_INT (ArduPilot accepts it only there).

        param1 message time wrapped at 250 s, param2 processing delay 0, param3 1-sigma accuracy
        (m), x/y latitude/longitude in degE7, z NaN (altitude not used).
        """
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        accuracy = float(sigma_m) if math.isfinite(sigma_m) and sigma_m > 0.0 else math.nan
        stamp = math.fmod(self.clock.now_s, EXT_POS_TIME_WRAP_S) if self.clock.started else 0.0
        lon = ((lon_deg + 180.0) % 360.0) - 180.0
        self.mav.command_int_send(self.fc.sysid, self.fc.compid, mavlink.MAV_FRAME_GLOBAL,
                                  mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE, 0, 0,
                                  stamp, 0.0, accuracy, math.nan,
                                  int(round(lat_deg * 1e7)), int(round(lon * 1e7)), math.nan)
        return True

    def send_odometry(self, north_m: float, east_m: float, sigma_m: float) -> bool:
        """ODOMETRY in the flight controller's local NED frame (position only; the rest unknown)."""
        if not (math.isfinite(north_m) and math.isfinite(east_m)):
            return False
        var = float(sigma_m) ** 2 if math.isfinite(sigma_m) and sigma_m > 0.0 else math.nan
        nan = math.nan
        pose_cov = [nan] * 21
        pose_cov[0], pose_cov[6] = var, var   # upper-triangular row-major: xx at 0, yy at 6
        self.mav.odometry_send(int(self.clock.now_s * 1e6) if self.clock.started else 0,
                               mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                               float(north_m), float(east_m), nan, [nan, nan, nan, nan], nan, nan, nan,
                               nan, nan, nan, pose_cov, [nan] * 21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 50)
        return True

    def send_gps_input(self, lat_deg: float, lon_deg: float, sigma_m: float, alt_m: float = 0.0,
                       satellites: int = 10) -> bool:
        """GPS_INPUT as a MAVLink GPS (ArduPilot GPSn_TYPE 14, gps_id 1 = the second GPS).

        Position only (velocities flagged ignored: the flight controller derives them from the
        positions); ``horiz_accuracy`` the honest 1-sigma; GPS week and week-ms from the flight
        controller's own clock (SYSTEM_TIME), as its GPS checks compare them.
        """
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        if self.clock.unix_minus_boot_s is None or not self.clock.started:
            return False   # no date yet: a GPS without time fails the flight controller's checks
        unix_s = self.clock.now_s + self.clock.unix_minus_boot_s
        week, week_ms = gps_week_time(unix_s)
        accuracy = float(sigma_m) if math.isfinite(sigma_m) and sigma_m > 0.0 else 100.0
        lon = ((lon_deg + 180.0) % 360.0) - 180.0
        self.mav.gps_input_send(int(unix_s * 1e6), 1, GPS_INPUT_IGNORE, week_ms, week, 3,
                                int(round(lat_deg * 1e7)), int(round(lon * 1e7)), float(alt_m),
                                1.0, 1.0, 0.0, 0.0, 0.0, 0.0, min(accuracy, 1e6), 5.0, satellites)
        self.stats.positions_fed += 1
        return True

"""What the companion tells an operator's ground station about itself, and reading it back.

The companion (component 191 of the vehicle's system) says it in messages a ground station
already decodes; this module is the one place that gives their fields a meaning, both ways: the
companion encodes with :func:`failsafe_bits` and :func:`space_weather_bits`, and a ground-station
tool (the MAVProxy module :mod:`fcmpc.mavproxy`) reads with :class:`StatusReader`.

Once a second of wall time (an operator's pace, whatever a simulator's speed-up):

``HEARTBEAT``               ``custom_mode`` the phase (:data:`PHASES`: 0 wait_fc, 1 startup, 2 ready,
                            3 running, 5 done); ``system_status`` MAV_STATE_CRITICAL in failsafe,
                            ACTIVE while running, STANDBY otherwise
``GLOBAL_POSITION_INT_COV`` the navigator's estimate (once a mission has one), flown on from the last
                            control step with the command; velocity north/east (m/s); the covariance
                            of the last step: north-north, north-east, east-east in m^2 in the first
                            two rows and columns of the 6x6 matrix, everything else NaN
``NAMED_VALUE_FLOAT``       ``FC_ERR`` the estimate's 1-sigma (m), ``FC_REM`` distance to go (m), of the
                            last step (the same names the companion sends after every step)
``NAMED_VALUE_INT``         ``FC_FS`` the failsafe conditions (:data:`FAILSAFE_BITS`), ``FC_SWX`` the
                            space-weather feed (:data:`SPACE_WEATHER_BITS`)

The destination is the companion's parameters ``NAV_DEST_LAT`` / ``NAV_DEST_LON`` and the feed's
values ``NAV_KP`` / ``NAV_SYMH`` (PARAM_VALUE, answered to PARAM_REQUEST_READ). Commands are
COMMAND_LONG to component 191 (:mod:`companion.process.operator_commands`).

>>> failsafe_names(failsafe_bits(["mag: no valid magnetometer sample for 2.5 s"], True))
['mag']
>>> space_weather_names(space_weather_bits(kp_fresh=True, symh_fresh=False, declared=True, disturbed=True,
...                                        f_weighed=False))
['NAV_KP fresh', 'storm declared', 'disturbance active', 'F set aside']
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.io.link.conventions import COMPANION_COMPONENT
from companion.process.machine import STATE_CODES

__all__ = ["COMPANION_COMPONENT", "DEST_PARAMS", "FAILSAFE_BITS", "FEED_PARAMS", "PHASES", "SPACE_WEATHER_BITS",
           "STATUS_PERIOD_WALL_S", "StatusReader", "failsafe_bits", "failsafe_names", "space_weather_bits",
           "space_weather_names"]

PHASES: dict[int, str] = {code: name for name, code in STATE_CODES.items()}
STATUS_PERIOD_WALL_S = 1.0

# a failsafe reason is "kind: text" (companion.failsafe); "recovering": all healthy, waiting out resume_s
FAILSAFE_BITS: dict[str, int] = {"mag": 1, "attitude": 2, "heartbeat": 4, "params": 8, "nav": 16, "recovering": 32}
SPACE_WEATHER_BITS: dict[str, int] = {"NAV_KP fresh": 1, "NAV_SYMH fresh": 2, "storm declared": 4,
                                      "disturbance active": 8, "F weighed": 16, "F set aside": 32}
# NAMED_VALUE_FLOAT / NAMED_VALUE_INT name -> StatusReader field
NAMED_FIELDS = {"FC_ERR": "sigma_m", "FC_REM": "remaining_m", "FC_FS": "failsafes", "FC_SWX": "space_weather"}
DEST_PARAMS = ("NAV_DEST_LAT", "NAV_DEST_LON")
FEED_PARAMS = ("NAV_KP", "NAV_SYMH")


def failsafe_bits(reasons: list[str], active: bool) -> int:
    """FC_FS: one bit per failsafe condition in ``reasons``; ``recovering`` when ``active`` without one."""
    bits = 0
    for reason in reasons:
        bits |= FAILSAFE_BITS.get(reason.split(":", 1)[0].strip(), 0)
    return bits | (FAILSAFE_BITS["recovering"] if active and not bits else 0)


def space_weather_bits(*, kp_fresh: bool, symh_fresh: bool, declared: bool, disturbed: bool,
                       f_weighed: bool | None) -> int:
    """FC_SWX: which readings are fresh, and the filter's state (``f_weighed`` None: F not in the set)."""
    flags = {"NAV_KP fresh": kp_fresh, "NAV_SYMH fresh": symh_fresh, "storm declared": declared,
             "disturbance active": disturbed, "F weighed": f_weighed is True, "F set aside": f_weighed is False}
    return sum(bit for name, bit in SPACE_WEATHER_BITS.items() if flags[name])


def _names(bits: int, table: dict[str, int]) -> list[str]:
    return [name for name, bit in table.items() if bits & bit]


def failsafe_names(bits: int) -> list[str]:
    return _names(bits, FAILSAFE_BITS)


def space_weather_names(bits: int) -> list[str]:
    return _names(bits, SPACE_WEATHER_BITS)


@dataclass
class StatusReader:
    """The companion's status as a ground station receives it: hand every message to
    :meth:`packet`; read the fields, or :meth:`lines` for people. ``wall_s`` stamps say how old
    each part is (the reader keeps no clock of its own)."""

    system: int = 1
    component: int = COMPANION_COMPONENT
    heard_wall_s: float = math.nan
    phase: str = ""
    system_status: int = -1
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    cov_ne_m2: tuple[float, float, float] = (math.nan, math.nan, math.nan)   # nn, ne, ee
    velocity_ne_mps: tuple[float, float] = (math.nan, math.nan)
    estimate_wall_s: float = math.nan
    sigma_m: float = math.nan
    remaining_m: float = math.nan
    failsafes: int | None = None
    space_weather: int | None = None
    params: dict[str, float] = field(default_factory=dict)
    acks: list[tuple[int, int]] = field(default_factory=list)     # (command, result), newest last

    def packet(self, msg, wall_s: float) -> bool:
        """Take ``msg`` if it is the companion's (True); anything else is left alone."""
        if msg.get_srcSystem() != self.system or msg.get_srcComponent() != self.component:
            return False
        mtype = msg.get_type()
        if mtype == "HEARTBEAT":
            self.heard_wall_s = wall_s
            self.phase = PHASES.get(msg.custom_mode, f"unknown ({msg.custom_mode})")
            self.system_status = msg.system_status
        elif mtype == "GLOBAL_POSITION_INT_COV":
            cov = list(msg.covariance)
            self.lat_deg, self.lon_deg = msg.lat * 1e-7, msg.lon * 1e-7
            self.cov_ne_m2 = (cov[0], cov[1], cov[7])
            self.velocity_ne_mps = (msg.vx, msg.vy)
            self.estimate_wall_s = wall_s
        elif mtype in ("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT") and _text(msg.name) in NAMED_FIELDS:
            setattr(self, NAMED_FIELDS[_text(msg.name)], msg.value)
        elif mtype == "PARAM_VALUE":
            self.params[_text(msg.param_id)] = float(msg.param_value)
        elif mtype == "COMMAND_ACK":
            self.acks.append((msg.command, msg.result))
            del self.acks[:-20]
        else:
            return False
        return True

    @property
    def destination(self) -> tuple[float, float] | None:
        lat, lon = (self.params.get(name, math.nan) for name in DEST_PARAMS)
        return (lat, lon) if math.isfinite(lat) and math.isfinite(lon) else None

    @property
    def estimate(self) -> tuple[float, float] | None:
        return (self.lat_deg, self.lon_deg) if math.isfinite(self.lat_deg) and math.isfinite(self.lon_deg) else None

    def lines(self, wall_s: float) -> list[str]:
        """``fcmpc status``: what the companion last said, for people."""
        if not math.isfinite(self.heard_wall_s):
            return [f"fcmpc: nothing heard from the companion ({self.system}/{self.component}) yet"]
        age = wall_s - self.heard_wall_s
        out = [f"fcmpc: phase {self.phase}" + (" (FAILSAFE)" if self.failsafes else "")
               + (f", last heard {age:.0f} s ago" if age > 3.0 * STATUS_PERIOD_WALL_S else "")]
        remaining = f"{self.remaining_m / 1000.0:.2f} km" if math.isfinite(self.remaining_m) else "unknown"
        sigma = f"{self.sigma_m:.0f} m" if math.isfinite(self.sigma_m) else "unknown (no estimate yet)"
        out.append(f"fcmpc: distance to go {remaining}, estimate 1-sigma {sigma}")
        if self.estimate is not None:
            old = wall_s - self.estimate_wall_s
            out.append(f"fcmpc: estimate {self.lat_deg:.5f},{self.lon_deg:.5f}"
                       + (f" ({old:.0f} s old)" if old > 3.0 * STATUS_PERIOD_WALL_S else ""))
        if self.destination is not None:
            out.append(f"fcmpc: destination {self.destination[0]:.5f},{self.destination[1]:.5f}")
        if self.space_weather is not None:
            said = space_weather_names(self.space_weather)
            values = ", ".join(f"{name} {self.params[name]:g}" for name in FEED_PARAMS
                               if f"{name} fresh" in said and name in self.params)
            stale = [name for name in FEED_PARAMS if f"{name} fresh" not in said]
            words = [w for w in said if not w.endswith(" fresh")]
            out.append("fcmpc: space weather: " + "; ".join(
                part for part in ((values or "no fresh reading"), (f"not renewed: {', '.join(stale)}" if stale else ""),
                                  ", ".join(words) or "no storm declared") if part))
        if self.failsafes is not None:
            out.append("fcmpc: failsafes: " + (", ".join(failsafe_names(self.failsafes)) or "none"))
        return out


def _text(value) -> str:
    if isinstance(value, (bytes, bytearray)):
        value = value.decode("ascii", errors="replace")
    return value.split("\x00", 1)[0]

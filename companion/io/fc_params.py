"""Reading the flight controller's own parameters, and what they say about its heading.

The companion must know whether the yaw it gets in ATTITUDE comes from the same compass it
measures the field with. On ArduPilot (EKF3) that is ``EK3_SRC1_YAW`` (1 compass, 2 GPS,
3 GPS with compass fallback, 6 ExternalNav, 8 GSF) together with ``COMPASS_USE``; on PX4
(EKF2) ``EKF2_MAG_TYPE`` (0 automatic, 1 magnetic heading, 5 none, 6 init only) and the GNSS
dual-antenna heading bit of ``EKF2_GPS_CTRL``. A compass-derived yaw is the compass heading
plus a declination table evaluated at the flight controller's own position estimate, so D
measured against it carries no position information (see :mod:`companion.nav.elements`).

:class:`FcParamReader` asks for named parameters with PARAM_REQUEST_READ (component of the
flight controller), collects the PARAM_VALUE answers, retries unanswered names with a
doubling interval in message time, and gives up after a deadline; :func:`judge_heading` turns
what was read into a :class:`HeadingVerdict`. PX4 sends INT32 values bytewise, ArduPilot as
a C cast.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

__all__ = ["FcParamReader", "HeadingVerdict", "judge_heading", "HEADING_PARAMS", "ARDUPILOT_HEADING_PARAMS",
           "PX4_HEADING_PARAMS"]

ARDUPILOT_HEADING_PARAMS = ("EK3_SRC1_YAW", "COMPASS_USE", "AHRS_EKF_TYPE")
PX4_HEADING_PARAMS = ("EKF2_MAG_TYPE", "EKF2_GPS_CTRL", "EKF2_EV_CTRL")
HEADING_PARAMS = {"ardupilot": ARDUPILOT_HEADING_PARAMS, "px4": PX4_HEADING_PARAMS}

_PX4_INT_PARAMS = frozenset(PX4_HEADING_PARAMS)
_EK3_YAW = {0: "none", 1: "compass", 2: "GPS (dual antenna)", 3: "GPS with compass fallback",
            6: "ExternalNav", 8: "GSF (gyro and GPS velocity)"}   # AP_NavEKF3 EK3_SRC1_YAW


@dataclass(frozen=True)
class HeadingVerdict:
    """Whether the flight controller's yaw is compass-derived (None: could not be told)."""

    compass_derived: bool | None
    reason: str


def judge_heading(autopilot: str, values: dict[str, float]) -> HeadingVerdict:
    """The verdict on ``values`` read from an ``autopilot`` ("ardupilot" or "px4").

    >>> judge_heading("ardupilot", {"EK3_SRC1_YAW": 1, "COMPASS_USE": 1}).compass_derived
    True
    >>> judge_heading("ardupilot", {"EK3_SRC1_YAW": 2, "COMPASS_USE": 1}).compass_derived
    False
    """
    if autopilot == "px4":
        mag_type = values.get("EKF2_MAG_TYPE")
        if mag_type is None:
            return HeadingVerdict(None, "EKF2_MAG_TYPE not answered")
        gps_ctrl = int(values.get("EKF2_GPS_CTRL", 0))
        ev_ctrl = int(values.get("EKF2_EV_CTRL", 0))
        if int(mag_type) == 5 and gps_ctrl & 8:
            return HeadingVerdict(False, "EKF2_MAG_TYPE 5 (none) with GNSS dual-antenna heading")
        if int(mag_type) == 5 and ev_ctrl & 8:
            return HeadingVerdict(False, "EKF2_MAG_TYPE 5 (none) with external-vision yaw (EKF2_EV_CTRL bit 3)")
        if int(mag_type) == 5:
            return HeadingVerdict(False, "EKF2_MAG_TYPE 5: no magnetometer in the yaw")
        # 0 automatic and 1 heading fuse it throughout; 6 "init" takes the initial yaw from it and
        # then integrates the gyro: that yaw still carries the compass and the declination table
        return HeadingVerdict(True, f"EKF2_MAG_TYPE {int(mag_type)}: yaw from the magnetometer")
    src = values.get("EK3_SRC1_YAW")
    use = values.get("COMPASS_USE")
    ekf = values.get("AHRS_EKF_TYPE")
    if ekf is not None and int(ekf) not in (3,):
        if use is not None and int(use) == 0:
            return HeadingVerdict(False, f"AHRS_EKF_TYPE {int(ekf)} with COMPASS_USE 0")
        return HeadingVerdict(True, f"AHRS_EKF_TYPE {int(ekf)} (not EKF3): yaw from the compass")
    if src is None:
        return HeadingVerdict(None, "EK3_SRC1_YAW not answered")
    name = _EK3_YAW.get(int(src), f"source {int(src)}")
    if int(src) in (1, 3):
        if use is not None and int(use) == 0 and int(src) != 1:
            return HeadingVerdict(False, f"EK3_SRC1_YAW {int(src)} ({name}) with COMPASS_USE 0")
        # 3/8 fall back to the compass exactly when GPS is lost: the flight this navigator is for
        return HeadingVerdict(True, f"EK3_SRC1_YAW {int(src)} ({name})")
    return HeadingVerdict(False, f"EK3_SRC1_YAW {int(src)} ({name})")


class FcParamReader:
    """Asks the flight controller for ``names`` and collects the answers (message time)."""

    def __init__(self, names: tuple[str, ...], first_retry_s: float = 1.0, deadline_s: float = 15.0,
                 bytewise: bool = False) -> None:
        self.names = tuple(names)
        self.values: dict[str, float] = {}
        self.first_retry_s = first_retry_s
        self.deadline_s = deadline_s
        self.bytewise = bytewise
        self.started_s = math.nan
        self._next_s = -math.inf
        self._interval_s = first_retry_s
        self.requests = 0

    @property
    def complete(self) -> bool:
        return all(name in self.values for name in self.names)

    def expired(self, now_s: float) -> bool:
        return math.isfinite(self.started_s) and now_s - self.started_s >= self.deadline_s

    @property
    def missing(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if n not in self.values)

    def due(self, now_s: float) -> tuple[str, ...]:
        """Names to (re)request now; doubles the retry interval each time."""
        if not math.isfinite(self.started_s):
            self.started_s = now_s
        if self.complete or self.expired(now_s) or now_s < self._next_s:
            return ()
        self._next_s = now_s + self._interval_s
        self._interval_s *= 2.0
        self.requests += 1
        return self.missing

    def packet(self, msg) -> bool:
        """Take a PARAM_VALUE from the flight controller; True if it was one of ours."""
        raw = msg.param_id
        name = (raw.decode("ascii", errors="replace") if isinstance(raw, bytes) else raw).split("\x00", 1)[0]
        if name not in self.names:
            return False
        value = float(msg.param_value)
        if self.bytewise and name in _PX4_INT_PARAMS:
            value = float(struct.unpack("<i", struct.pack("<f", value))[0])
        self.values[name] = value
        return True

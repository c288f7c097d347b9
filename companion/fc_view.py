"""What the companion knows about its flight controller beyond the heartbeat.

Three questions decide how the navigator may use what the flight controller reports:

1. **Is its yaw compass-derived?** (:mod:`companion.io.fc_params`) Then declination measured
   against it is not a measurement, and the navigator steers on the heading-free (I, F).
   ``COMP_HEADING_SRC`` 1/2 declares the answer; 0 reads the flight controller's parameters.
2. **Is its position independent of this navigator?** GLOBAL_POSITION_INT is GPS-aided while
   the flight controller's own GPS (GPS_RAW_INT, which ArduPilot and PX4 send for their first
   receiver) has a 3D fix, and it is our own estimate fed back while we feed GPS_INPUT and the
   flight controller reports our GPS as its second (GPS2_RAW with a fix). Only otherwise (a
   navigation-grade INS free-running, as the simulator's, which ignores GPS_INPUT) is it an
   independent INS the fusion may use.
3. **Does it need our position?** With ``COMP_POS_PUB`` 3 the companion sends GPS_INPUT at the
   setpoint rate as the flight controller's second GPS: while its own GPS has a 3D fix, an echo
   of its GPS-aided position claiming fewer satellites (its own GPS stays primary, and its
   arming checks see a healthy second GPS); once its GPS is lost, a smooth position
   (:class:`companion.io.position_feed.PositionFeed`) that starts from the last echo, so there
   is no step at the switch-over, and blends towards the navigator's estimate.

It also tracks arming refusals (COMMAND_ACK of MAV_CMD_COMPONENT_ARM_DISARM and the
flight controller's "PreArm:"/"Arm:" STATUSTEXT) so the application can say why and back off,
and the flight controller's own failsafes ("EKF failsafe" ... "EKF failsafe cleared"), so a mode
change it made itself is told from a pilot's.
All times are message time.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from companion.io.fc_params import HEADING_PARAMS, FcParamReader, HeadingVerdict, judge_heading
from companion.io.link import MavlinkLink
from companion.io.position_feed import PositionFeed

__all__ = ["FcView", "ArmingBackoff", "GPS_FIX_MAX_AGE_S", "PUBLISH_GPS_INPUT"]

GPS_FIX_MAX_AGE_S = 3.0       # no GPS_RAW_INT with a 3D fix for this long: the FC has no GPS
PUBLISH_GPS_INPUT = 3         # COMP_POS_PUB value
FC_TEXTS_KEPT = 20            # the flight controller's last STATUSTEXTs kept (the status page shows them)
ARM_BACKOFF_FIRST_S = 2.0
ARM_BACKOFF_MAX_S = 60.0


@dataclass
class ArmingBackoff:
    """Retry interval for arming: doubles on every refusal, back to the first on success."""

    interval_s: float = ARM_BACKOFF_FIRST_S
    refusals: int = 0
    last_reason: str = ""

    def refused(self, reason: str) -> float:
        self.refusals += 1
        self.last_reason = reason or self.last_reason
        self.interval_s = min(self.interval_s * 2.0, ARM_BACKOFF_MAX_S)
        return self.interval_s

    def reset(self) -> None:
        self.interval_s = ARM_BACKOFF_FIRST_S


class FcView:
    """The flight controller's heading source, GPS state and position feed; see the module docstring."""

    def __init__(self, heading_source: int, position_publish: int, blend_mps: float = 0.5,
                 accel_mps2: float = math.inf) -> None:
        self.heading_source = heading_source
        self.position_publish = position_publish
        self.reader: FcParamReader | None = None
        self.family = ""
        self.gps_fix_time_s = -math.inf       # last GPS_RAW_INT with fix_type >= 3
        self.feed_ack_time_s = -math.inf      # last GPS2_RAW with a fix while we feed: the FC uses our GPS
        self.gps_seen = False
        self.feed = PositionFeed(blend_mps, accel_mps2)
        self.feeding_own = False              # the feed carries our estimate (the FC has no GPS)
        self.arming = ArmingBackoff()
        self.prearm_text = ""
        self.fc_failsafe = ""                 # the FC's own failsafe in force ("EKF failsafe"), "" when none
        self.texts: deque[str] = deque(maxlen=FC_TEXTS_KEPT)   # its last STATUSTEXTs, "[message time] text"
        self._verdict: HeadingVerdict | None = None

    # --- receive ---------------------------------------------------------------------------
    def start(self, family: str, bytewise: bool, now_s: float) -> None:
        """The flight controller was detected: ask for its heading parameters (unless declared)."""
        self.family = family
        self._verdict = None
        if self.heading_source == 1:
            self._verdict = HeadingVerdict(False, "COMP_HEADING_SRC 1: declared independent of the compass")
        elif self.heading_source == 2:
            self._verdict = HeadingVerdict(True, "COMP_HEADING_SRC 2: declared compass-derived")
        else:
            self.reader = FcParamReader(HEADING_PARAMS[family], bytewise=bytewise)
            self.reader.started_s = now_s

    def packet(self, msg, now_s: float) -> None:
        """Receive hook for the flight controller's messages (``now_s``: message time)."""
        mtype = msg.get_type()
        if mtype == "GPS_RAW_INT":
            self.gps_seen = True
            if msg.fix_type >= 3:
                self.gps_fix_time_s = now_s
        elif mtype == "GPS2_RAW":
            if msg.fix_type >= 3 and self.feeding_own:
                self.feed_ack_time_s = now_s
        elif mtype == "PARAM_VALUE" and self.reader is not None:
            self.reader.packet(msg)
        elif mtype == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", errors="replace")
            if msg.get_srcComponent() != 191:
                self.texts.append(f"[{now_s:10.1f}] {text.strip()}")
            if text.startswith(("PreArm:", "Arm:", "Arming denied", "Preflight Fail")):
                self.prearm_text = text.strip()
            elif "failsafe" in text.lower() and msg.get_srcComponent() != 191:
                self.fc_failsafe = "" if "cleared" in text.lower() else text.strip()

    def rebooted(self) -> None:
        """The flight controller rebooted: what was timed on its old clock is void (a GPS fix at
        old-clock time T would otherwise count as fresh until the new clock reached T + 3 s), and
        the position feed starts again from the navigator's estimate."""
        self.gps_fix_time_s = self.feed_ack_time_s = -math.inf
        self.feed.stop()
        self.feeding_own = False
        self.prearm_text = ""
        self.fc_failsafe = ""

    # --- heading ---------------------------------------------------------------------------
    def poll_requests(self, link: MavlinkLink, now_s: float) -> None:
        """Send due PARAM_REQUEST_READs to the flight controller."""
        if self.reader is None:
            return
        for name in self.reader.due(now_s):
            link.mav.param_request_read_send(link.fc.sysid, link.fc.compid, name.encode("ascii"), -1)

    def heading_verdict(self, now_s: float) -> HeadingVerdict | None:
        """The verdict, or None while the parameters are still being read."""
        if self._verdict is not None:
            return self._verdict
        reader = self.reader
        if reader is None:
            return None
        if reader.complete or (reader.expired(now_s) and reader.values):
            self._verdict = judge_heading(self.family, reader.values)
            if self._verdict.compass_derived is None:
                self._verdict = HeadingVerdict(True, f"{self._verdict.reason}: assumed compass-derived")
        elif reader.expired(now_s):
            self._verdict = HeadingVerdict(True, f"no answer to {', '.join(reader.names)} within "
                                                 f"{reader.deadline_s:g} s: assumed compass-derived")
        return self._verdict

    # --- GPS and position --------------------------------------------------------------------
    def gps_has_fix(self, now_s: float) -> bool:
        """The flight controller's own GPS has a 3D fix now."""
        return now_s - self.gps_fix_time_s <= GPS_FIX_MAX_AGE_S

    def position_independent(self, now_s: float) -> tuple[bool, str]:
        """Whether GLOBAL_POSITION_INT may be used as an independent INS, and why (not)."""
        if self.gps_has_fix(now_s):
            return False, "GPS-aided"
        if self.feeding_own and now_s - self.feed_ack_time_s <= GPS_FIX_MAX_AGE_S:
            return False, "our own estimate fed back (GPS_INPUT, reported as its GPS2)"
        return True, "free inertial" if self.gps_seen else "no GPS reported"

    def feed_wanted(self) -> bool:
        """Whether GPS_INPUT goes out at all (COMP_POS_PUB 3): an echo while the FC has GPS,
        our own position once it has not."""
        return self.position_publish == PUBLISH_GPS_INPUT

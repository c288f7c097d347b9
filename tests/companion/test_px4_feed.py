"""The PX4 side of the position feed (HIL_GPS) and the streams the companion turns off on PX4.

Real pymavlink framing: each message is packed and parsed back, as PX4's receiver would see it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest
from pymavlink.dialects.v20 import common

from companion.io.link.outputs import HIL_GPS
from companion.io.position_feed import feed_message_name, send_feed, send_hil_gps
from companion.io.px4 import unused_streams
from companion.io.sensors.mag_units import mag_messages


@dataclass
class _Clock:
    now_s: float = 100.0
    unix_minus_boot_s: float | None = 1715364000.0
    started: bool = True


@dataclass
class _Stats:
    positions_fed: int = 0


@dataclass
class _Link:
    """What send_feed needs of MavlinkLink: ``mav`` (packing into ``sent``), ``send_hil_gps``, ``clock``, ``stats``."""

    clock: _Clock = field(default_factory=_Clock)
    stats: _Stats = field(default_factory=_Stats)
    sent: list = field(default_factory=list)

    def __post_init__(self) -> None:
        self.mav = common.MAVLink(self, srcSystem=4, srcComponent=191)
        self.parser = common.MAVLink(None)

    def write(self, data: bytes) -> None:
        self.sent.extend(self.parser.parse_buffer(bytes(data)) or [])

    def send_hil_gps(self, *fields) -> None:
        HIL_GPS.send(self.mav, *fields)

    def send_gps_input(self, lat_deg, lon_deg, sigma_m, satellites=10) -> bool:
        self.sent.append(("GPS_INPUT", lat_deg, lon_deg))
        return True


def test_hil_gps_carries_position_accuracy_velocity_and_px4s_time():
    link = _Link()
    assert send_hil_gps(link, 32.5, 152.25, 5.0, vn_mps=-2.0, ve_mps=2.0, satellites=10)
    [msg] = link.sent
    assert msg.get_type() == "HIL_GPS" and msg.get_srcSystem() == 4
    assert msg.fix_type == 3 and msg.satellites_visible == 10 and msg.id == 1
    assert msg.lat == 325000000 and msg.lon == 1522500000
    assert msg.eph == 500 and msg.epv == 500                        # cm: EKF2_REQ_EPH/EPV compare metres
    assert (msg.vn, msg.ve) == (-200, 200) and msg.vel == round(math.hypot(2.0, 2.0) * 100)
    assert msg.cog == 13500                                          # south-east, cdeg from north
    assert msg.time_usec == int((100.0 + 1715364000.0) * 1e6)
    assert link.stats.positions_fed == 1


def test_hil_gps_refuses_what_it_cannot_say():
    link = _Link()
    assert not send_hil_gps(link, math.nan, 152.0, 5.0)
    assert not send_hil_gps(link, 95.0, 152.0, 5.0)
    link.clock.unix_minus_boot_s = None                              # no SYSTEM_TIME yet: a GPS without time
    assert not send_hil_gps(link, 32.0, 152.0, 5.0)
    assert link.sent == [] and link.stats.positions_fed == 0


def test_hil_gps_at_rest_has_no_course_and_wraps_longitude():
    link = _Link()
    send_hil_gps(link, -10.0, 190.0, math.nan)
    [msg] = link.sent
    assert msg.cog == 65535 and msg.lon == -1700000000 and msg.eph == 10000   # unknown sigma: 100 m claimed


@pytest.mark.parametrize("family, message", [("px4", "HIL_GPS"), ("ardupilot", "GPS_INPUT")])
def test_feed_goes_out_in_the_message_each_autopilot_accepts(family, message):
    link = _Link()
    assert feed_message_name(family) == message
    send_feed(link, family, 33.0, 152.0, 5.0, 6)
    sent = link.sent[0]
    assert (sent[0] if isinstance(sent, tuple) else sent.get_type()) == message


def test_unused_streams_only_on_px4():
    assert unused_streams("ardupilot") == ()
    assert "ATTITUDE" not in unused_streams("px4") and "SCALED_IMU" not in unused_streams("px4")
    assert "HIGHRES_IMU" in unused_streams("px4") and "HIGHRES_IMU" not in unused_streams("px4", keep=("HIGHRES_IMU",))
    assert all(hasattr(common, f"MAVLINK_MSG_ID_{name}") for name in unused_streams("px4"))


@pytest.mark.parametrize("values, derived", [
    ({"EKF2_MAG_TYPE": 1, "EKF2_GPS_CTRL": 7, "EKF2_EV_CTRL": 0}, True),      # the SIH rover's own settings
    ({"EKF2_MAG_TYPE": 6, "EKF2_GPS_CTRL": 7, "EKF2_EV_CTRL": 0}, True),      # initial yaw from the compass
    ({"EKF2_MAG_TYPE": 5, "EKF2_GPS_CTRL": 7, "EKF2_EV_CTRL": 8}, False),     # yaw from external vision
    ({"EKF2_MAG_TYPE": 1, "EKF2_GPS_CTRL": 7, "EKF2_EV_CTRL": 8}, True),      # the compass still in the yaw
])
def test_px4_heading_verdict(values, derived):
    from companion.io.fc_params import PX4_HEADING_PARAMS, judge_heading

    assert "EKF2_EV_CTRL" in PX4_HEADING_PARAMS
    assert judge_heading("px4", values).compass_derived is derived


def test_px4_echo_carries_the_velocity_and_is_flown_on_ardupilots_is_not():
    from companion.io.position_feed import send_echo
    from companion.io.sensors.mavlink_source import FcPosition

    pos = FcPosition(99.0, 33.0, 152.0, 0.0, 3.0, 0.0)          # 1 s old, 3 m/s north
    link = _Link()
    send_echo(link, "px4", pos, 100.0, 5.0, 6)
    [msg] = link.sent
    assert msg.get_type() == "HIL_GPS" and msg.vn == 300 and msg.satellites_visible == 6
    assert msg.lat - 330000000 == pytest.approx(3.0 / 111_000 * 1e7, rel=0.02)   # 3 m further north
    link = _Link()
    send_echo(link, "ardupilot", pos, 100.0, 5.0, 6)
    assert link.sent == [("GPS_INPUT", 33.0, 152.0)]


def test_px4_magnetometer_is_read_without_ekf2s_bias_state():
    """PX4's HIGHRES_IMU subtracts EKF2's magnetometer-bias state, which wanders by thousands of nT on
    a level rover: the companion reads sensor_mag (SCALED_IMU) there; on ArduPilot HIGHRES_IMU, the
    compass field untruncated, with RAW_IMU as the fallback."""
    assert mag_messages("px4") == ("SCALED_IMU",) and mag_messages("ardupilot") == ("HIGHRES_IMU", "RAW_IMU")
    assert mag_messages("px4", "HIGHRES_IMU") == ("HIGHRES_IMU",)

"""Positions from MAVLink (companion.io.sensors.mavlink_source): GLOBAL_POSITION_INT and GPS_RAW_INT
carry latitude and longitude as int32 degE7, which hold up to 214.7 degrees. A value beyond the
Earth from the flight controller (or from anyone speaking with its system id on an unsigned link)
must not reach the navigator as the INS position or the GPS start.

Oracle: the ranges of latitude and longitude; property-based over every int32 pair (hypothesis).
"""
from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.link import MessageClock
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.mission import Mission, Phase
from companion.nav.step_io import Measurement
from companion.params import NavConfig

INT32 = st.integers(-2**31, 2**31 - 1)


def _global_position(lat_e7: int, lon_e7: int):
    return mavlink.MAVLink_global_position_int_message(1000, lat_e7, lon_e7, 0, 0, 100, -50, 0, 0)


def _gps_raw(lat_e7: int, lon_e7: int):
    return mavlink.MAVLink_gps_raw_int_message(1_000_000, 3, lat_e7, lon_e7, 0, 100, 100, 0, 0, 12)


@given(INT32, INT32)
def test_the_fc_position_is_on_the_earth_or_not_taken(lat_e7, lon_e7):
    """Whatever int32 pair arrives, the decoder's FC position is on the Earth; a pair beyond it
    leaves the last one as it was and says why."""
    dec = MavlinkDecoder(MessageClock(), imu=False)
    dec.decode(_global_position(330_000_000, 1_520_000_000))
    dec.decode(_global_position(lat_e7, lon_e7))
    pos = dec.fc_position
    assert -90.0 <= pos.lat_deg <= 90.0 and -180.0 <= pos.lon_deg <= 180.0
    on_earth = abs(lat_e7) <= 900_000_000 and abs(lon_e7) <= 1_800_000_000
    if not on_earth:
        assert (pos.lat_deg, pos.lon_deg) == (33.0, 152.0)
        assert "outside the Earth" in dec.last_problem["position"]


@given(INT32, INT32)
def test_a_gps_fix_beyond_the_earth_is_not_valid(lat_e7, lon_e7):
    """A GPS_RAW_INT beyond the Earth is decoded as an invalid sample (never a start position)."""
    [sample] = MavlinkDecoder(MessageClock(), imu=False).decode(_gps_raw(lat_e7, lon_e7))
    on_earth = abs(lat_e7) <= 900_000_000 and abs(lon_e7) <= 1_800_000_000
    assert sample.valid == on_earth


def test_an_ins_position_beyond_the_earth_is_a_rejected_period_not_an_error():
    """The navigation core's last guard: an INS position that reaches it beyond the Earth (from a
    source other than MAVLink) is a measurement it rejects (issue 47: the navigator never raises on a
    measurement, nor ends the mission on one): the period is held with the reason named and counted,
    the last command flies on, and nothing of the mission changes."""
    config = NavConfig()
    mission = Mission(config)
    mission.set_start_fix(2.5)
    lat, lon = config.start_lat_deg, config.start_lon_deg
    for k in range(5):
        e = mission.model.elements(lat, lon, config.alt_m, config.year)
        ins = (lat, lon) if k < 4 else (123.0, lon)
        last = cmd if k else None
        cmd = mission.step(Measurement(360.0 * k, e.decl_deg, e.incl_deg, *ins, 360.0, e.f_nt))
        lat, lon = lat - 0.02, lon + 0.02
    assert cmd.phase == Phase.HOLD and not cmd.done, (cmd.phase, cmd.reason)
    assert cmd.reason.startswith("measurement rejected") and "123" in cmd.reason, cmd.reason
    assert mission.rejected_measurements == 1
    assert math.isfinite(cmd.est_lat_deg) and -90.0 <= cmd.est_lat_deg <= 90.0
    assert (cmd.course_rad, cmd.speed_mps) == (last.course_rad, last.speed_mps)   # the last command flies on

"""What the companion does differently on PX4, measured against PX4 SITL with SIH (v1.17 main).

PX4's onboard link (``mavlink start -m onboard``, the mode a companion port runs in) streams
about 400 messages per second the companion never reads: ATTITUDE_QUATERNION at 50 Hz,
LOCAL_POSITION_NED and ODOMETRY at 30 Hz, ALTITUDE, DISTANCE_SENSOR and VFR_HUD at 10 Hz, on
top of ATTITUDE at 100 Hz and HIGHRES_IMU at 50 Hz (which the companion turns down to what it
averages). PX4 honours MAV_CMD_SET_MESSAGE_INTERVAL on that link (COMMAND_ACK ACCEPTED, and the
rates follow), with -1 turning a stream off. Parsing what is not used costs the companion CPU,
and in SITL at a speed factor of N it is N times as much per wall second, so the companion turns
those streams off (:func:`unused_streams`) before it asks for its own.

Other PX4 conventions live where the rest of their kind is: modes and setpoint masks in
:mod:`companion.io.mavlink_link`, the heading parameters in :mod:`companion.io.fc_params`, the
position feed (HIL_GPS) in :mod:`companion.io.position_feed`.
"""
from __future__ import annotations

__all__ = ["PX4_UNUSED_STREAMS", "unused_streams"]

PX4_UNUSED_STREAMS = ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ODOMETRY", "ALTITUDE", "DISTANCE_SENSOR",
                      "VFR_HUD")


def unused_streams(family: str) -> tuple[str, ...]:
    """Streams to turn off on a flight controller of ``family`` ("ardupilot", "px4").

    >>> unused_streams("ardupilot"), unused_streams("px4")[:2]
    ((), ('ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED'))
    """
    return PX4_UNUSED_STREAMS if family == "px4" else ()

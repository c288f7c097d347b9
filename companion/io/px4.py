"""What the companion does differently on PX4, measured against PX4 SITL with SIH (v1.17 main).

PX4's onboard link (``mavlink start -m onboard``, the mode a companion port runs in) streams
about 400 messages per second the companion never reads: ATTITUDE_QUATERNION at 50 Hz,
LOCAL_POSITION_NED and ODOMETRY at 30 Hz, ALTITUDE, DISTANCE_SENSOR and VFR_HUD at 10 Hz, on
top of ATTITUDE at 100 Hz and HIGHRES_IMU at 50 Hz (which the companion turns down to what it
averages). PX4 honours MAV_CMD_SET_MESSAGE_INTERVAL on that link (COMMAND_ACK ACCEPTED, and the
rates follow), with -1 turning a stream off. Parsing what is not used costs the companion CPU,
and in SITL at a speed factor of N it is N times as much per wall second, so the companion turns
those streams off (:func:`unused_streams`) before it asks for its own.

The magnetometer is read from SCALED_IMU (:func:`companion.io.sensors.mag_units.mag_messages`), PX4's ``sensor_mag`` as the
driver reports it, not from HIGHRES_IMU: PX4's HIGHRES_IMU stream subtracts EKF2's body-field bias
*state* (``estimator_sensor_bias.mag_bias``) from ``vehicle_magnetometer``, and on a level ground
vehicle that state is not observable (body z and the earth field's vertical are the same axis).
Measured on PX4 SITL with SIH (Ackermann rover, 15 min driving a square at 3 m/s): SCALED_IMU's
|F| stayed at 42,400 nT +- 400 (30 s means), HIGHRES_IMU's fell by 5,500 nT, as the bias state's
body z reached -9,200 nT (body y up to +2,800 nT on a straight leg); CAL_MAG0_*OFF stayed 0. The
companion calibrates the field itself at the known start (``NAV_CALIBRATE``, ``MAG_OFS_*``), as it
does with ArduPilot's RAW_IMU, so it must read a field without an estimator's state in it.

Other PX4 conventions live where the rest of their kind is: modes and setpoint masks in
:mod:`companion.io.link`, the heading parameters in :mod:`companion.io.fc_params`, the
position feed (HIL_GPS) in :mod:`companion.io.position_feed`.
"""
from __future__ import annotations

__all__ = ["PX4_UNUSED_STREAMS", "unused_streams"]

PX4_UNUSED_STREAMS = ("ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ODOMETRY", "ALTITUDE", "DISTANCE_SENSOR",
                      "VFR_HUD", "HIGHRES_IMU")


def unused_streams(family: str, keep: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Streams to turn off on a flight controller of ``family`` ("ardupilot", "px4"), but ``keep``
    (the magnetometer messages in use).

    >>> unused_streams("ardupilot"), unused_streams("px4")[:2], "HIGHRES_IMU" in unused_streams("px4", ("HIGHRES_IMU",))
    ((), ('ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED'), False)
    """
    return tuple(name for name in (PX4_UNUSED_STREAMS if family == "px4" else ()) if name not in keep)

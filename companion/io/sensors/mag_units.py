"""How autopilots put a magnetometer reading into MAVLink, and how to read it back in nT.

**Integer messages** (RAW_IMU, SCALED_IMU/2/3) carry milligauss in int16. ArduPilot
(``GCS_MAVLINK::send_raw_imu`` / ``send_scaled_imu``) and PX4 (its SCALED_IMU streams,
``msg.xmag = sensor_mag.x * 1000.0f``) assign a float to the int16 field, a C conversion that
*truncates toward zero*. A count ``c`` therefore stands for the interval ``(c - 1, c]`` mG when
positive, ``[c, c + 1)`` when negative and ``(-1, 1)`` at zero. Taking ``c`` itself is biased by
half a count, 50 nT, toward zero on every axis, and the bias follows each axis' sign, so it moves
with the heading: on ArduPilot SITL's noise-free compass it was up to 100 nT per axis, an
inclination error of up to 0.1 deg that changed at every turn (issue 16). :func:`count_to_nt`
takes the interval's midpoint, ``c + 0.5 sign(c)``, which is unbiased once the sensor's noise
spans a count, and never more than half a count off.

**HIGHRES_IMU** is float. The MAVLink spec says gauss, and PX4 sends gauss. ArduPilot sends
``compass.get_field() * 1000.0f`` (``GCS_MAVLINK::send_highres_imu``, "convert to gauss"), and
``get_field`` is already milligauss, so its unit is 1e-6 gauss = 0.1 nT. Measured on ArduRover
4.7.0-dev SITL: HIGHRES_IMU 302897.875 where RAW_IMU said 302 (:data:`HIGHRES_NT_PER_UNIT`).

**Which message** (:func:`mag_messages`, in order of preference): on ArduPilot HIGHRES_IMU, the
same compass field without the truncation, then RAW_IMU for a build without HIGHRES_IMU
(``AP_MAVLINK_MSG_HIGHRES_IMU_ENABLED`` off on small boards); on PX4 SCALED_IMU, the raw
``sensor_mag``, because PX4's HIGHRES_IMU subtracts EKF2's body-field bias state
(:mod:`companion.io.px4`).
"""
from __future__ import annotations

__all__ = ["GAUSS_TO_NT", "HIGHRES_NT_PER_UNIT", "MAG_MESSAGES_BY_FAMILY", "MILLIGAUSS_TO_NT", "count_to_nt",
           "highres_nt_per_unit", "mag_messages"]

MILLIGAUSS_TO_NT = 100.0   # 1 mG = 1e-7 T = 100 nT
GAUSS_TO_NT = 1e5
# nT per HIGHRES_IMU magnetometer unit, by autopilot family (the spec's gauss unless listed)
HIGHRES_NT_PER_UNIT = {"ardupilot": 0.1}
MAG_MESSAGES_BY_FAMILY = {"ardupilot": ("HIGHRES_IMU", "RAW_IMU"), "px4": ("SCALED_IMU",)}


def count_to_nt(count: int) -> float:
    """One axis of an integer (mG, truncated toward zero) magnetometer field, in nT: the midpoint.

    >>> count_to_nt(302), count_to_nt(-21), count_to_nt(0)
    (30250.0, -2150.0, 0.0)
    """
    if count > 0:
        return (count + 0.5) * MILLIGAUSS_TO_NT
    if count < 0:
        return (count - 0.5) * MILLIGAUSS_TO_NT
    return 0.0


def highres_nt_per_unit(family: str) -> float:
    """nT per HIGHRES_IMU magnetometer unit for an autopilot family ("ardupilot", "px4").

    >>> highres_nt_per_unit("ardupilot"), highres_nt_per_unit("px4")
    (0.1, 100000.0)
    """
    return HIGHRES_NT_PER_UNIT.get(family, GAUSS_TO_NT)


def mag_messages(family: str, chosen: str | None = None) -> tuple[str, ...]:
    """The messages to read the magnetometer from, preferred first: ``chosen`` (``--mag-message``)
    alone, or the family's.

    >>> mag_messages("ardupilot"), mag_messages("px4"), mag_messages("px4", "HIGHRES_IMU")
    (('HIGHRES_IMU', 'RAW_IMU'), ('SCALED_IMU',), ('HIGHRES_IMU',))
    """
    return (chosen,) if chosen else MAG_MESSAGES_BY_FAMILY.get(family, ("RAW_IMU",))

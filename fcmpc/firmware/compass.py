"""A real compass for the firmware's own simulation, and the calibration a user gives it (issue 47).

ArduPilot's SITL flies a perfect compass by default (``SIM_MAG_RND 0``, no offsets, no soft iron,
no motor interference). :data:`ARDUPILOT_REAL` puts a real installation's errors on its first
compass, each with where it comes from:

- **Hard and soft iron**: the calibration a real vehicle's ArduPilot computed for its external
  compass (``COMPASS_OFS_*``, ``COMPASS_DIA_*``, ``COMPASS_ODI_*`` in the ``PARM`` records of
  ``../shared/data/logs/log171.bin``, a Pixhawk 1 with an external HMC5883L, 2015-11-21):
  offsets -97.8, 118.1, 213.2 mGauss; diagonal 0.9957, 1.0081, 1.0027; off-diagonal 0.0183,
  -0.0027, -0.0042. ArduPilot's SITL compass applies ``SIM_MAG1_*`` so that exactly those
  ``COMPASS_*`` values correct it (``AP_Compass_SITL``), so the vehicle's distortion is this one.
- **Noise**: the same log's MAG samples at rest (5-60 s): sample-to-sample scatter 1.8, 1.8, 1.0
  mGauss per axis (the difference of consecutive samples over sqrt 2). ``SIM_MAG_RND`` draws each
  axis uniformly in +-RND, standard deviation RND / sqrt 3, so 2.6 mGauss gives 1.5.
- **Motor interference** (``SIM_MAG_MOT``, mGauss per ampere of the simulated battery current, added
  in the body frame): a CompassMot result a user reported for his vehicle with current sensing
  (COMPASS_MOTCT 2): -0.71, -0.14, +0.68 mGauss/A, "interference level 7" %, a good installation by
  ArduPilot's guideline of under 30 % (discuss.ardupilot.org, "COMPASS_MOTCT setting", 2015). This
  SITL's motorboat draws 50 A at full throttle (measured: SYS_STATUS.current_battery 5000 cA in
  MANUAL at full throttle), so at cruise the compass is offset by a few tens of mGauss (a few
  thousand nT) whenever the motor runs, and not while the boat stands for its start-up average.
  **Not with ``--physics json``** (measured 2026-12-06, docs/notes/2026-12-06-ardupilot-json-lockstep.md
  section 6): there SITL's compass shows no current dependence at all (the body field's residual
  against the model within 50 nT at 40, 10 and 1 A on one heading, where 0.68 mGauss/A would move
  z by 2,000 nT), although SYS_STATUS reports 39.9 A while cruising. SITL adds ``SIM_MAG_MOT``
  times its physics backend's battery current (``Aircraft::update_mag_field_bf``); where the JSON
  backend's differs from the one SYS_STATUS reports was not traced.

How a boat's user calibrates it: a boat cannot be turned through every attitude for ArduPilot's
onboard calibration, so ArduPilot's "large vehicle" calibration (``MAV_CMD_FIXED_MAG_CAL_YAW``) is
the way: with GPS and the vehicle's true heading known (a landmark, a dock), ArduPilot computes
the offsets from its own field tables. It learns no soft iron, and motor interference is left to
CompassMot, a separate procedure with the motor run up against its mooring that the large-vehicle
calibration does not include (COMPASS_MOTCT stays at its default 0): what is left is what such a
boat flies with. :func:`calibrate_fixed_yaw` does it with the true heading from the simulator's
SIMSTATE.

``--compass ideal`` keeps today's perfect compass.
"""
from __future__ import annotations

import math
import time

from fcmpc.firmware.monitor import FirmwareMonitor, mavlink

__all__ = ["ARDUPILOT_REAL", "COMPASSES", "calibrate_fixed_yaw", "ardupilot_compass_params"]

COMPASSES = ("real", "ideal")

ARDUPILOT_REAL: dict[str, float] = {
    "SIM_MAG1_OFS_X": -97.79, "SIM_MAG1_OFS_Y": 118.11, "SIM_MAG1_OFS_Z": 213.18,
    "SIM_MAG1_DIA_X": 0.99573, "SIM_MAG1_DIA_Y": 1.00815, "SIM_MAG1_DIA_Z": 1.00274,
    "SIM_MAG1_ODI_X": 0.018288, "SIM_MAG1_ODI_Y": -0.002727, "SIM_MAG1_ODI_Z": -0.004213,
    "SIM_MAG_RND": 2.6,
    "SIM_MAG_MOT_X": -0.71, "SIM_MAG_MOT_Y": -0.14, "SIM_MAG_MOT_Z": 0.68,
    # one compass, as on a boat with one external unit (the second and third SITL compasses would
    # otherwise stay perfect and outvote the first in ArduPilot's consistency checks)
    "COMPASS_USE2": 0, "COMPASS_USE3": 0,
}


def ardupilot_compass_params(compass: str) -> dict[str, float]:
    """ArduPilot SITL parameters for ``compass`` ("real" or "ideal")."""
    if compass not in COMPASSES:
        raise ValueError(f"compass {compass!r}: choose from {', '.join(COMPASSES)}")
    return dict(ARDUPILOT_REAL) if compass == "real" else {}


def calibrate_fixed_yaw(monitor: FirmwareMonitor, timeout_wall_s: float = 120.0) -> str:
    """ArduPilot's large-vehicle compass calibration, as a boat's user does it: once GPS has a 3D fix
    and the simulator reports the true heading, MAV_CMD_FIXED_MAG_CAL_YAW with that heading (ArduPilot's
    own position and field tables). Returns the words for the records; RuntimeError if refused."""
    monitor.pump(lambda m: m.gps_fix >= 3 and bool(m.truth), timeout_wall_s, "a GPS fix and the true heading")
    yaw_deg = monitor.truth[-1].yaw_deg
    monitor.acks.pop(mavlink.MAV_CMD_FIXED_MAG_CAL_YAW, None)
    sent = time.monotonic()
    monitor.send_command(mavlink.MAV_CMD_FIXED_MAG_CAL_YAW, yaw_deg, 0, 0, 0)
    monitor.pump(lambda m: mavlink.MAV_CMD_FIXED_MAG_CAL_YAW in m.acks, timeout_wall_s, "the compass calibration")
    result = monitor.acks.pop(mavlink.MAV_CMD_FIXED_MAG_CAL_YAW)
    if result != mavlink.MAV_RESULT_ACCEPTED:
        raise RuntimeError(f"ArduPilot refused the fixed-yaw compass calibration (result {result}); "
                           f"texts: {monitor.texts[-3:]}")
    offsets = monitor.read_params(("COMPASS_OFS_X", "COMPASS_OFS_Y", "COMPASS_OFS_Z"), timeout_wall_s)
    words = ", ".join(f"{v:+.1f}" for v in offsets.values())
    return (f"compass calibrated at true heading {yaw_deg:.1f} deg (MAV_CMD_FIXED_MAG_CAL_YAW, "
            f"{time.monotonic() - sent:.1f} s): COMPASS_OFS {words} mGauss; soft iron and motor interference "
            f"left as installed")


def uniform_sd(rnd: float) -> float:
    """Standard deviation of SITL's magnetometer noise for ``SIM_MAG_RND`` (uniform in +-RND).

    >>> round(uniform_sd(2.6), 2)
    1.5
    """
    return rnd / math.sqrt(3.0)

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
  ArduPilot's guideline of under 30 % (discuss.ardupilot.org, "COMPASS_MOTCT setting", 2015). SITL
  multiplies it by its physics backend's battery current, which neither of our boats' backends sets
  (traced in docs/notes/2026-12-06-ardupilot-json-lockstep.md, section 9): the JSON backend of the shared
  binary carries no battery key, and the built-in motorboat never calls ``update_battery()`` (the
  run-up below measured 0.003 mGauss/A on it), while SYS_STATUS shows SITL's separate 50 A x throttle.
  **With ``--physics json``** the rig therefore moves ``SIM_MAG_MOT`` to our world, which puts the same
  field on the compass through ``SIM_MAG1_OFS`` from the throttle ArduPilot commands and the current SITL
  reports for it (:mod:`sitl.physics.motor_field`, :func:`fcmpc.firmware.ardupilot_json_rig.motor_field`):
  cruising at 80 % (40 A) the compass is offset by about (-28, -6, +27) mGauss (4,000 nT), and not while
  the boat stands for its start-up average. The built-in motorboat still flies without it.

How a boat's user calibrates it: a boat cannot be turned through every attitude for ArduPilot's
onboard calibration, so ArduPilot's "large vehicle" calibration (``MAV_CMD_FIXED_MAG_CAL_YAW``) is
the way: with GPS and the vehicle's true heading known (a landmark, a dock), ArduPilot computes
the offsets from its own field tables. It learns no soft iron (left as installed), and no motor
interference: that is CompassMot's, the motor run up against the mooring while the compass is
watched. Copter does it onboard (``MAV_CMD_PREFLIGHT_CALIBRATION`` param6 1, ``ArduCopter/compassmot.cpp``);
Rover has no CompassMot, so a boat's user does what it does from the ground station:
:func:`calibrate_motor_interference` runs the throttle up ahead and astern on the mooring (MANUAL, rudder
amidships), fits ArduPilot's corrected field (RAW_IMU) against its battery monitor's current (SYS_STATUS),
the waves' roll and pitch taken out by ATTITUDE, and sets ``COMPASS_MOTCT 2`` (current based) and
``COMPASS_MOT_X/Y/Z`` (= minus the field's change per ampere: ArduPilot adds ``COMPASS_MOT x current``
after its other corrections, ``AP_Compass_Backend::correct_field``). :func:`calibrate_fixed_yaw` takes
the true heading from the simulator's SIMSTATE. ``--compass real-nomot`` flies the same compass with
the motor left uncompensated (COMPASS_MOTCT 0), as a user who skips CompassMot does.

``--compass ideal`` keeps today's perfect compass.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fcmpc.firmware.monitor import FirmwareMonitor, mavlink

__all__ = ["ARDUPILOT_REAL", "COMPASSES", "calibrate_fixed_yaw", "ardupilot_compass_params", "MotorFit",
           "fit_motor_interference", "measure_motor_interference", "calibrate_motor_interference"]

COMPASSES = ("real", "real-nomot", "ideal")     # real-nomot: the same compass, its motor left uncompensated

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
    """ArduPilot SITL parameters for ``compass`` (one of :data:`COMPASSES`)."""
    if compass not in COMPASSES:
        raise ValueError(f"compass {compass!r}: choose from {', '.join(COMPASSES)}")
    return dict(ARDUPILOT_REAL) if compass.startswith("real") else {}


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
            f"{time.monotonic() - sent:.1f} s): COMPASS_OFS {words} mGauss; soft iron left as installed")


# The motor run-up on the mooring (what Copter's onboard CompassMot does, from the ground station: Rover has
# none): MANUAL, rudder amidships, the throttle held at each level for MOT_HOLD_S of firmware time, ahead and
# astern in turn so that the boat ends where it began; the first MOT_SETTLE_S of each level left out
MOT_LEVELS = (0.0, 0.5, -0.5, 0.75, -0.75, 1.0, -1.0, 0.0)
MOT_HOLD_S = 12.0          # two or more wave periods
MOT_SETTLE_S = 2.0
MOT_MIN_SPAN_A = 10.0       # a sweep that moved the measured current less than this fits nothing


@dataclass(frozen=True)
class MotorFit:
    """The field's change per ampere (mGauss/A, body axes, as ArduPilot's corrected compass reads it),
    the field at zero current, the residual's rms (mGauss), the current's range (A) and the samples."""

    per_amp: tuple[float, float, float]
    at_zero: tuple[float, float, float]
    residual_mgauss: float
    current_span_a: tuple[float, float]
    samples: int

    @property
    def compass_mot(self) -> tuple[float, float, float]:
        """ArduPilot's ``COMPASS_MOT_X/Y/Z`` (COMPASS_MOTCT 2): it adds ``COMPASS_MOT x current`` to the
        corrected field (``AP_Compass_Backend::correct_field``), so the opposite of the change per ampere."""
        return tuple(-v for v in self.per_amp)

    def words(self) -> str:
        """The fit for the records."""
        mot = ", ".join(f"{v:+.3f}" for v in self.compass_mot)
        return (f"motor interference fitted on the mooring ({self.samples} samples, {self.current_span_a[0]:.1f}-"
                f"{self.current_span_a[1]:.1f} A, residual {self.residual_mgauss:.1f} mGauss, interference "
                f"{self.interference_pct():.0f} %): COMPASS_MOTCT 2, COMPASS_MOT {mot} mGauss/A")

    def interference_pct(self) -> float:
        """CompassMot's figure: the largest current's field change against the field, in percent."""
        field = float(np.linalg.norm(self.at_zero))
        return 100.0 * float(np.linalg.norm(self.per_amp)) * max(abs(a) for a in self.current_span_a) / field


def fit_motor_interference(current_a, field_mgauss, tilt_rad=None) -> MotorFit:
    """Least squares of each body axis of the field against the battery current (field = at_zero +
    per_amp x current); ValueError when the current spans less than :data:`MOT_MIN_SPAN_A`. ``tilt_rad``
    (N x 2: roll, pitch) adds each as a regressor: a boat rolling and pitching in the waves turns the
    Earth's field in its body axes by about tilt x field (800 nT rms measured on our world's waves at
    the mooring), which the fit then takes out instead of counting it as noise.

    >>> i = np.array([0.0, 10.0, 20.0, 40.0])
    >>> f = np.outer(i, [-0.71, -0.14, 0.68]) + [200.0, 50.0, 400.0]
    >>> fit = fit_motor_interference(i, f)
    >>> [round(v, 3) for v in fit.compass_mot], round(fit.residual_mgauss, 6)
    ([0.71, 0.14, -0.68], 0.0)
    """
    current = np.asarray(current_a, dtype=float)
    field = np.asarray(field_mgauss, dtype=float).reshape(-1, 3)
    if current.size != field.shape[0] or current.size < 3:
        raise ValueError(f"{current.size} currents for {field.shape[0]} field samples: need >= 3 pairs")
    if current.max() - current.min() < MOT_MIN_SPAN_A:
        raise ValueError(f"the current spanned {current.min():.1f}-{current.max():.1f} A: less than "
                         f"{MOT_MIN_SPAN_A:g} A, no motor interference can be fitted")
    columns = [np.ones_like(current), current]
    if tilt_rad is not None:
        tilt = np.asarray(tilt_rad, dtype=float).reshape(-1, 2)
        columns += [tilt[:, 0], tilt[:, 1]]
    design = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(design, field, rcond=None)
    residual = field - design @ coef
    return MotorFit(tuple(float(v) for v in coef[1]), tuple(float(v) for v in coef[0]),
                    float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))),
                    (float(current.min()), float(current.max())), int(current.size))


def measure_motor_interference(monitor: FirmwareMonitor, timeout_wall_s: float = 300.0) -> MotorFit:
    """The motor run-up (:data:`MOT_LEVELS`): ArduPilot's corrected compass (RAW_IMU, mGauss) against
    its battery monitor's current (SYS_STATUS) and its attitude's roll and pitch (ATTITUDE), each at 10 Hz,
    fitted by :func:`fit_motor_interference`. Armed (forced, as on a mooring without GPS checks) in
    MANUAL and disarmed after, the mode and the streams' rates restored."""
    samples: list[tuple[float, ...]] = []   # firmware time, current, field x y z, roll, pitch
    current, tilt = [math.nan], [math.nan, math.nan]

    def on_status(msg) -> None:
        current[0] = msg.current_battery * 0.01 if msg.current_battery >= 0 else math.nan

    def on_attitude(msg) -> None:
        tilt[:] = msg.roll, msg.pitch

    def on_imu(msg) -> None:
        if math.isfinite(current[0]) and math.isfinite(tilt[0]):
            samples.append((monitor.time_s, current[0], msg.xmag, msg.ymag, msg.zmag, *tilt))

    streams = (mavlink.MAVLINK_MSG_ID_RAW_IMU, mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_ATTITUDE)
    monitor.listeners.update(RAW_IMU=on_imu, SYS_STATUS=on_status, ATTITUDE=on_attitude)
    for message_id in streams:
        monitor.send_command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e5)
    mode = monitor.mode
    try:
        monitor.conn.mav.set_mode_send(monitor.target_system, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0)  # MANUAL
        monitor.pump(lambda m: m.mode == 0, timeout_wall_s, "MANUAL for the motor run-up")
        monitor.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
        monitor.pump(lambda m: m.armed, timeout_wall_s, "armed for the motor run-up")
        windows = []
        for level in MOT_LEVELS:
            start = monitor.time_s
            windows.append((start + MOT_SETTLE_S, start + MOT_HOLD_S))
            while monitor.time_s < start + MOT_HOLD_S:     # RC_OVERRIDE_TIME (3 s): renewed every second
                monitor.conn.mav.rc_channels_override_send(monitor.target_system, 1, 1500, 65535,
                                                           int(round(1500 + 500 * level)), *(65535,) * 5)
                t = monitor.time_s
                monitor.pump(lambda m, t=t: m.time_s >= t + 1.0, timeout_wall_s, "the motor run-up")
    finally:
        monitor.conn.mav.rc_channels_override_send(monitor.target_system, 1, *(0,) * 8)    # released
        monitor.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
        monitor.pump(lambda m: not m.armed, timeout_wall_s, "disarmed after the motor run-up")
        if mode >= 0:
            monitor.conn.mav.set_mode_send(monitor.target_system, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)
        for message_id in streams:     # 0: back to the port's stream groups
            monitor.send_command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 0)
        for name in ("RAW_IMU", "SYS_STATUS", "ATTITUDE"):
            monitor.listeners.pop(name, None)
    kept = np.array([s for s in samples if any(a <= s[0] < b for a, b in windows)])
    if kept.size == 0:
        raise RuntimeError("the motor run-up recorded no compass sample with a battery current")
    return fit_motor_interference(kept[:, 1], kept[:, 2:5], kept[:, 5:7])


def calibrate_motor_interference(monitor: FirmwareMonitor, timeout_wall_s: float = 300.0) -> MotorFit:
    """CompassMot as a boat's user does it on the mooring (:func:`measure_motor_interference`), then
    ``COMPASS_MOTCT 2`` (current based) and ``COMPASS_MOT_X/Y/Z`` set and read back."""
    fit = measure_motor_interference(monitor, timeout_wall_s)
    values = dict(zip(("COMPASS_MOT_X", "COMPASS_MOT_Y", "COMPASS_MOT_Z"), fit.compass_mot))
    for name, value in {**values, "COMPASS_MOTCT": 2}.items():
        monitor.set_param(name, value)
    got = monitor.read_params((*values, "COMPASS_MOTCT"), timeout_wall_s)
    if got["COMPASS_MOTCT"] != 2 or any(abs(got[k] - v) > 1e-3 for k, v in values.items()):
        raise RuntimeError(f"ArduPilot did not take the motor compensation: {got}")
    return fit


def uniform_sd(rnd: float) -> float:
    """Standard deviation of SITL's magnetometer noise for ``SIM_MAG_RND`` (uniform in +-RND).

    >>> round(uniform_sd(2.6), 2)
    1.5
    """
    return rnd / math.sqrt(3.0)

"""The flight controller's attitude estimate: where its heading comes from, and its errors.

The declination the companion measures is ``D_meas = D_true + (yaw_est - yaw_true)``, so the
heading source decides what D is worth. Per scenario (``[attitude] heading_source``):

``true``
    an independent true-heading sensor (marine gyrocompass, or a dual-antenna GNSS heading
    carried through a short outage): ``yaw_est = yaw + b + x(t) + w``, with a per-run bias
    ``b ~ N(0, heading_bias_deg^2)``, a first-order Gauss-Markov drift ``x`` of standard
    deviation ``heading_drift_deg`` and correlation time ``heading_drift_tau_s`` (sampled
    exactly), and the white noise ``w`` of the sensor model (``attitude_noise_deg``).
``ins``
    the INS's own azimuth error: ``yaw_est = yaw + psi_z(t) + w`` with ``psi_z`` taken from the
    same 15-state propagation (:meth:`sitl.world.ins.InsErrorModel.attitude_error_rad`) that
    makes the INS position error, so heading and position errors are consistent.
``magnetic``
    what ArduPilot's EKF3 or PX4's EKF2 report when the compass gives yaw: the yaw that makes
    the measured (calibrated, tilt-compensated) body field agree with the declination of a
    table evaluated at the flight controller's own position estimate, ``yaw_est = D_table(p_fc)
    - atan2(h_y, h_x) + w`` (:func:`compass_yaw_rad`); the table is IGRF-14
    (:func:`sitl.world.igrf.igrf14_model`), as ArduPilot's are generated from IGRF, while the
    navigator uses WMM. D measured against this yaw is the table's declination at p_fc plus
    noise: it carries almost no position information.

Tilt (roll, pitch): the true wave attitude plus, when ``tilt_from_ins``, the INS tilt errors
rotated into the body axes, plus a per-run AHRS bias ``N(0, tilt_bias_deg^2)`` per axis, plus
the white noise. Defaults are all zero: the paper's ideal world (true yaw plus white noise).

Angles in radians unless a name says degrees; yaw from true north, clockwise (MAVLink).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["HEADING_SOURCES", "AttitudeErrorConfig", "AttitudeErrors", "compass_yaw_rad", "level_field"]

HEADING_SOURCES = ("true", "ins", "magnetic")


@dataclass(frozen=True)
class AttitudeErrorConfig:
    """The ``[attitude]`` table of a scenario (1-sigma values; 0 switches a term off)."""

    heading_source: str = "true"
    heading_bias_deg: float = 0.0
    heading_drift_deg: float = 0.0
    heading_drift_tau_s: float = 3600.0
    tilt_bias_deg: float = 0.0
    tilt_from_ins: bool = False

    def __post_init__(self) -> None:
        if self.heading_source not in HEADING_SOURCES:
            raise ValueError(f"heading_source must be one of {', '.join(HEADING_SOURCES)}, "
                             f"not {self.heading_source!r}")
        if self.heading_drift_tau_s <= 0.0:
            raise ValueError("heading_drift_tau_s must be > 0")

    @property
    def ins_share(self) -> int:
        """How much of this attitude is the INS's, as a navigator set up for this installation
        declares it (``FUS_ATT_INS``): 2 tilt and heading, 1 tilt, 0 none (a heading alone from
        the INS is not a setting: 0)."""
        if not self.tilt_from_ins:
            return 0
        return 2 if self.heading_source == "ins" else 1

    @property
    def ideal(self) -> bool:
        """True for the paper's world: a true heading with white noise only."""
        return (self.heading_source == "true" and not self.heading_bias_deg and not self.heading_drift_deg
                and not self.tilt_bias_deg and not self.tilt_from_ins)


class AttitudeErrors:
    """One run's slow attitude errors (biases, heading drift); the caller adds the white noise.

    Draw order from ``rng``: heading bias, roll and pitch bias, the drift's initial value,
    then one normal per :meth:`advance` step; terms with a zero sigma draw nothing.
    """

    def __init__(self, config: AttitudeErrorConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        rad = math.radians
        self.heading_bias_rad = rng.normal(0.0, rad(config.heading_bias_deg)) if config.heading_bias_deg else 0.0
        self.tilt_bias_rad = (tuple(rng.normal(0.0, rad(config.tilt_bias_deg), 2)) if config.tilt_bias_deg
                              else (0.0, 0.0))
        self._drift_sigma = rad(config.heading_drift_deg)
        self.drift_rad = rng.normal(0.0, self._drift_sigma) if self._drift_sigma else 0.0
        self._time_s = 0.0

    def advance(self, time_s: float) -> float:
        """Move the Gauss-Markov heading drift to ``time_s`` (exact discretisation); returns it."""
        dt = time_s - self._time_s
        if dt > 0.0 and self._drift_sigma:
            decay = math.exp(-dt / self.config.heading_drift_tau_s)
            self.drift_rad = (self.drift_rad * decay
                              + self._drift_sigma * math.sqrt(1.0 - decay * decay) * self._rng.normal())
        if dt > 0.0:
            self._time_s = time_s
        return self.drift_rad

    def slow_errors_rad(self, time_s: float, yaw_rad: float, ins_error=None) -> tuple[float, float, float]:
        """(roll, pitch, yaw) errors at ``time_s`` without white noise; the yaw term is only
        meaningful for the ``true`` and ``ins`` sources. ``ins_error`` is the INS error model
        (``sitl.world.ins.InsErrorModel``) or None while the flight controller is GPS-aided."""
        c = self.config
        roll, pitch = self.tilt_bias_rad
        yaw = 0.0
        ins = ins_error.attitude_error_rad(yaw_rad) if ins_error is not None else (0.0, 0.0, 0.0)
        if c.tilt_from_ins:
            roll, pitch = roll + ins[0], pitch + ins[1]
        if c.heading_source == "true":
            yaw = self.heading_bias_rad + self.advance(time_s)
        elif c.heading_source == "ins":
            yaw = ins[2]
        return roll, pitch, yaw


def level_field(body_nt, roll_rad, pitch_rad) -> np.ndarray:
    """Body field (..., 3) rotated by roll and pitch only: the field in the heading frame
    (x forward-level, y right-level, z down), as a compass's tilt compensation forms it."""
    b = np.asarray(body_nt, float)
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    hx = cp * bx + sp * sr * by + sp * cr * bz
    hy = cr * by - sr * bz
    hz = -sp * bx + cp * sr * by + cp * cr * bz
    return np.stack([hx, hy, hz], axis=-1)


def compass_yaw_rad(body_nt, roll_rad, pitch_rad, table_decl_deg):
    """The yaw a compass-aided EKF reports: the one that puts the tilt-compensated body field
    at the table's declination, ``D_table - atan2(h_y, h_x)`` (radians, unwrapped)."""
    h = level_field(body_nt, roll_rad, pitch_rad)
    return np.radians(table_decl_deg) - np.arctan2(h[..., 1], h[..., 0])

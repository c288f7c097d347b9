"""Magnetometer errors left after calibration: hard- and soft-iron residuals, temperature drift.

A calibrated magnetometer still reads ``m = (I + S) b + o + c (T(t) - T_cal)`` where ``b`` is the
true body-frame field, ``S`` a symmetric soft-iron residual (scale and non-orthogonality
errors the ellipsoid fit left), ``o`` a hard-iron residual (offset) and ``c`` a temperature
coefficient per axis times the temperature change since calibration. Each run draws its own:
``o ~ N(0, hard_iron_nt^2)`` per axis, the 6 distinct elements of ``S ~ N(0, soft_iron^2)``,
``c ~ N(0, temp_coeff_nt_per_k^2)`` per axis; the temperature follows a diurnal sinusoid of
amplitude ``temp_swing_k`` starting at the calibration temperature. White noise and
resolution are the sensor's (:class:`sitl.scenario.SensorModel`), added by the caller.

Sizes used by the realistic presets, and why: an AK8963 has 0.15 uT (150 nT) resolution; a
field calibration (ArduPilot's, or an ellipsoid fit) typically leaves offsets of one to two
LSB and scale/cross-axis errors of about half a percent, so the presets use 150 nT per axis
and 0.5 %; a 10 nT/K offset coefficient over a 5 K day adds up to 50 nT. These are stated
assumptions of a well-installed consumer magnetometer, not measurements of one part.

>>> errs = MagErrors.draw(MagErrorConfig(hard_iron_nt=150.0), np.random.default_rng(0))
>>> errs.apply(np.zeros(3), 0.0).round(1).tolist() == errs.hard_iron_nt.round(1).tolist()
True
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MagErrorConfig", "MagErrors", "DAY_S"]

DAY_S = 86400.0


@dataclass(frozen=True)
class MagErrorConfig:
    """1-sigma sizes of the per-run draws (0: that error is absent)."""

    hard_iron_nt: float = 0.0
    soft_iron: float = 0.0                 # dimensionless, per element of the symmetric residual
    temp_coeff_nt_per_k: float = 0.0
    temp_swing_k: float = 0.0              # amplitude of the diurnal temperature change

    @property
    def active(self) -> bool:
        return bool(self.hard_iron_nt or self.soft_iron or (self.temp_coeff_nt_per_k and self.temp_swing_k))


@dataclass(frozen=True)
class MagErrors:
    """One run's residuals; :meth:`apply` maps true body fields to what the sensor reads (before noise)."""

    hard_iron_nt: np.ndarray
    soft_iron: np.ndarray                  # (3, 3) symmetric
    temp_coeff_nt_per_k: np.ndarray
    temp_swing_k: float = 0.0

    @classmethod
    def draw(cls, config: MagErrorConfig, rng: np.random.Generator) -> MagErrors:
        """Draw hard iron (3), soft iron (6 distinct elements), temperature coefficients (3), in that order."""
        hard = rng.normal(0.0, config.hard_iron_nt, 3) if config.hard_iron_nt else np.zeros(3)
        soft = np.zeros((3, 3))
        if config.soft_iron:
            upper = rng.normal(0.0, config.soft_iron, 6)
            soft[np.triu_indices(3)] = upper
            soft = soft + np.triu(soft, 1).T
        coeff = rng.normal(0.0, config.temp_coeff_nt_per_k, 3) if config.temp_coeff_nt_per_k else np.zeros(3)
        return cls(hard, soft, coeff, config.temp_swing_k)

    @classmethod
    def none(cls) -> MagErrors:
        return cls(np.zeros(3), np.zeros((3, 3)), np.zeros(3), 0.0)

    def temperature_change_k(self, time_s):
        """Temperature minus the calibration temperature: ``swing sin(2 pi t / day)``."""
        return self.temp_swing_k * np.sin(2.0 * math.pi * np.asarray(time_s, float) / DAY_S)

    def apply(self, body_nt, time_s) -> np.ndarray:
        """``(I + S) b + o + c dT(t)`` for body fields (..., 3) at times broadcastable to (...)."""
        b = np.asarray(body_nt, float)
        out = b + b @ self.soft_iron.T + self.hard_iron_nt
        if self.temp_swing_k:
            out = out + np.asarray(self.temperature_change_k(time_s))[..., None] * self.temp_coeff_nt_per_k
        return out

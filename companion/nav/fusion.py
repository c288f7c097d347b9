"""INS / geomagnetic fusion: the paper's 15-state error Kalman filter (eq. 46-58, Table 3).

Selected with ``FUS_MODEL 1``; the default is the error-state filter of
:mod:`companion.nav.navfilter` (INS error dynamics or dead reckoning, element bias states).

State ``dX`` (eq. 47): attitude errors (3), position errors (3: east, north, up), velocity
errors (3), constant gyro drift (3), random gyro drift (3). We keep the paper's order for the
position block at indices 3-4 so ``H_B = [0_2x3 I_2 0_2x10]`` (eq. 51) as printed, and hold
the position error in **metres east/north** rather than the paper's longitude/latitude
radians, so Table 3's numbers read as km^2 (``FusionSettings.*_m2``).

Measurement (eq. 50): ``dZ = Z_m - Z_c``, INS position minus geomagnetic position, in local
metres. Prediction with ``F = I_15`` (eq. 52-53), gain and update (eq. 54-56) by filterpy.

Feedback (selectable, ``FUS_FEEDBACK``):

* ``CORRECTED_INS`` (default): the fused position is the INS position minus the estimated INS
  error, ``Z_m - dX_pos``. This is the standard error-state feedback: the estimate keeps the
  INS's smoothness and the geomagnetic fix's absolute reference.
* ``PAPER`` (eq. 58 as printed): ``Z_c(k+1) = Z_c(k) + dX_pos``. Adding the estimated INS
  error to the geomagnetic fix moves it *towards* the INS solution by the INS's own error;
  kept for comparison.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from companion.nav.filter_settings import BiasSpec
from companion.registry import settings

__all__ = ["FusionFeedback", "FusionSettings", "FusionResult", "InsGeomagFusion", "H_B", "ModelError"]

H_B = np.hstack([np.zeros((2, 3)), np.eye(2), np.zeros((2, 10))])  # eq. 51


class FusionFeedback:
    """Values of FUS_FEEDBACK."""

    CORRECTED_INS = 0
    PAPER = 1


@settings("fusion")
class FusionSettings:
    """Table 3 in SI: position-error variances in m^2 (``FUS_QC_KM2``, ``FUS_RC_KM2``,
    ``FUS_P0_KM2``) and the feedback (``FUS_FEEDBACK``, :class:`FusionFeedback`)."""

    qc_m2: float
    rc_m2: float
    p0_m2: float
    feedback: int


@settings("model_error")
class ModelError:
    """The field model's element error as a Gauss-Markov field in distance: 1-sigma
    ``sigma_deg`` (D, I) and ``sigma_nt`` (F, H, Z) at a point, correlation length ``length_m``
    (``NAV_MERR_DEG``, ``NAV_MERR_NT``, ``NAV_MERR_KM``: Table 3's uncertainty)."""

    sigma_deg: float
    sigma_nt: float
    length_m: float

    def variance(self, names: tuple[str, ...], distance_m: float | None) -> np.ndarray:
        """Variance of each element's model error at ``distance_m`` from a calibration point,
        after the calibration's value there is removed; ``None``: not calibrated."""
        point = BiasSpec.per_element(names, self.sigma_deg, self.sigma_nt) ** 2
        if distance_m is None:
            return point
        return 2.0 * point * (1.0 - math.exp(-max(distance_m, 0.0) / self.length_m))


@dataclass(frozen=True)
class FusionResult:
    """Fused position offset (east, north metres from the caller's reference) and its 1-sigma."""

    east_m: float
    north_m: float
    sigma_m: float
    innovation_m: tuple[float, float]


class InsGeomagFusion:
    """The error-state filter. Positions are local (east, north) metres in a frame the caller
    keeps fixed between calls (the mission uses its start point)."""

    def __init__(self, settings: FusionSettings) -> None:
        self.settings = settings
        kf = KalmanFilter(dim_x=15, dim_z=2)
        kf.F = np.eye(15)                                    # Table 3: F = I_15
        kf.H = H_B.copy()
        kf.Q = np.diag([0, 0, 0, settings.qc_m2, settings.qc_m2] + [0] * 10).astype(float)
        kf.R = np.eye(2) * settings.rc_m2
        kf.P = np.diag([0, 0, 0, settings.p0_m2, settings.p0_m2] + [0] * 10).astype(float)
        kf.x = np.zeros((15, 1))
        self.kf = kf

    @property
    def error_estimate_m(self) -> np.ndarray:
        """Estimated INS position error (east, north) in metres."""
        return self.kf.x[3:5, 0].copy()

    @property
    def sigma_m(self) -> float:
        """1-sigma horizontal position uncertainty (RMS of the two axes) in metres."""
        return float(np.sqrt(0.5 * (self.kf.P[3, 3] + self.kf.P[4, 4])))

    def step(self, ins_en_m: np.ndarray, geomag_en_m: np.ndarray) -> FusionResult:
        """One predict + update with ``dZ = Z_m - Z_c`` (eq. 50, 52-56); returns the fused position."""
        ins = np.asarray(ins_en_m, dtype=float)
        fix = np.asarray(geomag_en_m, dtype=float)
        dz = ins - fix
        self.kf.predict()
        self.kf.update(dz.reshape(2, 1))
        correction = self.error_estimate_m
        if self.settings.feedback == FusionFeedback.PAPER:
            fused = fix + correction                         # eq. 58 as printed
        else:
            fused = ins - correction
        return FusionResult(float(fused[0]), float(fused[1]), self.sigma_m, (float(dz[0]), float(dz[1])))

    def predict_only(self, ins_en_m: np.ndarray) -> FusionResult:
        """No geomagnetic fix this step: propagate, and correct the INS with the last estimate."""
        self.kf.predict()
        fused = np.asarray(ins_en_m, dtype=float) - self.error_estimate_m
        return FusionResult(float(fused[0]), float(fused[1]), self.sigma_m, (0.0, 0.0))

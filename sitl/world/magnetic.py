"""The true magnetic field the simulated vehicle flies through: WMM plus a storm disturbance.

The Monte Carlo and the MAVLink simulator both read the field here, so a storm changes
what either sees in the same way.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from companion.nav.field import WorldMagneticModel

__all__ = ["Disturbance", "TruthField", "decl_incl_from_ned"]


class Disturbance(Protocol):
    """A time-varying field disturbance in north/east/down nT (``sitl.storms.StormDisturbance``)."""

    def disturbance_ned_nt(self, lat_deg, lon_deg, time_s): ...


def decl_incl_from_ned(north_nt, east_nt, down_nt) -> tuple[np.ndarray, np.ndarray]:
    """Declination and inclination in degrees of a NED field vector (eq. 2, signs per ``companion``)."""
    horizontal = np.hypot(north_nt, east_nt)
    return np.degrees(np.arctan2(east_nt, north_nt)), np.degrees(np.arctan2(down_nt, horizontal))


@dataclass(frozen=True)
class TruthField:
    """WMM at ``year`` plus an optional disturbance evaluated at ``storm_time_s(elapsed_s)``.

    ``storm_time_s`` maps mission elapsed seconds onto the disturbance's own time axis
    (POSIX UTC seconds); ``storm_scale`` multiplies the disturbance.
    """

    model: WorldMagneticModel
    year: float
    disturbance: Disturbance | None = None
    storm_time_s: object = None  # callable elapsed_s -> POSIX seconds, or None
    storm_scale: float = 1.0

    def field_ned_nt(self, lat_deg, lon_deg, alt_m, elapsed_s) -> np.ndarray:
        """True field (..., 3) north/east/down in nT."""
        wmm = self.model.elements(lat_deg, lon_deg, alt_m, self.year)
        ned = np.stack(np.broadcast_arrays(wmm.x_nt, wmm.y_nt, wmm.z_nt), axis=-1).astype(float)
        if self.disturbance is not None and self.storm_scale != 0.0:
            t = self.storm_time_s(elapsed_s) if self.storm_time_s is not None else elapsed_s
            dn, de, dd = self.disturbance.disturbance_ned_nt(lat_deg, lon_deg, t)
            ned = ned + self.storm_scale * np.stack(np.broadcast_arrays(dn, de, dd), axis=-1)
        return ned

    def decl_incl_deg(self, lat_deg, lon_deg, alt_m, elapsed_s) -> tuple[np.ndarray, np.ndarray]:
        """True (D, I) in degrees."""
        ned = self.field_ned_nt(lat_deg, lon_deg, alt_m, elapsed_s)
        return decl_incl_from_ned(ned[..., 0], ned[..., 1], ned[..., 2])

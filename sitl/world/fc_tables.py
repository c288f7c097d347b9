"""A flight controller's own field tables as the truth's main field: the world ArduPilot SITL flies in.

ArduPilot SITL makes its simulated compass from ``AP_Declination``: declination, inclination and
intensity tabulated on a 10-degree grid of latitude and longitude (generated from IGRF), each
interpolated bilinearly between the four corners of its cell, and the earth-frame field built from
the three. Its EKF takes its declination from the same table. pymavlink carries a copy of these
tables and the same interpolation (``pymavlink.mavextra.get_mag_field_ef``); that copy reproduces the
intensity measured on the ArduPilot SITL binary in ``../shared/ardupilot`` at three points of the
Pacific route to the nanotesla (ArduPilot minus WMM2020: +114, +79, +193 nT at 33N 152E, 30.5N 155E,
28N 158E; the table copy: +114, +79, +193 nT), and its declination explains the 0.12-0.14 deg by which
a heading from the raw magnetometer plus WMM's D missed the true heading there.

:class:`FlightControllerTables` has the :class:`~companion.nav.field.WorldMagneticModel` interface
the truth field uses (``elements(lat, lon, alt, year)``, arrays or scalars; altitude and date are
ignored, as the tables are). It is the *truth* side only: the navigator keeps WMM. A scenario asks
for it with ``[field] main = "ardupilot"`` (``sitl/scenarios/pacific_ardupilot.toml``).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from companion.nav.wmm import FieldElements

__all__ = ["FlightControllerTables", "ardupilot_tables"]

GAUSS_TO_NT = 1e5


class FlightControllerTables:
    """Declination, inclination (deg) and intensity (gauss) tables on a regular grid from
    (``min_lat``, ``min_lon``) in steps of ``resolution_deg``, interpolated bilinearly per element."""

    def __init__(self, name: str, declination: np.ndarray, inclination: np.ndarray, intensity_gauss: np.ndarray,
                 resolution_deg: float = 10.0, min_lat: float = -90.0, min_lon: float = -180.0) -> None:
        self.name = name
        self.tables = tuple(np.asarray(t, dtype=float) for t in (declination, inclination, intensity_gauss))
        if not all(t.shape == self.tables[0].shape and t.ndim == 2 for t in self.tables):
            raise ValueError("the three tables must be 2-D arrays of one shape")
        self.resolution_deg, self.min_lat, self.min_lon = float(resolution_deg), float(min_lat), float(min_lon)

    def _interpolate(self, table: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        rows, cols = table.shape
        u = (lat - self.min_lat) / self.resolution_deg
        v = (lon - self.min_lon) / self.resolution_deg
        i = np.clip(np.floor(u).astype(int), 0, rows - 2)
        j = np.clip(np.floor(v).astype(int), 0, cols - 2)
        a, b = v - j, u - i                    # across longitude, then latitude (AP_Declination's order)
        south = table[i, j] + a * (table[i, j + 1] - table[i, j])
        north = table[i + 1, j] + a * (table[i + 1, j + 1] - table[i + 1, j])
        return south + b * (north - south)

    def elements(self, lat_deg, lon_deg, alt_m=0.0, year=None) -> FieldElements:  # noqa: ARG002 (tables have neither)
        """The interpolated field at the points (the same shapes as the inputs)."""
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float))
        decl, incl, intensity = (self._interpolate(t, lat, lon) for t in self.tables)
        f = intensity * GAUSS_TO_NT
        h = f * np.cos(np.radians(incl))
        values = (h * np.cos(np.radians(decl)), h * np.sin(np.radians(decl)), f * np.sin(np.radians(incl)), h, f,
                  decl, incl)
        if np.ndim(lat_deg) == 0 and np.ndim(lon_deg) == 0:
            values = tuple(float(v) for v in values)
        return FieldElements(*values)

    def ned(self, lat_deg, lon_deg, alt_m=0.0, year=None):
        """(X, Y, Z) in nT: :meth:`elements`' first three (the truth field's interface)."""
        e = self.elements(lat_deg, lon_deg, alt_m, year)
        return e.x_nt, e.y_nt, e.z_nt


@lru_cache(maxsize=1)
def ardupilot_tables() -> FlightControllerTables:
    """ArduPilot's ``AP_Declination`` tables, from pymavlink's copy."""
    from pymavlink import mavextra

    return FlightControllerTables("ArduPilot AP_Declination tables", mavextra.declination_table,
                                  mavextra.inclination_table, mavextra.intensity_table, mavextra.SAMPLING_RES,
                                  mavextra.SAMPLING_MIN_LAT, mavextra.SAMPLING_MIN_LON)

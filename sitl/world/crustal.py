"""A seeded crustal (lithospheric) anomaly field: what no main-field model contains.

Model: a stationary, isotropic Gaussian random potential field on a local tangent plane,
drawn as a sum of ``waves`` plane waves (random Fourier features). For wave j with horizontal
wavenumber k_j (rad/m, east/north), phase phi_j and amplitude c = sigma sqrt(2 / waves)::

    theta_j = k_j . r + phi_j
    B_down  = -sum_j c cos(theta_j) exp(-|k_j| h)
    B_north =  sum_j c (k_north / |k|) sin(theta_j) exp(-|k_j| h)
    B_east  =  sum_j c (k_east / |k|) sin(theta_j) exp(-|k_j| h)

which is ``-grad V`` of the harmonic potential ``V = sum_j (c / |k_j|) cos(theta_j) e^{-|k_j| h}``
above the sources (``h`` the height above sea level, the upward continuation): the three
components are one consistent, curl-free field, the vertical component has variance sigma^2
and the two horizontal components together sigma^2 (each sigma^2 / 2 on average).

Spectrum: k_j ~ N(0, (2 / L^2) I_2), so the covariance of B_down at sea level is
``sigma^2 exp(-r^2 / L^2)`` (``L`` = ``correlation_length_m``: the lag at which the correlation
falls to 1/e), and the radial power spectrum peaks at the wavelength ``pi sqrt(2) L`` = 4.44 L.

Values for the open ocean (defaults of :class:`CrustalConfig`): sigma = 100 nT and L = 22.5 km.
Sources: marine magnetic anomalies have "an amplitude of a few tens to a few hundreds nT and a
wavelength of about 100 km" (Encyclopedia of Geomagnetism and Paleomagnetism, Springer 2007,
"Magnetic anomalies, marine"); the oceanic-crust power spectrum from Project Magnet survey
lines peaks near 100 km wavelength (O'Brien, Parker & Constable, JGR 104, 1999; revised by
Korte, Constable & Parker, JGR 107, 2002, doi:10.1029/2001JB001389), hence L = 100 km / 4.44;
the WMM2020 error model, dominated by the crustal field, gives global rms uncertainties of
131/94/157 nT in X/Y/Z (Chulliat et al., NOAA 2020), oceans being quieter than continents.
These are order-of-magnitude values for an unmapped ocean, not a map of the route; a Gaussian
covariance is a simplification of the measured spectra.

Geometry: east/north metres from ``origin`` by the local metres-per-degree at the origin
(equirectangular); over a few hundred kilometres the distortion is a few percent of the
lags, immaterial for a statistically homogeneous field. Pure: drawn once from a generator.

>>> field = CrustalField.draw(CrustalConfig(enabled=True), np.random.default_rng(1), 30.0, 155.0)
>>> field.ned_nt(30.0, 155.0, 0.0).shape
(3,)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.geo import metres_per_degree

__all__ = ["CrustalConfig", "CrustalField"]


@dataclass(frozen=True)
class CrustalConfig:
    """The anomaly field's statistics (see the module docstring for the sources)."""

    enabled: bool = False
    rms_down_nt: float = 100.0            # rms of the vertical component at sea level
    correlation_length_m: float = 22500.0  # covariance sigma^2 exp(-r^2 / L^2)
    waves: int = 400                      # plane waves in the draw (more: closer to Gaussian)

    def __post_init__(self) -> None:
        if self.rms_down_nt < 0.0 or self.correlation_length_m <= 0.0 or self.waves < 1:
            raise ValueError("crustal field needs rms_down_nt >= 0, correlation_length_m > 0, waves >= 1")


class CrustalField:
    """One realisation of the anomaly field; ``ned_nt`` evaluates it (broadcast arrays)."""

    def __init__(self, config: CrustalConfig, wavenumbers: np.ndarray, phases: np.ndarray,
                 origin_lat_deg: float, origin_lon_deg: float) -> None:
        self.config = config
        self.k_en = np.asarray(wavenumbers, dtype=float)          # (waves, 2) east, north rad/m
        self.k_abs = np.hypot(self.k_en[:, 0], self.k_en[:, 1])
        self.unit = self.k_en / np.maximum(self.k_abs, 1e-15)[:, None]
        self.phases = np.asarray(phases, dtype=float)
        self.amplitude_nt = config.rms_down_nt * math.sqrt(2.0 / len(self.phases))
        self.origin = (float(origin_lat_deg), float(origin_lon_deg))
        east, north = metres_per_degree(origin_lat_deg)
        self._m_per_deg = (float(east), float(north))

    @classmethod
    def draw(cls, config: CrustalConfig, rng: np.random.Generator, origin_lat_deg: float,
             origin_lon_deg: float) -> CrustalField:
        """A realisation with wavenumbers ~ N(0, 2 / L^2) per axis and uniform phases."""
        k = rng.normal(0.0, math.sqrt(2.0) / config.correlation_length_m, (config.waves, 2))
        phases = rng.uniform(0.0, 2.0 * math.pi, config.waves)
        return cls(config, k, phases, origin_lat_deg, origin_lon_deg)

    def ned_nt(self, lat_deg, lon_deg, alt_m=0.0) -> np.ndarray:
        """Anomaly (..., 3) north/east/down in nT at the points (upward-continued to ``alt_m``)."""
        lat, lon, alt = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                            np.asarray(alt_m, float))
        east = ((lon - self.origin[1] + 180.0) % 360.0 - 180.0) * self._m_per_deg[0]
        north = (lat - self.origin[0]) * self._m_per_deg[1]
        theta = east[..., None] * self.k_en[:, 0] + north[..., None] * self.k_en[:, 1] + self.phases
        decay = self.amplitude_nt * np.exp(-self.k_abs * np.maximum(alt, 0.0)[..., None])
        sin = np.sin(theta) * decay
        return np.stack([sin @ self.unit[:, 1], sin @ self.unit[:, 0], -(np.cos(theta) * decay).sum(-1)], axis=-1)

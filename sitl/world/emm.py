"""The real crust along a route: EMM2017 degrees 16-790, synthesised once on a regional grid.

The Enhanced Magnetic Model 2017 (NOAA NCEI, Chulliat et al. 2017; ``crust/EMM2017.COF`` in the
real data folder: columns ``n m g h`` in nT, Schmidt semi-normalised, epoch 2017.0, degrees
1-790) holds the main field to degree 15 and the lithospheric (crustal) field from degree 16
to 790, wavelengths down to ``2 pi R / 790`` = 51 km. The truth of the realistic worlds is
IGRF-14 (:mod:`sitl.world.igrf`) plus this crust; the crust is static (no secular variation).

Synthesis (:func:`synthesise_crust_grid`): pyshtools (``SHMagCoeffs.expand``, the field's
standard library for spherical-harmonic synthesis) computes ``B_r`` (up), ``B_theta`` (south)
and ``B_phi`` (east) on a global Driscoll-Healy grid at ``lmax`` = the model's top degree,
on the WGS84 ellipsoid raised by the route's altitude (``a + h``, ``b + h``: the field at the
height of every node, not on one sphere). The grid's latitudes are geocentric; each node is
given its geodetic latitude (the normal of that ellipsoid) and its vector is rotated from
geocentric (X' = -B_theta, Z' = -B_r) into geodetic north/east/down by ``psi = phi' - phi``,
exactly as the main-field sums of :mod:`companion.nav.harmonics` and so IGRF-14 do: the two
parts of the truth are in one frame. The route's box (with a margin) is kept; between nodes
(0.114 deg apart at degree 790, about 12.6 km, a quarter of the shortest wavelength) a bicubic
interpolating spline per component (scipy ``RectBivariateSpline``) gives the field.

Cache (:func:`crust_grid_for_route`): the box is saved as ``.npz`` in :func:`cache_dir`
(``$FCMPC_CACHE_DIR``, else ``$XDG_CACHE_HOME/fcmpc``, else ``~/.cache/fcmpc``) under a name
keyed by the coefficient file's SHA-256, the degree range, the box and the altitude: the first
run on a route synthesises (a few tens of seconds at degree 790), every later one loads.
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["CRUST_MAX_DEGREE", "CRUST_MIN_DEGREE", "EMM_FILE", "CrustGrid", "OutsideGridError", "cache_dir", "crust_grid_for_route",
           "read_emm", "synthesise_crust_grid"]

EMM_FILE = Path("crust") / "EMM2017.COF"
"""The coefficient file, relative to the real data folder (:func:`sitl.storms.default_data_dir`)."""
CRUST_MIN_DEGREE = 16   # EMM2017's crust begins where its core field ends (degree 15)
CRUST_MAX_DEGREE = 790  # its last degree: 51 km wavelength
ROUTE_MARGIN_DEG = 10.0  # the box around start and destination (1100 km): room for a lost vehicle's wander
ALT_TOLERANCE_M = 100.0  # evaluation this far from the grid's altitude is refused (upward continuation)

_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_REFERENCE_RADIUS_M = 6371200.0


def read_emm(path: str | os.PathLike[str]) -> tuple[float, np.ndarray]:
    """(epoch, coefficients[2, L + 1, L + 1]) of an EMM ``.COF`` file: g in [0], h in [1], nT.

    >>> epoch, gh = read_emm(default_emm_file())   # doctest: +SKIP
    >>> epoch, gh.shape                            # doctest: +SKIP
    (2017.0, (2, 791, 791))
    """
    path = Path(path)
    try:
        with open(path, encoding="ascii") as handle:
            header = handle.readline().split()
            values = np.array(handle.read().split(), dtype=float)
        epoch = float(header[0])
        rows = values.reshape(-1, 4)
    except (OSError, ValueError, IndexError) as err:
        raise ValueError(f"{path}: not an EMM coefficient file (header 'epoch name date', rows 'n m g h'): "
                         f"{err}") from err
    if rows.shape[0] == 0:
        raise ValueError(f"{path}: no coefficient rows 'n m g h'")
    n, m = rows[:, 0].astype(int), rows[:, 1].astype(int)
    if (n < 1).any() or (m < 0).any() or (m > n).any():
        raise ValueError(f"{path}: degrees and orders outside 0 <= m <= n, n >= 1")
    top = int(n.max())
    gh = np.zeros((2, top + 1, top + 1))
    gh[0, n, m], gh[1, n, m] = rows[:, 2], rows[:, 3]
    return epoch, gh


def default_emm_file() -> Path:
    """EMM2017.COF in the real data folder (``$FCMPC_DATA_DIR`` or ``../shared/data``)."""
    from sitl.storms import default_data_dir
    return default_data_dir() / EMM_FILE


def cache_dir() -> Path:
    """Where synthesised grids are kept: ``$FCMPC_CACHE_DIR``, ``$XDG_CACHE_HOME/fcmpc`` or ``~/.cache/fcmpc``."""
    env = os.environ.get("FCMPC_CACHE_DIR")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fcmpc"


class OutsideGridError(ValueError):
    """A point outside the route's crust grid: a vehicle that left the simulated world."""


class CrustGrid:
    """The crust's north/east/down field (nT) on a geodetic grid at one altitude; :meth:`ned_nt`
    interpolates it bicubically. ``lat_deg`` (ascending, geodetic) and ``lon_deg`` (ascending,
    unwrapped: may pass 180 or 360) are the axes, ``ned_nt`` the (lat, lon, 3) values."""

    def __init__(self, lat_deg: np.ndarray, lon_deg: np.ndarray, ned_nt: np.ndarray, alt_m: float,
                 label: str = "") -> None:
        self.lat_deg = np.asarray(lat_deg, dtype=float)
        self.lon_deg = np.asarray(lon_deg, dtype=float)
        self.values = np.asarray(ned_nt, dtype=float)
        self.alt_m = float(alt_m)
        self.label = label
        if self.values.shape != (self.lat_deg.size, self.lon_deg.size, 3):
            raise ValueError(f"crust grid of shape {self.values.shape} for axes {self.lat_deg.size} x {self.lon_deg.size}")
        self._splines = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_splines"] = None   # rebuilt where it is used (the Monte Carlo's workers)
        return state

    def _spline_set(self):
        if self._splines is None:
            from scipy.interpolate import RectBivariateSpline
            self._splines = tuple(RectBivariateSpline(self.lat_deg, self.lon_deg, self.values[..., i], kx=3, ky=3)
                                  for i in range(3))
        return self._splines

    def covers(self, lat_deg, lon_deg) -> bool:
        """Whether every point lies inside the grid."""
        lat = np.asarray(lat_deg, dtype=float)
        lon = self._unwrap(np.asarray(lon_deg, dtype=float))
        return bool(np.all((lat >= self.lat_deg[0]) & (lat <= self.lat_deg[-1])
                           & (lon >= self.lon_deg[0]) & (lon <= self.lon_deg[-1])))

    def _unwrap(self, lon: np.ndarray) -> np.ndarray:
        return self.lon_deg[0] + (lon - self.lon_deg[0]) % 360.0

    def ned_nt(self, lat_deg, lon_deg, alt_m=0.0) -> np.ndarray:
        """The crust (..., 3) north/east/down in nT at geodetic points (broadcast). Raises
        :class:`OutsideGridError` outside the grid, ValueError more than ``ALT_TOLERANCE_M`` from its altitude."""
        lat, lon, alt = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                            np.asarray(alt_m, float))
        if np.any(np.abs(alt - self.alt_m) > ALT_TOLERANCE_M):
            raise ValueError(f"crust grid {self.label} is at {self.alt_m:.0f} m; asked at "
                             f"{float(np.max(np.abs(alt - self.alt_m))) + self.alt_m:.0f} m")
        if not self.covers(lat, lon):
            raise OutsideGridError(f"a point leaves the crust grid {self.label} (lat {self.lat_deg[0]:.2f}.."
                             f"{self.lat_deg[-1]:.2f}, lon {self.lon_deg[0]:.2f}..{self.lon_deg[-1]:.2f} deg)")
        flat_lat, flat_lon = lat.ravel(), self._unwrap(lon.ravel())
        out = np.stack([spline.ev(flat_lat, flat_lon) for spline in self._spline_set()], axis=-1)
        return out.reshape(lat.shape + (3,))


def _coefficients(gh: np.ndarray, min_degree: int, max_degree: int):
    """pyshtools' SHMagCoeffs of ``gh`` kept between the two degrees (inclusive)."""
    import pyshtools
    if not 1 <= min_degree <= max_degree < gh.shape[1]:
        raise ValueError(f"degree range {min_degree}-{max_degree} outside the model's 1-{gh.shape[1] - 1}")
    kept = np.array(gh[:, : max_degree + 1, : max_degree + 1])
    kept[:, :min_degree, :] = 0.0
    return pyshtools.SHMagCoeffs.from_array(kept, r0=_REFERENCE_RADIUS_M, normalization="schmidt", csphase=1,
                                            units="nT", copy=False)


def synthesise_crust_grid(gh: np.ndarray, min_degree: int, max_degree: int, lat_range_deg: tuple[float, float],
                          lon_range_deg: tuple[float, float], alt_m: float = 0.0, label: str = "") -> CrustGrid:
    """The field of ``gh``'s degrees ``min_degree``..``max_degree`` on the geodetic box (the
    module docstring): a global pyshtools grid at the box's altitude, cut to the box.
    ``lon_range_deg`` may pass 180 or 360 (e.g. (350, 370))."""
    coeffs = _coefficients(gh, min_degree, max_degree)
    a, b = _WGS84_A_M + alt_m, _WGS84_A_M * (1.0 - _WGS84_F) + alt_m
    grids = coeffs.expand(a=a, f=1.0 - b / a, lmax=max_degree, extend=False)
    lat_c = grids.rad.lats()                  # geocentric, 90 .. -90 + step, descending
    lon_all = grids.rad.lons()                # 0 .. 360 - step
    # geodetic latitude of each node: the normal of the ellipsoid (a, b) at geocentric lat_c
    lat_g = np.degrees(np.arctan(np.tan(np.radians(lat_c)) * (a / b) ** 2))
    rows = np.flatnonzero((lat_g >= lat_range_deg[0]) & (lat_g <= lat_range_deg[1]))
    rows = np.arange(max(rows.min() - 2, 0), min(rows.max() + 3, lat_c.size))[::-1]   # ascending, 2 spare
    step = lon_all[1] - lon_all[0]
    first = math.floor(lon_range_deg[0] / step) - 2
    count = math.ceil(lon_range_deg[1] / step) + 3 - first
    cols = np.arange(first, first + count) % lon_all.size
    lon = (first + np.arange(count)) * step
    psi = np.radians(lat_c[rows] - lat_g[rows])[:, None]
    x_c = -grids.theta.data[np.ix_(rows, cols)]   # geocentric north = -B_theta
    z_c = -grids.rad.data[np.ix_(rows, cols)]     # down = -B_r
    east = grids.phi.data[np.ix_(rows, cols)]
    ned = np.stack([x_c * np.cos(psi) - z_c * np.sin(psi), east, x_c * np.sin(psi) + z_c * np.cos(psi)], axis=-1)
    return CrustGrid(lat_g[rows], lon, ned, alt_m, label)


def route_box(start: tuple[float, float], destination: tuple[float, float],
              margin_deg: float = ROUTE_MARGIN_DEG) -> tuple[tuple[float, float], tuple[float, float]]:
    """((lat_min, lat_max), (lon_min, lon_max)) around a route, whole tenths of a degree; the
    longitudes unwrapped along the shorter way (lon_max - lon_min < 360)."""
    lon0 = start[1]
    lon1 = lon0 + (destination[1] - lon0 + 180.0) % 360.0 - 180.0
    lat = (max(-89.0, math.floor((min(start[0], destination[0]) - margin_deg) * 10) / 10),
           min(89.0, math.ceil((max(start[0], destination[0]) + margin_deg) * 10) / 10))
    west = math.floor((min(lon0, lon1) - margin_deg) * 10) / 10
    east = math.ceil((max(lon0, lon1) + margin_deg) * 10) / 10
    shift = math.floor(west / 360.0) * 360.0
    return lat, (west - shift, east - shift)


@lru_cache(maxsize=1)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def crust_grid_for_route(start: tuple[float, float], destination: tuple[float, float], alt_m: float = 0.0,
                         path: str | os.PathLike[str] | None = None, min_degree: int = CRUST_MIN_DEGREE,
                         max_degree: int = CRUST_MAX_DEGREE, margin_deg: float = ROUTE_MARGIN_DEG,
                         cache: str | os.PathLike[str] | None = None) -> CrustGrid:
    """The crust grid of the route ``start`` -> ``destination`` ((lat, lon) degrees): loaded from
    the cache (``cache`` folder, default :func:`cache_dir`) or synthesised and saved there.
    ``path``: the coefficient file (default EMM2017 in the real data folder)."""
    path = Path(path) if path is not None else default_emm_file()
    if not path.exists():
        raise FileNotFoundError(f"crust model {path} not found (set FCMPC_DATA_DIR to the real data folder)")
    stat = path.stat()
    digest = _file_digest(str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    lat_range, lon_range = route_box(start, destination, margin_deg)
    key = (f"crust_{digest[:16]}_n{min_degree}-{max_degree}_lat{lat_range[0]:g}_{lat_range[1]:g}"
           f"_lon{lon_range[0]:g}_{lon_range[1]:g}_h{alt_m:g}")
    label = f"{path.name} n{min_degree}-{max_degree}"
    folder = Path(cache) if cache is not None else cache_dir()
    target = folder / f"{key}.npz"
    if target.exists():
        with np.load(target) as saved:
            return CrustGrid(saved["lat_deg"], saved["lon_deg"], saved["ned_nt"], float(saved["alt_m"]), label)
    logging.getLogger(__name__).info("synthesising %s degrees %d-%d for the route's box (once; cached in %s)",
                                     path.name, min_degree, max_degree, folder)
    _, gh = read_emm(path)
    grid = synthesise_crust_grid(gh, min_degree, max_degree, lat_range, lon_range, alt_m, label)
    folder.mkdir(parents=True, exist_ok=True)
    partial = folder / f".{key}.{os.getpid()}.npz"   # written whole, then renamed: parallel runs never read half
    np.savez(partial, lat_deg=grid.lat_deg, lon_deg=grid.lon_deg, ned_nt=grid.values, alt_m=grid.alt_m)
    os.replace(partial, target)
    return grid

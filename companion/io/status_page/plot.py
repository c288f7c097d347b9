"""The status page's plot: the estimate with its 95 % ellipse, the destination and the track, as SVG.

Drawn on the server as a few SVG elements in a local frame (east/north metres from the
mission's start, :func:`companion.nav.geo.enu_offset`), with a kilometre grid: no map tiles,
nothing fetched from anywhere. A string a few kilobytes long, built in well under a millisecond,
so the page's thread holds the interpreter lock for no longer than that beside the companion's
loop (a matplotlib figure of the same takes tens of milliseconds of it).

Colours (the screenshot test looks for them): the estimated track and the estimate
:data:`TRACK_COLOUR`, the 95 % ellipse :data:`ELLIPSE_COLOUR`, the destination
:data:`DEST_COLOUR`, the start :data:`START_COLOUR`, the geomagnetic fixes :data:`FIX_COLOUR`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from html import escape

import numpy as np

from companion.io.status_page.snapshot import StatusSnapshot
from companion.nav.geo import enu_offset

__all__ = ["DEST_COLOUR", "ELLIPSE_CHI2", "ELLIPSE_COLOUR", "FIX_COLOUR", "START_COLOUR", "TRACK_COLOUR", "Ellipse",
           "Track", "ellipse_95", "plot_svg"]

TRACK_COLOUR = "#1f77b4"
ELLIPSE_COLOUR = "#d62728"
DEST_COLOUR = "#2ca02c"
START_COLOUR = "#7f7f7f"
FIX_COLOUR = "#ff7f0e"
ELLIPSE_CHI2 = -2.0 * math.log(1.0 - 0.95)   # chi-square quantile, 2 degrees of freedom: 5.991
SIZE_PX = 400                # the plot square
MARGIN_PX = 44
LEGEND_PX = 58               # the legend strip under it
CLOSE_UP_MIN_M = 500.0       # the close-up shows at least this much around the estimate


@dataclass(frozen=True)
class Track:
    """The steps so far, from the records (``steps.csv``): estimates and geomagnetic fixes, degrees."""

    est_lat_deg: tuple[float, ...] = ()
    est_lon_deg: tuple[float, ...] = ()
    fix_lat_deg: tuple[float, ...] = ()
    fix_lon_deg: tuple[float, ...] = ()


@dataclass(frozen=True)
class Ellipse:
    """Semi-axes (m) and the major axis's direction (radians from east, counter-clockwise)."""

    major_m: float
    minor_m: float
    angle_rad: float


def ellipse_95(cov_en_m2: tuple[float, float, float], sigma_m: float) -> Ellipse | None:
    """The 95 % ellipse of an east/north covariance ``(ee, en, nn)``; a circle of the 1-sigma
    ``sigma_m`` per axis when the covariance is not a finite positive one; None without either.

    >>> e = ellipse_95((400.0 ** 2, 0.0, 100.0 ** 2), float("nan"))
    >>> round(e.major_m), round(e.minor_m), e.angle_rad
    (979, 245, 0.0)
    >>> round(ellipse_95((float("nan"),) * 3, 100.0).major_m)
    245
    """
    ee, en, nn = cov_en_m2
    if all(math.isfinite(v) for v in (ee, en, nn)):
        values, vectors = np.linalg.eigh(np.array([[ee, en], [en, nn]]))
        if values[0] > 0.0:
            major = vectors[:, 1]
            return Ellipse(math.sqrt(ELLIPSE_CHI2 * values[1]), math.sqrt(ELLIPSE_CHI2 * values[0]),
                           math.atan2(major[1], major[0]) % math.pi)
    if math.isfinite(sigma_m) and sigma_m > 0.0:
        radius = math.sqrt(ELLIPSE_CHI2) * sigma_m
        return Ellipse(radius, radius, 0.0)
    return None


def _nice_step(span_m: float) -> float:
    """A grid step of 1, 2 or 5 times a power of ten giving 3 to 8 lines over ``span_m``."""
    raw = max(span_m, 1.0) / 5.0
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw)


def _coords(xs: np.ndarray, ys: np.ndarray, fmt: str) -> str:
    """``fmt`` of each finite (x, y) pair, joined by spaces."""
    keep = np.isfinite(xs) & np.isfinite(ys)
    return " ".join(fmt.format(x, y) for x, y in zip(xs[keep].tolist(), ys[keep].tolist()))


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def plot_svg(snap: StatusSnapshot, track: Track, close_up: bool = False) -> str:
    """The plot as an ``<svg>`` element (inline in the page, or served alone): the whole mission
    (start, destination, track), or with ``close_up`` the estimate's neighbourhood (three times
    its 95 % ellipse, at least CLOSE_UP_MIN_M), where the ellipse is more than a dot."""
    lat0, lon0 = snap.start_lat_deg, snap.start_lon_deg
    if not _finite(lat0, lon0):
        lat0, lon0 = (snap.est_lat_deg, snap.est_lon_deg) if _finite(snap.est_lat_deg, snap.est_lon_deg) \
            else (snap.dest_lat_deg, snap.dest_lon_deg)
    if not _finite(lat0, lon0):
        return _frame('<text x="50%" y="50%" text-anchor="middle">no position yet</text>', "")

    def local(lat, lon) -> tuple[np.ndarray, np.ndarray]:
        east, north = enu_offset(lat0, lon0, np.asarray(lat, dtype=float), np.asarray(lon, dtype=float))
        return np.atleast_1d(east), np.atleast_1d(north)

    track_e, track_n = local(track.est_lat_deg, track.est_lon_deg)
    fix_e, fix_n = local(track.fix_lat_deg, track.fix_lon_deg)
    dest_e, dest_n = local(snap.dest_lat_deg, snap.dest_lon_deg)
    est_e, est_n = local(snap.est_lat_deg, snap.est_lon_deg)
    has_estimate = _finite(est_e[0], est_n[0])
    ellipse = ellipse_95(snap.est_cov_en_m2, snap.est_sigma_m) if has_estimate else None
    reach = ellipse.major_m if ellipse is not None else 0.0
    if close_up:
        if not has_estimate:
            return _frame('<text x="50%" y="50%" text-anchor="middle">no estimate yet</text>', "")
        cx, cy, half = float(est_e[0]), float(est_n[0]), max(3.0 * reach, CLOSE_UP_MIN_M)
    else:
        xs = np.concatenate([[0.0], track_e, fix_e, dest_e, est_e - reach, est_e + reach])
        ys = np.concatenate([[0.0], track_n, fix_n, dest_n, est_n - reach, est_n + reach])
        keep = np.isfinite(xs) & np.isfinite(ys)
        xs, ys = xs[keep], ys[keep]
        half = max(float(np.ptp(xs)), float(np.ptp(ys)), 200.0) * 0.55
        cx, cy = float(xs.min() + xs.max()) / 2.0, float(ys.min() + ys.max()) / 2.0
    scale = (SIZE_PX - 2 * MARGIN_PX) / (2.0 * half)                 # px per metre, the same on both axes

    def px(east, north):   # metres (floats or arrays) -> pixels
        return MARGIN_PX + (east - cx + half) * scale, MARGIN_PX + (cy + half - north) * scale

    parts = []
    points = _coords(*px(track_e, track_n), "{:.1f},{:.1f}")
    if points:
        parts.append(f'<polyline points="{points}" fill="none" stroke="{TRACK_COLOUR}" stroke-width="2.5"/>')
    crosses = _coords(*px(fix_e, fix_n), "M{:.1f},{:.1f}m-4,-4l8,8m0,-8l-8,8")
    if crosses:
        parts.append(f'<path d="{crosses}" stroke="{FIX_COLOUR}" stroke-width="2"/>')
    x, y = px(0.0, 0.0)
    parts.append(f'<rect x="{x - 6:.1f}" y="{y - 6:.1f}" width="12" height="12" fill="{START_COLOUR}"/>')
    if _finite(dest_e[0], dest_n[0]):
        x, y = px(dest_e[0], dest_n[0])
        parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="9" fill="{DEST_COLOUR}"/>')
    if ellipse is not None:
        x, y = px(est_e[0], est_n[0])
        parts.append(f'<ellipse cx="{x:.1f}" cy="{y:.1f}" rx="{max(ellipse.major_m * scale, 1.5):.1f}" '
                     f'ry="{max(ellipse.minor_m * scale, 1.5):.1f}" '
                     f'transform="rotate({-math.degrees(ellipse.angle_rad):.1f} {x:.1f} {y:.1f})" '
                     f'fill="{ELLIPSE_COLOUR}" fill-opacity="0.25" stroke="{ELLIPSE_COLOUR}" stroke-width="2"/>')
    if has_estimate:
        x, y = px(est_e[0], est_n[0])
        parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="6" fill="{TRACK_COLOUR}" stroke="white"/>')
    title = "around the estimate" if close_up else "the mission"
    inside = f'<g clip-path="url(#{"c" if close_up else "m"})">{"".join(parts)}</g>'
    return _frame(_grid(cx, cy, half, px) + inside + f'<text x="{SIZE_PX / 2}" y="14" text-anchor="middle" '
                  f'font-size="13">{title}</text>' + _legend(), "c" if close_up else "m")


def _grid(cx: float, cy: float, half: float, px) -> str:
    step = _nice_step(2.0 * half)
    unit, div = ("km", 1000.0) if step >= 1000.0 else ("m", 1.0)
    out = []
    for value in np.arange(math.ceil((cx - half) / step) * step, cx + half + step * 1e-9, step):
        x, _ = px(value, cy)
        out.append(f'<line x1="{x:.1f}" y1="{MARGIN_PX}" x2="{x:.1f}" y2="{SIZE_PX - MARGIN_PX}" class="g"/>'
                   f'<text x="{x:.1f}" y="{SIZE_PX - MARGIN_PX + 14}" text-anchor="middle">{value / div:g}</text>')
    for value in np.arange(math.ceil((cy - half) / step) * step, cy + half + step * 1e-9, step):
        _, y = px(cx, value)
        out.append(f'<line x1="{MARGIN_PX}" y1="{y:.1f}" x2="{SIZE_PX - MARGIN_PX}" y2="{y:.1f}" class="g"/>'
                   f'<text x="{MARGIN_PX - 4}" y="{y + 4:.1f}" text-anchor="end">{value / div:g}</text>')
    out.append(f'<text x="{SIZE_PX / 2}" y="{SIZE_PX - 10}" text-anchor="middle">'
               f'{escape(unit)} east of the start</text>'
               f'<text x="12" y="{SIZE_PX / 2}" text-anchor="middle" transform="rotate(-90 12 {SIZE_PX / 2})">'
               f'{escape(unit)} north of the start</text>')
    return "".join(out)


def _legend() -> str:
    items = ((TRACK_COLOUR, "estimate and its track"), (ELLIPSE_COLOUR, "95 % ellipse"),
             (FIX_COLOUR, "geomagnetic fixes"), (DEST_COLOUR, "destination"), (START_COLOUR, "start"))
    return "".join(f'<rect x="{10 + 130 * (i % 3)}" y="{SIZE_PX + 8 + 18 * (i // 3)}" width="10" height="10" '
                   f'fill="{colour}"/><text x="{24 + 130 * (i % 3)}" y="{SIZE_PX + 17 + 18 * (i // 3)}">'
                   f'{escape(label)}</text>' for i, (colour, label) in enumerate(items))


def _frame(body: str, clip_id: str) -> str:
    """The ``<svg>`` around ``body``, with a clip path ``clip_id`` for the plot's square."""
    inner = SIZE_PX - 2 * MARGIN_PX
    clip = f'<defs><clipPath id="{clip_id}"><rect x="{MARGIN_PX}" y="{MARGIN_PX}" width="{inner}" ' \
           f'height="{inner}"/></clipPath></defs>' if clip_id else ""
    height = SIZE_PX + LEGEND_PX
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{SIZE_PX}" height="{height}" '
            f'viewBox="0 0 {SIZE_PX} {height}" font-family="sans-serif" font-size="11">'
            f'<style>.g{{stroke:#ddd;stroke-width:1}}</style>{clip}'
            f'<rect width="100%" height="100%" fill="white"/>{body}</svg>')

"""Metrics of Section 4.1 (companion.nav.metrics, eq. 59-63) and the reference path.

Oracles: eq. 59 and eq. 63 evaluated by hand on small arrays, and tracks built with
geographiclib's Direct/Line so that each point's distance from the geodesic, and each step's
length, is known by construction.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from geographiclib.geodesic import Geodesic

from companion.nav.metrics import (
    PMR_TOLERANCE_M,
    cep50,
    cep_paper,
    mean_terminal_location,
    path_deviation_m,
    percentile,
    step_lengths_m,
    track_metrics,
)
from companion.nav.geo import metres_per_degree
from companion.nav.reference import ReferencePath

WGS84 = Geodesic.WGS84
START, DEST = (33.0, 152.0), (28.0, 158.0)
LINE = WGS84.InverseLine(*START, *DEST)


def on_line(s_m: float) -> tuple[float, float, float]:
    """(lat, lon, local azimuth) of the point s_m along the start->destination geodesic."""
    pos = LINE.Position(s_m)
    return pos["lat2"], pos["lon2"], pos["azi2"]


def offset(s_m: float, side_m: float) -> tuple[float, float]:
    """A point side_m metres perpendicular (right of the track for > 0) to the geodesic at s_m."""
    lat, lon, azi = on_line(s_m)
    out = WGS84.Direct(lat, lon, azi + math.copysign(90.0, side_m), abs(side_m))
    return out["lat2"], out["lon2"]


# --- CEP (eq. 59) --------------------------------------------------------------------------------
@pytest.mark.parametrize("miss", [[1.0, 2.0, 3.0, 4.0, 10.0], [4.0, 1.0, 2.5, 3.0], [7.0],
                                  [0.19, 8.92, 35.18, 0.5, 0.7, 2.0, 1.1]])
def test_cep_paper_is_eq_59_with_one_over_all_runs(miss):
    ordered = sorted(miss)
    n = len(ordered)
    median = ordered[n // 2] if n % 2 else 0.5 * (ordered[n // 2 - 1] + ordered[n // 2])
    total = 0.0
    for d in miss:
        if d <= median:          # the indicator I(d_i <= d_50)
            total += d * d
    expected = math.sqrt(total / n)   # 1/N over *all* N runs, as printed
    assert cep_paper(miss) == pytest.approx(expected, rel=1e-14)
    assert cep50(miss) == pytest.approx(median, rel=1e-14)


def test_cep_paper_differs_from_the_rms_of_the_inner_half():
    miss = [1.0, 2.0, 3.0, 4.0]          # median 2.5: inner half {1, 2}
    assert cep_paper(miss) == pytest.approx(math.sqrt((1 + 4) / 4))
    assert cep_paper(miss) != pytest.approx(math.sqrt((1 + 4) / 2))


# --- path deviation (eq. 60-62) --------------------------------------------------------------------
def test_percentile_is_the_nearest_rank():
    """The house's one percentile (every p90 miss, the companion's latency p99), on ten misses by hand.

    Misses 12, 3, 7, 30, 18, 5, 9, 21, 15, 26 km sorted: 3, 5, 7, 9, 12, 15, 18, 21, 26, 30.
    p90: ceil(0.9 x 10) = 9th smallest = 26 (interpolating, as np.percentile does, would give
    26 + 0.1 x (30 - 26) = 26.4); p25: ceil(2.5) = 3rd = 7; p50: ceil(5) = 5th = 12 (the median,
    the mean of the 5th and 6th, is 13.5: percentile is not the median); p100: 30; p1: ceil(0.1) =
    1st = 3. One value is every percentile of itself; no values: NaN.
    """
    miss = [12.0, 3.0, 7.0, 30.0, 18.0, 5.0, 9.0, 21.0, 15.0, 26.0]
    assert [percentile(miss, q) for q in (0.9, 0.25, 0.5, 1.0, 0.01)] == [26.0, 7.0, 12.0, 30.0, 3.0]
    assert percentile(np.array(miss), 0.9) == 26.0 and cep50(miss) == 13.5
    assert percentile([4.2], 0.9) == 4.2 and math.isnan(percentile([], 0.9))


def test_points_on_the_geodesic_have_no_deviation():
    along = np.linspace(0.0, LINE.s13, 37)
    lat, lon = np.array([on_line(s)[0] for s in along]), np.array([on_line(s)[1] for s in along])
    dev = path_deviation_m(lat, lon, START, DEST)
    assert dev.shape == (37,)
    assert np.max(dev) < 0.05  # 250 m chords of an 800 km geodesic: the sagitta is ~1 mm


@pytest.mark.parametrize("side_m", [-20000.0, -1000.0, -300.0, 120.0, 750.0, 5000.0])
def test_perpendicular_offset_is_measured_as_the_deviation(side_m):
    along = [1234.5, 0.3 * LINE.s13, 0.61 * LINE.s13, LINE.s13 - 2000.0]
    points = [offset(s, side_m) for s in along]
    dev = path_deviation_m([p[0] for p in points], [p[1] for p in points], START, DEST)
    np.testing.assert_allclose(dev, abs(side_m), atol=1.0)


def brute_force_deviation_m(lat, lon) -> np.ndarray:
    """The nearest point over every chord of the same 250 m polyline (no window)."""
    count = max(2, int(math.ceil(LINE.s13 / 250.0)) + 1)
    samples = [LINE.Position(s) for s in np.linspace(0.0, LINE.s13, count)]
    a_lat, a_lon = np.radians([p["lat2"] for p in samples]), np.radians([p["lon2"] for p in samples])

    def ecef(la, lo):
        e2 = WGS84.f * (2.0 - WGS84.f)
        n = WGS84.a / np.sqrt(1.0 - e2 * np.sin(la) ** 2)
        return np.stack([n * np.cos(la) * np.cos(lo), n * np.cos(la) * np.sin(lo), n * (1 - e2) * np.sin(la)], -1)

    poly = ecef(a_lat, a_lon)
    a, seg = poly[:-1], np.diff(poly, axis=0)
    out = []
    for p in ecef(np.radians(lat), np.radians(lon)):
        t = np.clip(np.sum((p - a) * seg, axis=1) / np.sum(seg * seg, axis=1), 0.0, 1.0)
        out.append(np.sqrt(np.min(np.sum((a + seg * t[:, None] - p) ** 2, axis=1))))
    return np.array(out)


def test_the_windowed_search_finds_the_same_nearest_point_as_the_full_one():
    """Random points from on the line to 3000 km off it and beyond both ends (diverged runs)."""
    rng = np.random.default_rng(7)
    along = rng.uniform(-0.3, 1.3, 300) * LINE.s13
    sides = rng.choice([-1.0, 1.0], 300) * 10.0 ** rng.uniform(-1.0, 6.5, 300)
    points = [offset(min(max(s, 0.0), LINE.s13), d) for s, d in zip(along, sides)]
    points = [WGS84.Direct(*p, rng.uniform(0, 360), max(0.0, -s, s - LINE.s13)) for p, s in zip(points, along)]
    lat, lon = np.array([p["lat2"] for p in points]), np.array([p["lon2"] for p in points])
    np.testing.assert_allclose(path_deviation_m(lat, lon, START, DEST), brute_force_deviation_m(lat, lon),
                               rtol=1e-9, atol=1e-6)


def test_points_beyond_the_ends_measure_to_the_end_point():
    end = WGS84.Direct(*DEST, LINE.Position(LINE.s13)["azi2"], 3000.0)     # 3 km past the destination
    before = WGS84.Direct(*START, LINE.azi1 + 180.0, 2000.0)               # 2 km behind the start
    dev = path_deviation_m([end["lat2"], before["lat2"]], [end["lon2"], before["lon2"]], START, DEST)
    np.testing.assert_allclose(dev, [3000.0, 2000.0], atol=1.0)


def test_track_metrics_of_a_constructed_track():
    """Steps of known length along the geodesic, some points pushed off it by known amounts."""
    steps = np.array([5000.0, 6500.0, 4000.0, 5200.0, 5800.0, 4900.0])
    along = np.concatenate([[0.0], np.cumsum(steps)])
    sides = np.array([0.0, 100.0, -250.0, 400.0, 0.0, -1200.0, 0.0])
    lat, lon = zip(*[offset(s, d) if d else on_line(s)[:2] for s, d in zip(along, sides)])
    lat, lon = np.array(lat), np.array(lon)
    # independent step lengths: geographiclib Inverse between consecutive points
    expected_steps = np.array([WGS84.Inverse(lat[i], lon[i], lat[i + 1], lon[i + 1])["s12"]
                               for i in range(len(lat) - 1)])
    # Vincenty's iteration: within 0.1 mm of geographiclib (companion.nav.geo, tested there)
    np.testing.assert_allclose(step_lengths_m(lat, lon), expected_steps, rtol=0.0, atol=1e-4)
    m = track_metrics(lat, lon, START, DEST)
    n = len(expected_steps)
    mean = sum(expected_steps) / n
    variance = sum((d - mean) ** 2 for d in expected_steps) / (n - 1)   # eq. 63: 1/(n-1)
    assert m.step_variance_m2 == pytest.approx(variance, rel=1e-9)
    assert m.length_m == pytest.approx(sum(expected_steps), abs=1e-3)
    assert m.iterations == n
    assert m.mean_deviation_m == pytest.approx(np.mean(np.abs(sides)), abs=1.0)
    assert m.max_deviation_m == pytest.approx(1200.0, abs=1.0)
    within = sum(abs(d) <= PMR_TOLERANCE_M for d in sides)          # 0, 100, -250, 0, 0
    assert m.path_matching_rate_pct == pytest.approx(100.0 * within / len(sides))
    assert m.remaining_m == pytest.approx(WGS84.Inverse(lat[-1], lon[-1], *DEST)["s12"], rel=1e-12)
    assert (m.final_lat_deg, m.final_lon_deg) == (lat[-1], lon[-1])
    assert track_metrics(lat, lon, START, DEST, iterations=99).iterations == 99


def test_mean_terminal_location_averages_longitude_on_the_circle():
    lat, lon = mean_terminal_location([28.0, 28.2, 27.8], [179.9, -179.9, 179.8])
    assert lat == pytest.approx(28.0)
    # by hand: the directions 179.9, 180.1, 179.8 deg average to 179.9333 (their spread is tiny,
    # so the circular mean equals the arithmetic one to ~1e-9 deg); the naive mean would be 60
    assert (lon - 179.9333333 + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)


# --- reference path ------------------------------------------------------------------------------
def along_from_start(lat: float, lon: float) -> float:
    return WGS84.Inverse(*START, lat, lon)["s12"]


@pytest.mark.parametrize("fraction", [0.0, 0.1, 0.37, 0.5, 0.8])
@pytest.mark.parametrize("side_m", [0.0, 1500.0, -4000.0])
def test_aim_point_lies_on_the_geodesic_one_lookahead_ahead(fraction, side_m):
    path = ReferencePath(START, DEST)
    lookahead = 10000.0
    s0 = fraction * LINE.s13
    lat, lon = offset(s0, side_m) if side_m else on_line(s0)[:2]
    aim = path.aim_point(lat, lon, lookahead)
    # on the geodesic: start->aim plus aim->dest is the whole length (equality only on the line)
    s_aim = along_from_start(*aim)
    assert s_aim + WGS84.Inverse(*aim, *DEST)["s12"] == pytest.approx(LINE.s13, abs=1e-3)
    assert path_deviation_m([aim[0]], [aim[1]], START, DEST)[0] < 0.05
    # ahead by the lookahead, to within the sample spacing (<= 250 m): the nearest sample is
    # within half a spacing of the position's foot point, the aim sample within one beyond
    spacing = LINE.s13 / (len(path.along_m) - 1)
    assert spacing <= 250.0
    assert -0.5 * spacing - 1.0 <= s_aim - (s0 + lookahead) <= 1.5 * spacing + 1.0


def test_aim_point_stops_at_the_destination():
    path = ReferencePath(START, DEST)
    lat, lon, _ = on_line(LINE.s13 - 3000.0)
    aim = path.aim_point(lat, lon, 10000.0)
    assert WGS84.Inverse(*aim, *DEST)["s12"] < 1e-3
    assert path.length_m == pytest.approx(LINE.s13)


def test_nearest_index_of_the_two_step_search_is_the_full_searchs():
    """Points up to 3000 km off the route and beyond both ends, against the argmin over every sample."""
    path = ReferencePath(START, DEST)
    rng = np.random.default_rng(3)
    lat = rng.uniform(min(START[0], DEST[0]) - 15.0, max(START[0], DEST[0]) + 15.0, 400)
    lon = rng.uniform(min(START[1], DEST[1]) - 15.0, max(START[1], DEST[1]) + 15.0, 400)
    for la, lo in zip(lat, lon):
        east_per_deg, north_per_deg = metres_per_degree(float(la))
        d_east = ((path.lon_deg - lo + 180.0) % 360.0 - 180.0) * east_per_deg
        d_north = (path.lat_deg - la) * north_per_deg
        assert path.nearest_index(float(la), float(lo)) == int(np.argmin(d_east ** 2 + d_north ** 2))

"""The 95 % ellipse drawn on the map, against computations that share nothing with it: SciPy's
chi-square quantile, geographiclib's geodesics for where each vertex lies, the closed-form
eigenvalues of a 2x2 matrix, and samples of the Gaussian itself."""
from __future__ import annotations

import math

import numpy as np
import pytest
from geographiclib.geodesic import Geodesic

from companion.operator_status import StatusReader
from fcmpc.mavproxy.ellipse import chi2_2dof, ellipse_axes, ellipse_points

scipy_stats = pytest.importorskip("scipy.stats")
pytest.importorskip("MAVProxy")

# north-north, north-east, east-east (m^2): round, elongated north-east, elongated north-west, thin
COVARIANCES = [(250_000.0, 0.0, 250_000.0), (640_000.0, 300_000.0, 250_000.0), (90_000.0, -120_000.0, 360_000.0),
               (4.0e6, 1.9e6, 1.0e6)]


def test_chi_square_quantile():
    for p in (0.5, 0.95, 0.99):
        assert chi2_2dof(p) == pytest.approx(scipy_stats.chi2.ppf(p, 2), rel=1e-12)
    assert chi2_2dof(0.95) == pytest.approx(5.991, abs=5e-4)
    with pytest.raises(ValueError):
        chi2_2dof(1.0)


@pytest.mark.parametrize("cov", COVARIANCES)
def test_axes_are_the_closed_form_eigenvalues(cov):
    nn, ne, ee = cov
    mean, half = (nn + ee) / 2.0, math.hypot((nn - ee) / 2.0, ne)
    axes = ellipse_axes(cov, 0.95)
    k2 = scipy_stats.chi2.ppf(0.95, 2)
    assert axes.semi_major_m == pytest.approx(math.sqrt(k2 * (mean + half)), rel=1e-9)
    assert axes.semi_minor_m == pytest.approx(math.sqrt(k2 * (mean - half)), rel=1e-9)
    if ne:   # the major axis leans towards the east when north and east errors go together
        assert (math.sin(2.0 * axes.major_azimuth_rad) > 0.0) == (ne > 0.0)


@pytest.mark.parametrize("cov", COVARIANCES)
def test_vertices_lie_on_the_95_percent_contour(cov):
    """Each vertex, placed by geodesic distance and azimuth from the centre, is at Mahalanobis
    distance^2 = 5.991 within 0.3 %: the points are offset on a plane with the centre's metres per
    degree (companion.nav.geo.offset_position), 0.12 % off in d^2 (3 m of 5.5 km) at the largest here."""
    lat0, lon0 = 33.0, 152.0
    points = ellipse_points(lat0, lon0, cov, 0.95, count=36)
    assert len(points) == 37 and points[0] == points[-1]
    mat = np.array([[cov[0], cov[1]], [cov[1], cov[2]]])
    for lat, lon in points:
        g = Geodesic.WGS84.Inverse(lat0, lon0, lat, lon)
        x = g["s12"] * np.array([math.cos(math.radians(g["azi1"])), math.sin(math.radians(g["azi1"]))])
        assert float(x @ np.linalg.solve(mat, x)) == pytest.approx(scipy_stats.chi2.ppf(0.95, 2), rel=3e-3)


def test_the_polygon_holds_95_percent_of_the_gaussian():
    """20,000 seeded samples of N(0, C) in local metres: the share inside the drawn polygon."""
    from matplotlib.path import Path

    cov = COVARIANCES[1]
    lat0, lon0 = -20.0, 10.0
    points = np.array(ellipse_points(lat0, lon0, cov, 0.95, count=96))
    g = Geodesic.WGS84
    local = []
    for lat, lon in points:
        inv = g.Inverse(lat0, lon0, lat, lon)
        local.append((inv["s12"] * math.cos(math.radians(inv["azi1"])), inv["s12"] * math.sin(math.radians(inv["azi1"]))))
    samples = np.random.default_rng(50).multivariate_normal([0.0, 0.0], [[cov[0], cov[1]], [cov[1], cov[2]]], 20_000)
    inside = Path(np.array(local)).contains_points(samples).mean()
    assert inside == pytest.approx(0.95, abs=0.006)   # 3 binomial sigmas (0.0015 each) and the 96-gon


def test_not_a_covariance_is_refused():
    for bad in ((math.nan, 0.0, 1.0), (1.0, 2.0, 1.0), (-1.0, 0.0, 1.0)):
        with pytest.raises(ValueError):
            ellipse_axes(bad)


def test_map_shapes_from_the_status():
    """The estimate, its ellipse and the destination; without a covariance the estimate alone."""
    from fcmpc.mavproxy.module import map_shapes

    reader = StatusReader()
    assert map_shapes(reader) == []
    reader.lat_deg, reader.lon_deg, reader.cov_ne_m2 = 33.0, 152.0, COVARIANCES[1]
    reader.params.update(NAV_DEST_LAT=28.0, NAV_DEST_LON=158.0)
    shapes = {s.key: s for s in map_shapes(reader)}
    assert set(shapes) == {"fcmpc:ellipse", "fcmpc:estimate", "fcmpc:destination"}
    assert shapes["fcmpc:ellipse"].points == tuple(ellipse_points(33.0, 152.0, COVARIANCES[1], 0.95))
    assert shapes["fcmpc:destination"].latlon == (28.0, 158.0)
    reader.cov_ne_m2 = (math.nan, math.nan, math.nan)
    assert [s.key for s in map_shapes(reader)] == ["fcmpc:estimate", "fcmpc:destination"]

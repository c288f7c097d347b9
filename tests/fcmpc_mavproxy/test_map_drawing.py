"""The module's map drawing, run: the companion's status messages (sent by the companion process
on the rig, read from the wire) go through the module's code to MAVProxy's own slip objects,
drawn by their own ``draw(img, pixmapper, bounds)`` with the map's Web Mercator pixmapper
(tests/fcmpc_mavproxy/headless_map.py: MAVProxy's map window without wxPython). The pixels are
checked against geometry computed here from the message's covariance (closed-form eigenvalues,
SciPy's chi-square quantile), not by the module's ellipse code.

The checks are shared with test_module_live.py, which draws what a running companion sends."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="MAVProxy's map drawing needs OpenCV (the test extra)")
pytest.importorskip("MAVProxy")
scipy_stats = pytest.importorskip("scipy.stats")

from MAVProxy.modules.mavproxy_map import mp_tile  # noqa: E402

from companion.operator_status import StatusReader  # noqa: E402
from fcmpc.mavproxy.module import map_shapes, update_map  # noqa: E402
from tests.companion.process.conftest import rig  # noqa: E402,F401  (the fixture: the companion on the rig)
from tests.companion.process.rig import GOOD, _run_step, _sent, make_rig  # noqa: E402
from tests.companion.process.test_operator_commands import GCS, _from  # noqa: E402
from tests.companion.process.test_phases import _at  # noqa: E402
from tests.fcmpc_mavproxy.headless_map import HeadlessSlipMap, View  # noqa: E402

MAGENTA = (255, 0, 255)          # the module's ellipse colour, drawn without anti-aliasing
ICONS = {"estimate": "purpleplane.png", "destination": "flag.png"}


def ellipse_tolerance_px(axis_px: float) -> float:
    """How far the drawn outline may lie from the ellipse: 2 px (the 2 px line's half width and
    rounding to pixels, 0.5 px) plus 0.5 % of the axis (the vertices are placed with WGS84's
    metres per degree, the map projects on MAVProxy's sphere of 6378.1 km: 0.4 % apart north-south
    at 33 deg)."""
    return 2.0 + 0.005 * axis_px


def metres_per_pixel(view: View, lat_deg: float) -> float:
    """Web Mercator's scale at ``lat_deg``, the view's ground width being at its top edge."""
    return view.ground_width / view.width / math.cos(math.radians(view.lat)) * math.cos(math.radians(lat_deg))


def axes_from_covariance(cov_ne_m2) -> tuple[float, float, float]:
    """(semi-major m, semi-minor m, azimuth of the major axis from north to east, rad) of the 95 %
    ellipse, from the 2x2 matrix's closed-form eigenvalues."""
    nn, ne, ee = cov_ne_m2
    mean, half = (nn + ee) / 2.0, math.hypot((nn - ee) / 2.0, ne)
    k2 = scipy_stats.chi2.ppf(0.95, 2)
    return math.sqrt(k2 * (mean + half)), math.sqrt(k2 * (mean - half)), 0.5 * math.atan2(2.0 * ne, nn - ee)


def assert_ellipse_drawn(img: np.ndarray, view: View, centre_px: tuple[int, int], lat_deg: float,
                         cov_ne_m2) -> dict:
    """The magenta outline is the 95 % ellipse of ``cov_ne_m2`` about ``centre_px``: its extent along
    each axis, the distance of every outline pixel from the ellipse, and of every point of the
    ellipse (each degree round) from the outline within :func:`ellipse_tolerance_px`, but where
    something drawn after it (the estimate's label) covers it."""
    a_m, b_m, az = axes_from_covariance(cov_ne_m2)
    scale = metres_per_pixel(view, lat_deg)
    a, b = a_m / scale, b_m / scale
    ys, xs = np.nonzero(np.all(img == MAGENTA, axis=2))
    assert xs.size > 2.0 * math.pi * b, f"{xs.size} magenta pixels for an ellipse of {a:.0f} x {b:.0f} px"
    east, north = xs - centre_px[0], centre_px[1] - ys
    u = east * math.sin(az) + north * math.cos(az)        # along the major axis
    v = east * math.cos(az) - north * math.sin(az)        # along the minor axis
    tol = ellipse_tolerance_px(a)
    extents = {"major+": u.max(), "major-": -u.min(), "minor+": v.max(), "minor-": -v.min()}
    for name, extent in extents.items():
        want = a if name.startswith("major") else b
        assert abs(extent - want) <= tol, f"{name} {extent:.1f} px, the geometry says {want:.1f} +- {tol:.1f}"
    t = np.radians(np.arange(360.0))
    ideal = np.stack([a * np.cos(t), b * np.sin(t)], axis=1)
    gaps = np.hypot(u[:, None] - ideal[None, :, 0], v[:, None] - ideal[None, :, 1])
    assert gaps.min(axis=1).max() <= tol, f"an outline pixel {gaps.min(axis=1).max():.1f} px off the ellipse"
    for i in np.nonzero(gaps.min(axis=0) > tol)[0]:
        (pu, pv), r = ideal[i], math.ceil(tol)
        x = round(centre_px[0] + pu * math.sin(az) + pv * math.cos(az))
        y = round(centre_px[1] - pu * math.cos(az) + pv * math.sin(az))
        near = img[y - r:y + r + 1, x - r:x + r + 1].reshape(-1, 3)
        assert np.any(near.any(axis=1) & ~np.all(near == MAGENTA, axis=1)), \
            f"the outline misses the ellipse at {i} deg by {gaps.min(axis=0)[i]:.1f} px, nothing drawn over it"
    return {"semi_major_px": a, "semi_minor_px": b, **extents}


def assert_icon_drawn(img: np.ndarray, expected_px: tuple[int, int], icon_file: str, search_px: int = 6) -> None:
    """MAVProxy's icon (SlipIcon: RGB, centred on its position, added to what is below) is drawn
    with its centre within 1 px of ``expected_px``, found by template matching within ``search_px``."""
    icon = cv2.cvtColor(mp_tile.mp_icon(icon_file), cv2.COLOR_BGR2RGB)
    h, w = icon.shape[:2]
    x0, y0 = expected_px[0] - w // 2 - search_px, expected_px[1] - h // 2 - search_px
    assert x0 >= 0 and y0 >= 0 and x0 + w + 2 * search_px <= img.shape[1] and y0 + h + 2 * search_px <= img.shape[0]
    window = img[y0:y0 + h + 2 * search_px, x0:x0 + w + 2 * search_px]
    scores = cv2.matchTemplate(window.astype(np.float32), icon.astype(np.float32), cv2.TM_SQDIFF)
    _, _, best, _ = cv2.minMaxLoc(scores)
    assert abs(best[0] - search_px) <= 1 and abs(best[1] - search_px) <= 1, \
        f"{icon_file} drawn {best[0] - search_px}, {best[1] - search_px} px from where the map puts it"
    drawn = window[search_px:search_px + h, search_px:search_px + w]
    lit = icon.sum(axis=2) > 0
    assert np.mean(np.all(drawn[lit] == icon[lit], axis=1)) >= 0.8, f"{icon_file} not drawn as itself"


def assert_nothing_at(img: np.ndarray, px: tuple[int, int], radius: int = 12) -> None:
    x, y = px
    assert not img[max(y - radius, 0):y + radius, max(x - radius, 0):x + radius].any(), f"something drawn at {px}"


def _status(app, fc) -> tuple[StatusReader, object]:
    """The companion's operator status and its answers to NAV_DEST_*, read as MAVProxy reads them."""
    app.telemetry.operator_status()
    for name in (b"NAV_DEST_LAT", b"NAV_DEST_LON"):
        app.handle(_from(GCS, "PARAM_REQUEST_READ", target_system=1, target_component=191, param_id=name,
                         param_index=-1))
    reader, sent = StatusReader(system=1, component=191), _sent(fc)
    for msg in sent:
        reader.packet(msg, 0.0)
    cov_msgs = [m for m in sent if m.get_type() == "GLOBAL_POSITION_INT_COV"]
    assert cov_msgs, [m.get_type() for m in sent]
    return reader, cov_msgs[-1]


def _message_geometry(msg) -> tuple[tuple[float, float], tuple[float, float, float]]:
    """(lat, lon) and (north-north, north-east, east-east) as the message carries them."""
    return (msg.lat * 1e-7, msg.lon * 1e-7), (msg.covariance[0], msg.covariance[1], msg.covariance[7])


def test_the_estimate_ellipse_and_destination_drawn_moved_and_taken_away(rig, tmp_path):
    app, fc = rig
    # an ellipse elongated north-north-east (440 x 140 m): a wrong axis or a north/east swap shows in
    # its extents; the step at mission time 0, so the companion flies its estimate on from there
    _run_step(app, replace(GOOD, time_s=0.0, est_cov_en_m2=(10_000.0, 12_000.0, 25_600.0)))   # ee, en, nn
    reader, msg = _status(app, fc)
    latlon, cov = _message_geometry(msg)
    slipmap = HeadlessSlipMap(str(tmp_path / "tiles"), log=lambda text: None)
    shapes = tuple(map_shapes(reader))
    update_map(slipmap, shapes)
    assert set(slipmap.layers["FcMPC"]) == {"fcmpc:ellipse", "fcmpc:estimate", "fcmpc:destination"}

    a_m = axes_from_covariance(cov)[0]
    view = View.centred(slipmap.tiles, *latlon, 8.0 * a_m)          # the ellipse across a quarter of the view
    pixmapper = view.pixmapper(slipmap.tiles)
    img = slipmap.draw(view)
    assert pixmapper(latlon) == (400, 300)
    assert_ellipse_drawn(img, view, pixmapper(latlon), latlon[0], cov)
    assert_icon_drawn(img, pixmapper(latlon), ICONS["estimate"])

    destination = (app.params.values["NAV_DEST_LAT"], app.params.values["NAV_DEST_LON"])
    far = View.centred(slipmap.tiles, *destination, 2_000.0)
    assert_icon_drawn(slipmap.draw(far), far.pixmapper(slipmap.tiles)(destination), ICONS["destination"])

    # 40 s on (the flight controller's clock in steps it accepts): the companion has flown its
    # estimate on with the command, 13 m/s south-east, 520 m; the same view
    for t_s in range(10, 50, 10):
        _at(app, float(t_s))
    reader, msg = _status(app, fc)
    latlon2, cov2 = _message_geometry(msg)
    shapes2 = tuple(map_shapes(reader))
    update_map(slipmap, shapes2, shapes)
    img2 = slipmap.draw(view)
    assert math.dist(pixmapper(latlon2), pixmapper(latlon)) > 80.0
    assert_icon_drawn(img2, pixmapper(latlon2), ICONS["estimate"])
    assert_nothing_at(img2, pixmapper(latlon))
    assert_ellipse_drawn(img2, view, pixmapper(latlon2), latlon2[0], cov2)


def test_the_ellipse_taken_away_when_the_covariance_is_unknown(rig, tmp_path):
    """A companion that has an estimate without a covariance (a step before the filter has one, or
    the filter reset): the estimate alone, the ellipse drawn before taken off the map."""
    app, fc = rig
    _run_step(app, replace(GOOD, est_cov_en_m2=(250_000.0, 300_000.0, 640_000.0)))
    reader, msg = _status(app, fc)
    slipmap = HeadlessSlipMap(str(tmp_path / "tiles"), log=lambda text: None)
    shapes = tuple(map_shapes(reader))
    update_map(slipmap, shapes)
    latlon, cov = _message_geometry(msg)
    view = View.centred(slipmap.tiles, *latlon, 6.0 * axes_from_covariance(cov)[0])
    assert np.all(slipmap.draw(view) == MAGENTA, axis=2).any()

    other, other_fc = make_rig(tmp_path / "no_covariance")
    try:
        _run_step(other, GOOD)                     # GOOD: no covariance
        reader, msg = _status(other, other_fc)
    finally:
        other.close()
        other_fc.close()
    assert math.isnan(msg.covariance[0])
    update_map(slipmap, tuple(map_shapes(reader)), shapes)
    img = slipmap.draw(view)
    assert set(slipmap.layers["FcMPC"]) == {"fcmpc:estimate", "fcmpc:destination"}
    assert not np.all(img == MAGENTA, axis=2).any()
    assert_icon_drawn(img, view.pixmapper(slipmap.tiles)(_message_geometry(msg)[0]), ICONS["estimate"])

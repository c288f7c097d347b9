"""The magnetometer calibration fit (companion.nav.calibration) on the real log171.bin.

log171's primary compass (MAG, milligauss, already corrected by the flight controller's own
COMPASS_* values) is the real sample set: its attitudes, its noise and motor interference. A
known hard/soft-iron distortion ``m' = A m + h`` applied to it must be recovered: the fit of the
distorted samples must equal the fit of the log's own samples composed with the distortion
(the calibration of ``m'`` is ``W0 A^-1 (m' - (h + A o0))``, whose symmetric form is
``sqrtm(A^-T W0^T W0 A^-1)``), within 1 % of the soft iron and 50 nT of the hard iron.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.nav.calibration import (
    CalibrationRefused,
    ardupilot_compass_params,
    companion_params,
    direction_coverage,
    down_in_body,
    fit_calibration,
    fit_level_calibration,
)
from companion.nav.circle_level import down_from_specific_force, fit_circle_calibration
from companion.frames import ned_to_body
from companion.nav.field import WorldMagneticModel
from companion.nav.magnetometer import MILLIGAUSS_TO_NT, MagCalibration

# WMM2015 at log171's GPS (-35.3623, 149.1658, 595 m) on 2015-11-21 (2015.89): checked below
LOG171_YEAR = 2015.89


@pytest.fixture(scope="module")
def log171_mag(log171: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(time s, MAG field nT (n, 3), the model's |B| nT at the log's first 3D fix), read with pymavlink."""
    t, mag, field, _ = _read_log171(log171)
    return t, mag, float(np.linalg.norm(field))


@pytest.fixture(scope="module")
def log171_attitude(log171: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ATT rows: time s, roll, pitch, yaw rad; the model's field NED nT at the first fix)."""
    _, _, field, att = _read_log171(log171)
    return att, field


_CACHE: dict[str, tuple] = {}


def _read_log171(log171: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    if "log171" in _CACHE:
        return _CACHE["log171"]
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(log171))
    rows, att, fix = [], [], None
    try:
        while (msg := conn.recv_match(type=["MAG", "GPS", "ATT"])) is not None:
            if msg.get_type() == "MAG":   # Copter 3.3: TimeMS since boot, mG
                rows.append((msg.TimeMS * 1e-3, msg.MagX, msg.MagY, msg.MagZ))
            elif msg.get_type() == "ATT":
                att.append((msg.TimeMS * 1e-3, *np.radians((msg.Roll, msg.Pitch, msg.Yaw))))
            elif fix is None and msg.Status >= 3:
                fix = (msg.Lat, msg.Lng, msg.Alt)
    finally:
        conn.close()
    assert fix is not None
    a = np.array(rows)
    import pygeomag

    wmm2015 = WorldMagneticModel.from_cof(Path(pygeomag.__file__).resolve().parent / "wmm" / "WMM_2015.COF")
    field = np.array(wmm2015.ned(fix[0], fix[1], fix[2], LOG171_YEAR), dtype=float)
    _CACHE["log171"] = (a[:, 0], a[:, 1:] * MILLIGAUSS_TO_NT, field, np.array(att))
    return _CACHE["log171"]


def test_model_field_at_log171(log171_mag) -> None:
    _, mag, field_nt = log171_mag
    assert field_nt == pytest.approx(58170.0, abs=20.0)
    assert len(mag) == 2384


def _symmetric_root(b: np.ndarray) -> np.ndarray:
    values, vectors = np.linalg.eigh(b.T @ b)
    return (vectors * np.sqrt(values)) @ vectors.T


@pytest.mark.parametrize("distortion, hard_iron_nt", [
    (((1.08, 0.03, -0.02), (0.03, 0.95, 0.04), (-0.02, 0.04, 1.02)), (4000.0, -2500.0, 1500.0)),
    (((0.85, -0.06, 0.05), (-0.06, 1.12, 0.0), (0.05, 0.0, 0.97)), (-30000.0, 12000.0, -8000.0)),
])
def test_known_distortion_of_log171_is_recovered(log171_mag, distortion, hard_iron_nt) -> None:
    _, mag, field_nt = log171_mag
    own = fit_calibration(mag, field_nt)
    a, h = np.array(distortion), np.array(hard_iron_nt)
    fit = fit_calibration(mag @ a.T + h, field_nt)
    w0, o0 = np.array(own.soft_iron), np.array(own.offset_nt)
    expected_w = _symmetric_root(w0 @ np.linalg.inv(a))
    expected_o = h + a @ o0
    w = np.array(fit.soft_iron)
    assert np.linalg.norm(w - expected_w) / np.linalg.norm(expected_w) < 0.01
    assert np.abs(w - expected_w).max() < 0.01
    assert np.linalg.norm(np.array(fit.offset_nt) - expected_o) < 50.0
    # the corrected field of the distorted samples is the log's own corrected field, same size
    assert fit.residual_nt == pytest.approx(own.residual_nt, rel=0.01)
    # the log's own calibration: |F| 6-7 % above the model (the log171 replay's finding), < 1 % rms after
    assert np.linalg.norm(mag, axis=1).mean() / field_nt == pytest.approx(1.07, abs=0.01)
    assert own.residual_nt < 0.01 * field_nt


def test_corrected_field_has_the_models_magnitude(log171_mag) -> None:
    _, mag, field_nt = log171_mag
    fit = fit_calibration(mag, field_nt)
    cal = fit.calibration
    corrected = np.array([cal.apply(tuple(m)) for m in mag])
    assert np.median(np.linalg.norm(corrected, axis=1)) == pytest.approx(field_nt, rel=0.005)
    # the parameter sets say the same calibration
    comp = companion_params(fit)
    again = MagCalibration.from_mgauss(tuple(comp[f"MAG_OFS_{a}"] for a in "XYZ"),
                                       tuple(comp[f"MAG_SCALE_{a}"] for a in "XYZ"),
                                       (comp["MAG_SOFT_XY"], comp["MAG_SOFT_XZ"], comp["MAG_SOFT_YZ"]))
    assert np.allclose(again.apply(tuple(mag[0])), cal.apply(tuple(mag[0])))
    ap, angle = ardupilot_compass_params(fit)
    assert angle == pytest.approx(0.0, abs=1e-6)
    matrix = np.array([[ap["COMPASS_DIA_X"], ap["COMPASS_ODI_X"], ap["COMPASS_ODI_Y"]],
                       [ap["COMPASS_ODI_X"], ap["COMPASS_DIA_Y"], ap["COMPASS_ODI_Z"]],
                       [ap["COMPASS_ODI_Y"], ap["COMPASS_ODI_Z"], ap["COMPASS_DIA_Z"]]])
    ofs_mgauss = np.array([ap[f"COMPASS_OFS_{a}"] for a in "XYZ"])
    ardupilot = matrix @ (mag[0] / MILLIGAUSS_TO_NT + ofs_mgauss) * MILLIGAUSS_TO_NT
    assert np.allclose(ardupilot, cal.apply(tuple(mag[0])))
    assert set(ardupilot_compass_params(fit, 2)[0]) == {f"COMPASS_{k}2_{a}" for k in ("OFS", "DIA", "ODI")
                                                     for a in "XYZ"}


def test_too_little_rotation_is_refused(log171_mag) -> None:
    """On the ground before take-off (first 80 s) and in the climb the copter hardly turns."""
    t, mag, field_nt = log171_mag
    for t0, t1 in ((0.0, 80.0), (90.0, 130.0)):
        part = mag[(t >= t0) & (t < t1)]
        assert len(part) > 300
        with pytest.raises(CalibrationRefused, match="cover") as err:
            fit_calibration(part, field_nt)
        assert "sphere" in str(err.value)


def test_refusals_name_their_reason() -> None:
    with pytest.raises(CalibrationRefused, match="at least 100"):
        fit_calibration(np.ones((10, 3)), 50000.0)
    with pytest.raises(CalibrationRefused, match="do not vary"):
        fit_calibration(np.ones((200, 3)), 50000.0)
    with pytest.raises(ValueError, match="field_nt"):
        fit_calibration(np.ones((200, 3)), float("nan"))
    # one turn about z: a ring of directions, no soft iron in z can be known
    psi = np.linspace(0.0, 4.0 * np.pi, 400)
    ring = np.column_stack([20000.0 * np.cos(psi), 20000.0 * np.sin(psi), np.full(400, 45000.0)])
    with pytest.raises(CalibrationRefused):
        fit_calibration(ring, float(np.linalg.norm(ring[0])))


def test_direction_coverage_of_a_uniform_sphere() -> None:
    rng = np.random.default_rng(3)
    u = rng.normal(size=(5000, 3))
    share, scatter = direction_coverage(u)
    assert share == 1.0
    assert scatter == pytest.approx((1 / 3, 1 / 3, 1 / 3), abs=0.02)


def test_ardupilot_equivalents_compose_with_the_parameters_in_force(log171_mag) -> None:
    """A field already corrected by COMPASS_OFS/DIA/ODI: the new values calibrate the raw one."""
    _, mag, field_nt = log171_mag
    current = {"COMPASS_OFS_X": 120.0, "COMPASS_OFS_Y": -40.0, "COMPASS_OFS_Z": 65.0,
               "COMPASS_DIA_X": 1.02, "COMPASS_DIA_Y": 0.97, "COMPASS_DIA_Z": 1.0,
               "COMPASS_ODI_X": 0.01, "COMPASS_ODI_Y": -0.02, "COMPASS_ODI_Z": 0.015}
    old_m = np.array([[1.02, 0.01, -0.02], [0.01, 0.97, 0.015], [-0.02, 0.015, 1.0]])
    old_ofs = np.array([120.0, -40.0, 65.0])
    raw_mgauss = np.linalg.solve(old_m, (mag / MILLIGAUSS_TO_NT).T).T - old_ofs   # what the sensor read
    fit = fit_calibration(mag, field_nt)
    ap, angle = ardupilot_compass_params(fit, 1, current)
    assert angle < 1.0
    matrix = np.array([[ap["COMPASS_DIA_X"], ap["COMPASS_ODI_X"], ap["COMPASS_ODI_Y"]],
                       [ap["COMPASS_ODI_X"], ap["COMPASS_DIA_Y"], ap["COMPASS_ODI_Z"]],
                       [ap["COMPASS_ODI_Y"], ap["COMPASS_ODI_Z"], ap["COMPASS_DIA_Z"]]])
    new = (raw_mgauss + np.array([ap[f"COMPASS_OFS_{a}"] for a in "XYZ"])) @ matrix.T * MILLIGAUSS_TO_NT
    ours = np.array([fit.calibration.apply(tuple(m)) for m in mag])
    assert np.allclose(np.linalg.norm(new, axis=1), np.linalg.norm(ours, axis=1), rtol=1e-9)
    cos = np.sum(new * ours, axis=1) / np.linalg.norm(new, axis=1) / np.linalg.norm(ours, axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() <= angle + 1e-6


LEVEL_W = np.array([[1.1, 0.05, 0.0], [0.05, 0.92, 0.0], [0.0, 0.0, 1.01]])   # W33 = mean of W11, W22
LEVEL_O = np.array([12000.0, -7000.0, 4000.0])


def test_a_level_ring_is_fitted_by_the_level_calibration() -> None:
    """A boat's two slow circles: refused by the full fit, recovered exactly by the level one."""
    field = np.array([20000.0, 2000.0, 45000.0])
    yaw = np.linspace(0.0, 4.0 * np.pi, 400)
    body = np.array([ned_to_body(tuple(field), 0.0, 0.0, y) for y in yaw])
    raw = np.linalg.solve(LEVEL_W, body.T).T + LEVEL_O
    with pytest.raises(CalibrationRefused, match="scatter"):
        fit_calibration(raw, float(np.linalg.norm(field)))
    fit = fit_level_calibration(raw, down_in_body(np.zeros(400), np.zeros(400)), float(np.hypot(*field[:2])),
                                field[2])
    assert fit.level and fit.cell_share == 1.0
    assert np.allclose(fit.offset_nt, LEVEL_O, atol=0.5) and np.allclose(fit.soft_iron, LEVEL_W, atol=1e-6)
    half = slice(0, 100)   # half a circle: refused
    with pytest.raises(CalibrationRefused, match="sectors"):
        fit_level_calibration(raw[half], down_in_body(np.zeros(100), np.zeros(100)), float(np.hypot(*field[:2])),
                              field[2])


def test_level_calibration_with_log171s_attitudes(log171_attitude) -> None:
    """The field seen through log171's airborne attitudes (86-229 s: 419 deg of yaw, tilts up to
    40 deg), distorted, with 300 nT of noise (seeded): hard iron within 150 nT, soft iron 0.5 %."""
    att, field = log171_attitude
    air = att[(att[:, 0] > 86.0) & (att[:, 0] < 229.0)]
    body = np.array([ned_to_body(tuple(field), r, p, y) for _, r, p, y in air])
    rng = np.random.default_rng(7)
    raw = np.linalg.solve(LEVEL_W, body.T).T + LEVEL_O + rng.normal(0.0, 300.0, body.shape)
    fit = fit_level_calibration(raw, down_in_body(air[:, 1], air[:, 2]), float(np.hypot(*field[:2])), field[2])
    assert np.abs(np.array(fit.offset_nt) - LEVEL_O).max() < 150.0
    assert np.abs(np.array(fit.soft_iron) - LEVEL_W).max() < 0.005
    assert fit.residual_nt == pytest.approx(300.0, rel=0.1)


def _circle_rows(pitch_bias_deg: float, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A boat's calibration circle at 8 m/s turning right at 1.2 deg/s (300 s, 2 Hz), level, whose
    flight controller reports its pitch ``pitch_bias_deg`` off (ArduPilot's EKF in lockstep: +1.4
    deg on the circle, docs/notes/2026-12-06-ardupilot-json-lockstep.md section 6); the installation
    LEVEL_W/LEVEL_O with 150 nT of noise, the accelerometer with 0.02 m/s^2. Rows as
    CIRCLE_COLUMNS; and the field NED (nT)."""
    field = np.array([22000.0, 1500.0, 38000.0])
    rng = np.random.default_rng(seed)
    rate, speed = np.radians(1.2), 8.0
    yaw = np.arange(0.0, 300.0, 0.5) * rate
    body = np.array([ned_to_body(tuple(field), 0.0, 0.0, y) for y in yaw])
    raw = np.linalg.solve(LEVEL_W, body.T).T + LEVEL_O + rng.normal(0.0, 150.0, body.shape)
    centripetal = speed * rate * np.column_stack([-np.sin(yaw), np.cos(yaw), np.zeros_like(yaw)])
    force = np.array([ned_to_body((a[0], a[1], -9.80665), 0.0, 0.0, y) for a, y in zip(centripetal, yaw)])
    force += rng.normal(0.0, 0.02, force.shape)
    gyro = np.column_stack([np.zeros_like(yaw), np.zeros_like(yaw), np.full_like(yaw, rate)])
    fc = np.column_stack([np.zeros_like(yaw), np.full_like(yaw, np.radians(pitch_bias_deg))])
    return np.column_stack([raw, fc, force, gyro]), field


def _inclination_errors_deg(calibration: MagCalibration, field: np.ndarray) -> np.ndarray:
    """The gravity-referenced I minus the field's, on straight level legs at 8 headings."""
    from companion.nav.magnetometer import decl_incl_deg, gravity_inclination_deg

    truth = decl_incl_deg(*field)[1]
    errors = []
    for heading in np.radians(np.arange(0.0, 360.0, 45.0)):
        raw = np.linalg.solve(LEVEL_W, np.array(ned_to_body(tuple(field), 0.0, 0.0, heading))) + LEVEL_O
        errors.append(gravity_inclination_deg(calibration.apply(tuple(raw)), (0.0, 0.0, -9.80665)) - truth)
    return np.array(errors)


def test_a_circle_levelled_by_the_accelerometer_ignores_the_flight_controllers_tilt_error() -> None:
    """Levelled by the flight controller's biased pitch, the circle's fit turns the tilt into soft iron
    and the mission's gravity-referenced I errs with the heading (more than 1 deg here, as measured
    in lockstep: -1.3 to +1.6 deg); levelled by the specific force less the turn's centripetal part,
    within 0.1 deg at every heading, the bias notwithstanding."""
    rows, field = _circle_rows(pitch_bias_deg=1.4)
    h, z = float(np.hypot(*field[:2])), float(field[2])
    by_attitude = fit_level_calibration(rows[:, :3], down_in_body(rows[:, 3], rows[:, 4]), h, z)
    assert np.abs(_inclination_errors_deg(by_attitude.calibration, field)).max() > 1.0
    fit, by_accelerometer = fit_circle_calibration(rows, 8.0, h, z)
    assert by_accelerometer
    assert np.abs(_inclination_errors_deg(fit.calibration, field)).max() < 0.1
    assert np.abs(np.array(fit.offset_nt) - LEVEL_O).max() < 100.0
    # without the IMU (a source that gives none) the attitude is all there is
    rows[:, 5:] = np.nan
    assert not fit_circle_calibration(rows, 8.0, h, z)[1]


def test_the_centripetal_acceleration_is_removed_with_the_speed_flown() -> None:
    """The specific force on the circle tilts 1 deg to the inside at 8 m/s and 1.2 deg/s; the down
    vectors are level once the gyro x speed is removed, and tilted without it."""
    rows, _ = _circle_rows(0.0)
    level = down_from_specific_force(rows[:, 5:8], rows[:, 8:11], 8.0).mean(axis=0)
    assert np.degrees(np.arccos(level[2] / np.linalg.norm(level))) < 0.02
    tilted = down_from_specific_force(rows[:, 5:8], rows[:, 8:11], 0.0).mean(axis=0)
    assert np.degrees(np.arccos(tilted[2] / np.linalg.norm(tilted))) == pytest.approx(0.96, abs=0.05)
    assert np.isnan(down_from_specific_force([(np.nan, 0.0, 0.0), (0.0, 0.0, 0.0)], np.zeros((2, 3)), 8.0)).all()

"""Rotations, tilt compensation and the Mahony filter, against synthetic truth."""
from __future__ import annotations

import math
import random

import pytest

from companion.io.sensors.attitude import (
    MahonyFilter,
    MahonyGains,
    body_to_ned,
    euler_from_quaternion,
    heading_from_mag,
    ned_to_body,
    quaternion_from_euler,
    tilt_from_accel,
)

G = 9.80665
FIELD_NED = (23140.0, 5084.0, -53127.0)  # Canberra 2015 (WMM2015): D = 12.39, I = -65.97 deg


def specific_force(roll: float, pitch: float) -> tuple[float, float, float]:
    return ned_to_body((0.0, 0.0, -G), roll, pitch, 0.0)


def angle_diff_deg(a_rad: float, b_rad: float) -> float:
    return math.degrees(math.remainder(a_rad - b_rad, 2.0 * math.pi))


def test_body_ned_round_trip_and_known_rotation() -> None:
    rng = random.Random(7)
    for _ in range(50):
        r, p, y = rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(0, 6.28)
        v = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1))
        assert body_to_ned(ned_to_body(v, r, p, y), r, p, y) == pytest.approx(v, abs=1e-12)
    # Nose up 90 degrees: the body x axis points up (NED -z).
    assert body_to_ned((1.0, 0.0, 0.0), 0.0, math.pi / 2, 0.0) == pytest.approx((0.0, 0.0, -1.0), abs=1e-12)


def test_quaternion_euler_round_trip() -> None:
    rng = random.Random(3)
    for _ in range(50):
        r, p, y = rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(0, 6.28)
        assert euler_from_quaternion(quaternion_from_euler(r, p, y)) == pytest.approx((r, p, y), abs=1e-9)


def test_tilt_compensated_heading_and_declination_of_a_tilted_vehicle() -> None:
    rng = random.Random(11)
    decl = math.atan2(FIELD_NED[1], FIELD_NED[0])
    for _ in range(50):
        r, p, y = rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(0, 6.28)
        mag_b = ned_to_body(FIELD_NED, r, p, y)
        roll, pitch = tilt_from_accel(specific_force(r, p))
        assert (roll, pitch) == pytest.approx((r, p), abs=1e-12)
        assert angle_diff_deg(heading_from_mag(mag_b, roll, pitch), y - decl) == pytest.approx(0.0, abs=1e-9)
        # Given the true yaw, the measured vector gives D back: what the log replay does.
        n = body_to_ned(mag_b, r, p, y)
        assert math.degrees(math.atan2(n[1], n[0])) == pytest.approx(12.39, abs=0.01)


def run(filt: MahonyFilter, seconds: float, rate_hz: float, truth, gyro_bias=(0.0, 0.0, 0.0), t0=0.0):
    """Feed the filter consistent sensors along truth(t) -> (roll, pitch, yaw, rates)."""
    dt = 1.0 / rate_hz
    out = None
    for k in range(int(seconds * rate_hz)):
        t = t0 + k * dt
        r, p, y, w = truth(t)
        gyro = (w[0] + gyro_bias[0], w[1] + gyro_bias[1], w[2] + gyro_bias[2])
        out = filt.update(t, specific_force(r, p), gyro, ned_to_body(FIELD_NED, r, p, y))
    return out


def test_filter_tracks_a_constant_yaw_rate_turn() -> None:
    rate = math.radians(30.0)  # level turn, body z rate = yaw rate

    def truth(t: float):
        return 0.0, 0.0, (1.0 + rate * t) % (2 * math.pi), (0.0, 0.0, rate)

    filt = MahonyFilter(declination_rad=math.atan2(FIELD_NED[1], FIELD_NED[0]))
    roll, pitch, yaw = run(filt, 20.0, 100.0, truth)
    assert abs(math.degrees(roll)) < 0.1 and abs(math.degrees(pitch)) < 0.1
    assert angle_diff_deg(yaw, truth(19.99)[2]) == pytest.approx(0.0, abs=0.5)


def test_filter_converges_from_a_wrong_start() -> None:
    filt = MahonyFilter()
    # Start believing the vehicle is level and pointing at magnetic north...
    filt.update(0.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0), (FIELD_NED[0], 0.0, FIELD_NED[2]))
    r0, p0, y0 = math.radians(15.0), math.radians(-10.0), math.radians(120.0)
    # ...while it really sits tilted and turned.
    roll, pitch, yaw = run(filt, 15.0, 100.0, lambda t: (r0, p0, y0, (0.0, 0.0, 0.0)), t0=0.01)
    assert math.degrees(roll) == pytest.approx(15.0, abs=0.5)
    assert math.degrees(pitch) == pytest.approx(-10.0, abs=0.5)
    decl = math.atan2(FIELD_NED[1], FIELD_NED[0])
    assert angle_diff_deg(yaw, y0 - decl) == pytest.approx(0.0, abs=1.0)


def test_integral_term_absorbs_a_gyro_bias() -> None:
    filt = MahonyFilter(MahonyGains(kp=1.0, kp_yaw=0.5, ki=0.1))
    bias = (0.02, -0.015, 0.01)  # rad/s, about 1 deg/s
    roll, pitch, yaw = run(filt, 120.0, 50.0, lambda t: (0.1, 0.05, 2.0, (0.0, 0.0, 0.0)), gyro_bias=bias)
    decl = math.atan2(FIELD_NED[1], FIELD_NED[0])
    # Without the integral term a 1 deg/s bias against kp = 1/s leaves about a degree.
    assert math.degrees(roll) == pytest.approx(math.degrees(0.1), abs=0.1)
    assert math.degrees(pitch) == pytest.approx(math.degrees(0.05), abs=0.1)
    assert angle_diff_deg(yaw, 2.0 - decl) == pytest.approx(0.0, abs=0.3)


def test_a_magnetic_disturbance_does_not_tilt_the_estimate() -> None:
    filt = MahonyFilter()
    disturbed = (FIELD_NED[0], FIELD_NED[1], FIELD_NED[2] + 30000.0)  # strong vertical error
    dt = 0.01
    for k in range(2000):
        out = filt.update(k * dt, (0.0, 0.0, -G), (0.0, 0.0, 0.0), disturbed)
    roll, pitch, _ = out
    assert abs(math.degrees(roll)) < 0.01 and abs(math.degrees(pitch)) < 0.01


def test_a_long_gap_reinitialises() -> None:
    filt = MahonyFilter(MahonyGains(max_dt_s=0.2))
    filt.update(0.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0), (FIELD_NED[0], 0.0, FIELD_NED[2]))
    mag = ned_to_body(FIELD_NED, 0.0, 0.0, 1.0)
    _, _, yaw = filt.update(5.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0), mag)
    decl = math.atan2(FIELD_NED[1], FIELD_NED[0])
    assert angle_diff_deg(yaw, 1.0 - decl) == pytest.approx(0.0, abs=1e-6)


def test_gains_are_validated() -> None:
    with pytest.raises(ValueError, match="kp"):
        MahonyGains(kp=-1.0)
    with pytest.raises(ValueError, match="accel_gate"):
        MahonyGains(accel_gate=1.5)

"""Magnetometer units as the autopilots put them into MAVLink (companion.io.sensors.mag_units)."""
from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.link import MessageClock
from companion.io.sensors.mag_units import count_to_nt, highres_nt_per_unit, mag_messages
from companion.io.sensors.mavlink_source import MavlinkDecoder


def _truncated_counts(field_nt: np.ndarray) -> np.ndarray:
    """What ArduPilot and PX4 put into an int16 mG field: the C conversion, toward zero."""
    return np.trunc(field_nt / 100.0).astype(int)


def test_midpoint_of_a_truncated_count_is_unbiased_where_the_count_itself_is_not():
    """With noise spanning a few counts, the count itself is 50 nT short of the field on average,
    toward zero; the midpoint's mean error is within 2 nT of zero, for both signs."""
    rng = np.random.default_rng(7)
    for true_nt in (30_289.8, -2_178.9, 7.0):
        samples = true_nt + rng.normal(0.0, 150.0, 200_000)     # 1.5 counts of noise
        counts = _truncated_counts(samples)
        midpoint = np.mean([count_to_nt(int(c)) for c in counts[:20_000]])
        plain = np.mean(counts[:20_000]) * 100.0
        assert abs(midpoint - true_nt) < 3.0, (true_nt, midpoint)
        if abs(true_nt) > 500.0:
            assert abs(plain - true_nt) > 40.0      # the bias the midpoint removes is really there


def test_noise_free_field_is_never_more_than_half_a_count_off():
    rng = np.random.default_rng(1)
    field = rng.uniform(-60_000.0, 60_000.0, 5_000)
    err = np.array([count_to_nt(int(c)) for c in _truncated_counts(field)]) - field
    assert np.max(np.abs(err[np.abs(field) >= 100.0])) <= 50.0 + 1e-9
    assert np.max(np.abs(err)) <= 100.0                  # the zero count spans (-1, 1) mG


def _highres(t_us: int, mag: tuple[float, float, float]):
    return mavlink.MAVLink_highres_imu_message(t_us, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, *mag, 1013.0, 0.0, 0.0, 25.0,
                                               0x1FF, 0)


def _raw(t_us: int, mag: tuple[int, int, int]):
    return mavlink.MAVLink_raw_imu_message(t_us, 0, 0, -1000, 0, 0, 0, *mag, 0, 0)


def test_ardupilot_prefers_highres_imu_in_its_own_unit_and_retires_raw_imu():
    """The pair measured on ArduRover SITL: HIGHRES_IMU 302897.875 (compass.get_field() * 1000, 1e-6
    gauss) where RAW_IMU said 302. RAW_IMU serves until HIGHRES_IMU arrives, then only HIGHRES_IMU."""
    dec = MavlinkDecoder(MessageClock(), mag_message=mag_messages("ardupilot"), imu=False,
                         highres_nt_per_unit=highres_nt_per_unit("ardupilot"))
    [first] = dec.decode(_raw(1_000_000, (302, -21, 294)))
    assert first.mag_body_nt == (30250.0, -2150.0, 29450.0)
    [better] = dec.decode(_highres(1_100_000, (302897.875, -21789.26, 294424.81)))
    assert better.mag_body_nt == pytest.approx((30289.79, -2178.93, 29442.48), abs=0.01)
    assert dec.superseded == {"RAW_IMU"}
    assert dec.decode(_raw(1_200_000, (302, -21, 294))) == []
    for got, raw in zip(better.mag_body_nt, first.mag_body_nt):
        assert abs(got - raw) <= 50.0                   # the same field, the midpoint within half a count


def test_px4_reads_gauss_and_only_its_scaled_imu():
    dec = MavlinkDecoder(MessageClock(), mag_message=mag_messages("px4"), imu=False,
                         highres_nt_per_unit=highres_nt_per_unit("px4"))
    assert dec.decode(_highres(1_000_000, (0.3029, -0.0218, 0.2944))) == []
    explicit = MavlinkDecoder(MessageClock(), mag_message="HIGHRES_IMU", imu=False)
    [sample] = explicit.decode(_highres(1_000_000, (0.3029, -0.0218, 0.2944)))
    assert sample.mag_body_nt == pytest.approx((30290.0, -2180.0, 29440.0))


def test_unknown_magnetometer_message_is_refused():
    with pytest.raises(ValueError, match="not one of"):
        MavlinkDecoder(MessageClock(), mag_message=("HIGHRES_IMU", "GPS_RAW_INT"))


def test_preference_set_after_another_message_came_first_takes_over():
    """Before the autopilot is known the first magnetometer message owns the sensor; the family's
    preference, set once it is known, replaces it (PX4's HIGHRES_IMU comes first, SCALED_IMU is read)."""
    dec = MavlinkDecoder(MessageClock(), imu=False)
    assert len(dec.decode(_highres(1_000_000, (0.3029, -0.0218, 0.2944)))) == 1
    dec.mag_message = mag_messages("px4")
    scaled = mavlink.MAVLink_scaled_imu_message(1100, 0, 0, -1000, 0, 0, 0, 302, -21, 294, 0)
    [sample] = dec.decode(scaled)
    assert sample.mag_body_nt == (30250.0, -2150.0, 29450.0)
    assert dec.decode(_highres(1_200_000, (0.3029, -0.0218, 0.2944))) == []

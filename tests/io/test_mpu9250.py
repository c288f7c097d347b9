"""MPU9250 + AK8963 driver against the emulated register map (no hardware)."""
from __future__ import annotations

import math

import pytest

from companion.io.sensors import AttitudeSample, ImuSample, MagSample, SampleFlag, SensorError
from companion.io.sensors.attitude import ned_to_body
from companion.io.sensors.mpu9250 import MagCalibration, Mpu9250Config, Mpu9250Source
from companion.io.sensors.quality import MagChecks
from tests.io.emulated_mpu9250 import GRAVITY_MPS2, EmulatedMpu9250


class FakeTime:
    """An injectable clock and sleep that advance together."""

    def __init__(self, start: float = 100.0) -> None:
        self.now = start
        self.slept = 0.0

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds
        self.slept += seconds


def make(chip: EmulatedMpu9250, **config: object) -> tuple[Mpu9250Source, FakeTime]:
    t = FakeTime()
    src = Mpu9250Source(chip, Mpu9250Config(**config), clock=t.clock, sleep=t.sleep)
    return src, t


def by_type(samples: list, cls: type) -> list:
    return [s for s in samples if isinstance(s, cls)]


def specific_force(roll: float, pitch: float) -> tuple[float, float, float]:
    g = GRAVITY_MPS2
    return (g * math.sin(pitch), -g * math.sin(roll) * math.cos(pitch), -g * math.cos(roll) * math.cos(pitch))


@pytest.mark.parametrize("gyro_dps, accel_g", [(250, 2), (500, 4), (2000, 16)])
@pytest.mark.parametrize("asa", [(128, 128, 128), (176, 177, 165), (0, 255, 90)])
def test_decodes_the_emulated_state_back_within_quantisation(gyro_dps: int, accel_g: int, asa: tuple) -> None:
    field = (21345.0, -4567.0, -52012.0)
    accel = specific_force(math.radians(10.0), math.radians(-5.0))
    gyro = (0.0123, -0.0456, 0.789)
    chip = EmulatedMpu9250(field_body_nt=field, accel_body_mps2=accel, gyro_body_radps=gyro,
                           temperature_c=36.6, asa=asa)
    src, _ = make(chip, gyro_range_dps=gyro_dps, accel_range_g=accel_g)
    with src:
        samples = src.poll(0.1)
    imu = by_type(samples, ImuSample)[0]
    mag = by_type(samples, MagSample)[0]
    assert imu.valid and mag.valid

    accel_lsb = accel_g * GRAVITY_MPS2 / 32768.0
    gyro_lsb = math.radians(gyro_dps) / 32768.0
    for got, want in zip(imu.accel_body_mps2, accel):
        assert got == pytest.approx(want, abs=0.51 * accel_lsb)
    for got, want in zip(imu.gyro_body_radps, gyro):
        assert got == pytest.approx(want, abs=0.51 * gyro_lsb)
    assert imu.temperature_c == pytest.approx(36.6, abs=0.51 / 333.87)
    # Half an LSB of the AK8963 after the sensitivity adjustment of the axis involved.
    adj = [(a - 128) * 0.5 / 128 + 1 for a in asa]
    # body x = chip x = AK y; body y = -chip y = -AK x; body z = -chip z = AK z
    lsb_nt = (150.0 * adj[1], 150.0 * adj[0], 150.0 * adj[2])
    for got, want, lsb in zip(mag.mag_body_nt, field, lsb_nt):
        assert got == pytest.approx(want, abs=0.51 * lsb)


def test_configures_ranges_filter_rate_bypass_and_continuous_16bit_mode() -> None:
    chip = EmulatedMpu9250()
    src, _ = make(chip, gyro_range_dps=1000, accel_range_g=8, dlpf_hz=20, sample_rate_hz=200.0)
    with src:
        assert src.chip == "MPU-9250"
    assert chip.mpu[0x1B] == 2 << 3  # GYRO_CONFIG FS_SEL 1000 dps
    assert chip.mpu[0x1C] == 2 << 3  # ACCEL_CONFIG 8 g
    assert chip.mpu[0x1A] == 4  # DLPF_CFG 20 Hz
    assert chip.mpu[0x1D] == 4  # A_DLPF_CFG 21 Hz
    assert chip.mpu[0x19] == 4  # SMPLRT_DIV: 1000 / (1 + 4) = 200 Hz
    assert chip.mpu[0x37] & 0x02  # bypass to the AK8963
    assert chip.ak_cntl1 == 0x16  # 16-bit, continuous mode 2 (100 Hz)
    ak_writes = [(reg, val) for addr, reg, val in chip.writes if addr == 0x0C and reg == 0x0A]
    assert (0x0A, 0x0F) in ak_writes  # fuse ROM read for the ASA values


def test_the_mpu9255_is_accepted() -> None:
    src, _ = make(EmulatedMpu9250(who_am_i=0x73))
    with src:
        assert src.chip == "MPU-9255"


def test_a_wrong_who_am_i_is_a_clear_error() -> None:
    src, _ = make(EmulatedMpu9250(who_am_i=0x70))
    with pytest.raises(SensorError, match=r"WHO_AM_I 0x70.*MPU-6500.*expected 0x71"):
        src.open()
    src, _ = make(EmulatedMpu9250(who_am_i=0x12))
    with pytest.raises(SensorError, match=r"unexpected WHO_AM_I 0x12 at 0x68"):
        src.open()


def test_an_absent_chip_is_a_clear_error() -> None:
    src, _ = make(EmulatedMpu9250(present=False))
    with pytest.raises(SensorError, match=r"no MPU-9250 answers at I2C address 0x68.*Remote I/O"):
        src.open()


def test_a_wrong_ak8963_is_a_clear_error() -> None:
    src, _ = make(EmulatedMpu9250(ak_wia=0x00))
    with pytest.raises(SensorError, match=r"AK8963 WIA 0x00, expected 0x48"):
        src.open()


def test_a_missing_i2c_device_file_is_a_clear_error() -> None:
    src = Mpu9250Source("/dev/i2c-99")
    with pytest.raises(SensorError, match=r"cannot open I2C bus /dev/i2c-99"):
        src.open()


def test_poll_before_open_is_an_error() -> None:
    src, _ = make(EmulatedMpu9250())
    with pytest.raises(SensorError, match="before open"):
        src.poll()


def test_hofl_overflow_is_a_flagged_sample_and_the_source_keeps_going() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    src, _ = make(chip)
    with src:
        chip.force_hofl = True
        flagged = by_type(src.poll(0.1), MagSample)[0]
        chip.force_hofl = False
        after = by_type(src.poll(0.1), MagSample)[0]
    assert flagged.flags & SampleFlag.OVERFLOW and not flagged.valid
    assert after.valid
    assert src.stats.flagged == 1


def test_a_field_beyond_the_range_sets_hofl_in_the_chip_and_is_flagged() -> None:
    chip = EmulatedMpu9250(field_body_nt=(3_000_000.0, 2_000_000.0, 1_000_000.0))
    src, _ = make(chip)
    with src:
        mag = by_type(src.poll(0.1), MagSample)[0]
    assert mag.flags & SampleFlag.OVERFLOW


def test_intermittent_read_errors_are_counted_and_skipped() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    src, _ = make(chip)
    with src:
        assert by_type(src.poll(0.1), ImuSample)
        chip.fail_next(1, address=0x68)
        during = src.poll(0.1)
        chip.fail_next(1, address=0x0C)
        during_mag = src.poll(0.1)
        after = src.poll(0.1)
    assert not by_type(during, ImuSample) and by_type(during, MagSample)
    assert by_type(during_mag, ImuSample) and not by_type(during_mag, MagSample)
    assert by_type(after, ImuSample) and by_type(after, MagSample)
    assert src.stats.read_errors == 2
    assert "Remote I/O error" in (src.stats.last_error or "")


def test_identical_readings_are_flagged_stuck_but_noisy_ones_are_not() -> None:
    chip = EmulatedMpu9250()
    src, _ = make(chip, stuck_count=5, mag_checks=MagChecks(stuck_count=5), attitude=False)
    with src:
        samples = [s for _ in range(8) for s in src.poll(0.1)]
    mags = by_type(samples, MagSample)
    imus = by_type(samples, ImuSample)
    assert [bool(m.flags & SampleFlag.STUCK) for m in mags] == [False] * 4 + [True] * 4
    assert [bool(i.flags & SampleFlag.STUCK) for i in imus] == [False] * 4 + [True] * 4

    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    src, _ = make(chip, stuck_count=5, mag_checks=MagChecks(stuck_count=5))
    with src:
        samples = [s for _ in range(20) for s in src.poll(0.1)]
    assert all(s.valid for s in samples)


def test_hard_and_soft_iron_calibration_is_applied_in_the_body_frame() -> None:
    field = (20000.0, 5000.0, -50000.0)
    offset = (1500.0, -700.0, 300.0)
    chip = EmulatedMpu9250(field_body_nt=tuple(f + o for f, o in zip(field, offset)))
    soft = ((1.1, 0.0, 0.0), (0.0, 0.9, 0.0), (0.0, 0.0, 1.0))
    src, _ = make(chip, calibration=MagCalibration(offset_nt=offset, soft_iron=soft))
    with src:
        mag = by_type(src.poll(0.1), MagSample)[0]
    want = (field[0] * 1.1, field[1] * 0.9, field[2])
    for got, w in zip(mag.mag_body_nt, want):
        assert got == pytest.approx(w, abs=200.0)


def test_a_different_mounting_is_honoured() -> None:
    # Board rotated 90 degrees in yaw (chip X to the right), still face up.
    body_from_chip = ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0))
    field = (21000.0, 4500.0, -52000.0)
    chip = EmulatedMpu9250(field_body_nt=field, gyro_body_radps=(0.1, -0.2, 0.3),
                           body_from_chip=body_from_chip)
    src, _ = make(chip, mounting=body_from_chip)
    with src:
        samples = src.poll(0.1)
    mag = by_type(samples, MagSample)[0]
    imu = by_type(samples, ImuSample)[0]
    assert mag.mag_body_nt == pytest.approx(field, abs=200.0)
    assert imu.gyro_body_radps == pytest.approx((0.1, -0.2, 0.3), abs=1e-3)
    assert imu.accel_body_mps2 == pytest.approx((0.0, 0.0, -GRAVITY_MPS2), abs=2e-3)


def test_a_mounting_that_is_not_a_rotation_is_rejected() -> None:
    with pytest.raises(ValueError, match="mounting must be a proper rotation"):
        Mpu9250Config(mounting=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0)))
    with pytest.raises(ValueError, match="gyro_range_dps"):
        Mpu9250Config(gyro_range_dps=300)


@pytest.mark.parametrize("declination_deg", [None, 12.4])
def test_attitude_from_a_tilted_chip(declination_deg: float | None) -> None:
    roll, pitch, yaw = math.radians(8.0), math.radians(-12.0), math.radians(250.0)
    field_ned = (23140.0, 5084.0, -53127.0)  # Canberra, WMM2015: D = +12.39 deg
    decl = math.atan2(field_ned[1], field_ned[0])
    chip = EmulatedMpu9250(field_body_nt=ned_to_body(field_ned, roll, pitch, yaw),
                           accel_body_mps2=specific_force(roll, pitch))
    chip.noise_lsb = 1
    src, _ = make(chip, declination_rad=None if declination_deg is None else math.radians(declination_deg))
    with src:
        atts = [s for _ in range(50) for s in src.poll(0.1) if isinstance(s, AttitudeSample)]
    last = atts[-1]
    assert math.degrees(last.roll_rad) == pytest.approx(8.0, abs=0.2)
    assert math.degrees(last.pitch_rad) == pytest.approx(-12.0, abs=0.2)
    if declination_deg is None:
        assert last.yaw_reference == "magnetic"
        want = math.degrees(yaw - decl)
    else:
        assert last.yaw_reference == "true"
        want = 250.0 + declination_deg - math.degrees(decl)
    assert math.degrees(last.yaw_rad) == pytest.approx(want, abs=0.5)


def test_poll_paces_reads_at_the_sample_rate() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    src, t = make(chip, sample_rate_hz=50.0)
    with src:
        first = src.poll(0.0)
        assert first  # due immediately
        assert src.poll(0.0) == []  # the next one is 20 ms away
        second = src.poll(0.1)
    assert second[0].time_s - first[0].time_s == pytest.approx(0.02)


def test_magnetometer_read_only_when_it_has_new_data() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    chip.mag_ready_every = 10  # a 10 Hz magnetometer polled at 100 Hz
    src, _ = make(chip)
    with src:
        samples = [s for _ in range(100) for s in src.poll(0.1)]
    assert len(by_type(samples, ImuSample)) == 100
    assert len(by_type(samples, MagSample)) == 10
    assert len(by_type(samples, AttitudeSample)) == 100
    assert src.stats.read_errors == 0

"""InvenSense MPU-9250 (accelerometer, gyroscope) and its AK8963 magnetometer over I2C.

Register facts used here (MPU-9250 Register Map RM-MPU-9250A-00 rev 1.6, AK8963
datasheet MS1356-E-02):

* MPU-9250 at 0x68 (0x69 with AD0 high); WHO_AM_I (0x75) reads 0x71, 0x73 on the
  MPU-9255. 0x70 is an MPU-6500, which has no magnetometer.
* ACCEL_XOUT_H (0x3B): 14 bytes, big-endian int16: ax, ay, az, temperature, gx, gy, gz.
  Temperature degC = raw / 333.87 + 21. Accelerometer 16384 LSB/g at +-2 g (halving
  with each range step); gyro 131, 65.5, 32.8, 16.4 LSB/(deg/s) at 250..2000 deg/s.
* The AK8963 sits behind the MPU's auxiliary bus; INT_PIN_CFG (0x37) bit BYPASS_EN (0x02)
  with the I2C master off connects it to the host bus at 0x0C. WIA (0x00) reads 0x48.
  ST1 (0x02) bit 0 DRDY; HXL..HZH (0x03-0x08) little-endian int16; ST2 (0x09) bit 3 HOFL
  (magnetic overflow) -- reading ST2 ends the measurement cycle. CNTL1 (0x0A) = 0x16 is
  16-bit output (0.15 uT/LSB) in continuous mode 2 (100 Hz); 0x0F is fuse-ROM access,
  where ASAX..ASAZ (0x10-0x12) give the factory sensitivity adjustment
  ``adj = (ASA - 128) * 0.5 / 128 + 1``.
* The AK8963 axes are not the MPU's: mag x = accel y, mag y = accel x, mag z = -accel z.

Mounting (an assumption, change it with ``Mpu9250Config.mounting``): the board lies flat,
component side up, with the MPU's X axis (the pin-1 mark's axis in the datasheet) pointing
forward. The chip frame is right-handed with Z up, so its Y points left; the default
``mat_body_chip`` is therefore diag(1, -1, -1), a 180 degree roll. Every vector (accel,
gyro, mag) is first put in the MPU chip frame, then rotated by ``mat_body_chip``.

Calibration: hard-iron offsets and the soft-iron matrix are applied in the body frame,
``m = soft_iron @ (m_body - offset_nt)`` (:class:`MagCalibration`).

The MPU-9250 has no clock the host can read, so samples are stamped with the host's
monotonic clock when the read completes (injectable ``clock`` for tests).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from companion.io.sensors.attitude import MahonyFilter, MahonyGains, Matrix3
from companion.nav.magnetometer import MagCalibration
from companion.io.sensors.base import (
    AttitudeSample,
    ImuSample,
    MagSample,
    Sample,
    SampleFlag,
    SampleKind,
    SensorError,
    SensorSource,
    Vector3,
)
from companion.io.sensors.quality import MagChecks, MagQualityCheck, RepeatDetector

__all__ = [
    "AK8963_ADDRESS",
    "MPU9250_ADDRESS",
    "MagCalibration",
    "Mpu9250Config",
    "Mpu9250Source",
    "SMBusLike",
]

MPU9250_ADDRESS = 0x68
AK8963_ADDRESS = 0x0C

# MPU-9250 registers
SMPLRT_DIV = 0x19
CONFIG = 0x1A
GYRO_CONFIG = 0x1B
ACCEL_CONFIG = 0x1C
ACCEL_CONFIG2 = 0x1D
INT_PIN_CFG = 0x37
ACCEL_XOUT_H = 0x3B
USER_CTRL = 0x6A
PWR_MGMT_1 = 0x6B
PWR_MGMT_2 = 0x6C
WHO_AM_I = 0x75
# AK8963 registers
AK_WIA = 0x00
AK_ST1 = 0x02
AK_HXL = 0x03
AK_CNTL1 = 0x0A
AK_CNTL2 = 0x0B
AK_ASAX = 0x10

MPU_IDS = {0x71: "MPU-9250", 0x73: "MPU-9255"}
AK8963_WIA = 0x48
BYPASS_EN = 0x02
ST1_DRDY = 0x01
ST1_DOR = 0x02
ST2_HOFL = 0x08
CNTL1_POWER_DOWN = 0x00
CNTL1_FUSE_ROM = 0x0F
CNTL1_16BIT = 0x10
CNTL1_CONT_8HZ = 0x02
CNTL1_CONT_100HZ = 0x06
MAG_NT_PER_LSB_16BIT = 150.0  # 0.15 uT/LSB
MAG_RAW_LIMIT = 32760  # the AK8963's documented 16-bit output range
TEMP_LSB_PER_C = 333.87
TEMP_OFFSET_C = 21.0
GRAVITY_MPS2 = 9.80665

GYRO_RANGES_DPS = {250: 0, 500: 1, 1000: 2, 2000: 3}
# Datasheet sensitivities (LSB per deg/s); note 16.4, not 32768 / 2000 = 16.384.
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
ACCEL_RANGES_G = {2: 0, 4: 1, 8: 2, 16: 3}
# Gyro/temperature DLPF bandwidth (Hz) -> DLPF_CFG, all with a 1 kHz internal rate.
GYRO_DLPF_HZ = {184: 1, 92: 2, 41: 3, 20: 4, 10: 5, 5: 6}
# Accelerometer DLPF bandwidth (Hz) -> A_DLPF_CFG with ACCEL_FCHOICE_B = 0.
ACCEL_DLPF_HZ = {218: 1, 99: 2, 45: 3, 21: 4, 10: 5, 5: 6}

DEFAULT_MOUNTING: Matrix3 = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))


class SMBusLike(Protocol):
    """The part of ``smbus2.SMBus`` the driver uses (tests pass an emulated chip)."""

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...

    def close(self) -> None: ...


def _check_rotation(mat: Matrix3, what: str) -> Matrix3:
    rows = tuple(tuple(float(c) for c in row) for row in mat)
    if len(rows) != 3 or any(len(r) != 3 for r in rows):
        raise ValueError(f"{what} must be a 3x3 matrix, got {mat!r}")
    for i in range(3):
        for j in range(3):
            dot = sum(rows[i][k] * rows[j][k] for k in range(3))
            if abs(dot - (1.0 if i == j else 0.0)) > 1e-6:
                raise ValueError(f"{what} must be orthonormal, got {mat!r}")
    det = (rows[0][0] * (rows[1][1] * rows[2][2] - rows[1][2] * rows[2][1])
           - rows[0][1] * (rows[1][0] * rows[2][2] - rows[1][2] * rows[2][0])
           + rows[0][2] * (rows[1][0] * rows[2][1] - rows[1][1] * rows[2][0]))
    if det < 0.0:
        raise ValueError(f"{what} must be a proper rotation (det +1), got det {det:+.3f}")
    return rows  # type: ignore[return-value]


def _apply(mat: Matrix3, vec: Vector3) -> Vector3:
    return (
        mat[0][0] * vec[0] + mat[0][1] * vec[1] + mat[0][2] * vec[2],
        mat[1][0] * vec[0] + mat[1][1] * vec[1] + mat[1][2] * vec[2],
        mat[2][0] * vec[0] + mat[2][1] * vec[1] + mat[2][2] * vec[2],
    )


@dataclass(frozen=True)
class Mpu9250Config:
    """Settings of :class:`Mpu9250Source`; values are validated here, at the edge.

    ``gyro_range_dps`` 250/500/1000/2000; ``accel_range_g`` 2/4/8/16; ``dlpf_hz``: gyro
    low-pass bandwidth 184/92/41/20/10/5 (the accelerometer gets the nearest of
    218/99/45/21/10/5); ``sample_rate_hz``: output rate, 1000 / (1 + SMPLRT_DIV), 4..1000
    (the driver reads at this rate); ``mag_rate_hz``: 8 or 100 (AK8963 continuous mode
    1 or 2); ``mounting``: ``mat_body_chip`` (see the module docstring);
    ``declination_rad``: given to the attitude filter so its yaw is true, None for a
    magnetic yaw; ``stuck_count``: identical IMU readings that mean a frozen sensor.
    """

    address: int = MPU9250_ADDRESS
    gyro_range_dps: int = 500
    accel_range_g: int = 4
    dlpf_hz: int = 41
    sample_rate_hz: float = 100.0
    mag_rate_hz: int = 100
    mounting: Matrix3 = DEFAULT_MOUNTING
    calibration: MagCalibration = field(default_factory=MagCalibration)
    mag_checks: MagChecks = field(default_factory=MagChecks)
    filter_gains: MahonyGains = field(default_factory=MahonyGains)
    declination_rad: float | None = None
    attitude: bool = True
    stuck_count: int = 10

    def __post_init__(self) -> None:
        if self.address not in (0x68, 0x69):
            raise ValueError(f"Mpu9250Config.address must be 0x68 or 0x69, got {self.address:#x}")
        if self.gyro_range_dps not in GYRO_RANGES_DPS:
            raise ValueError(f"Mpu9250Config.gyro_range_dps must be one of {sorted(GYRO_RANGES_DPS)}, "
                             f"got {self.gyro_range_dps}")
        if self.accel_range_g not in ACCEL_RANGES_G:
            raise ValueError(f"Mpu9250Config.accel_range_g must be one of {sorted(ACCEL_RANGES_G)}, "
                             f"got {self.accel_range_g}")
        if self.dlpf_hz not in GYRO_DLPF_HZ:
            raise ValueError(f"Mpu9250Config.dlpf_hz must be one of {sorted(GYRO_DLPF_HZ)}, got {self.dlpf_hz}")
        if not 4.0 <= self.sample_rate_hz <= 1000.0:
            raise ValueError(f"Mpu9250Config.sample_rate_hz must be in [4, 1000] Hz, got {self.sample_rate_hz}")
        if self.mag_rate_hz not in (8, 100):
            raise ValueError(f"Mpu9250Config.mag_rate_hz must be 8 or 100, got {self.mag_rate_hz}")
        if self.stuck_count < 2:
            raise ValueError(f"Mpu9250Config.stuck_count must be >= 2, got {self.stuck_count}")
        object.__setattr__(self, "mounting", _check_rotation(self.mounting, "Mpu9250Config.mounting"))

    @property
    def smplrt_div(self) -> int:
        return max(0, min(255, round(1000.0 / self.sample_rate_hz) - 1))

    @property
    def accel_dlpf_cfg(self) -> int:
        nearest = min(ACCEL_DLPF_HZ, key=lambda hz: abs(hz - self.dlpf_hz))
        return ACCEL_DLPF_HZ[nearest]


def _int16_be(hi: int, lo: int) -> int:
    v = (hi << 8) | lo
    return v - 0x10000 if v & 0x8000 else v


def _int16_le(lo: int, hi: int) -> int:
    return _int16_be(hi, lo)


class Mpu9250Source(SensorSource):
    """MPU-9250 + AK8963 read over I2C: IMU, magnetometer and filtered attitude samples.

    ``bus`` is an open ``smbus2.SMBus`` (or anything with its methods), a bus number, or
    a device path such as ``/dev/i2c-1``. ``poll`` reads at ``sample_rate_hz``: one
    14-byte burst for accel/temperature/gyro, then the AK8963 when it has new data. An
    I2C error during ``poll`` is counted in ``stats`` and that reading is skipped.
    """

    provides = frozenset({SampleKind.MAG, SampleKind.ATTITUDE})

    def __init__(
        self,
        bus: SMBusLike | int | str = "/dev/i2c-1",
        config: Mpu9250Config | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        name: str | None = None,
    ) -> None:
        super().__init__()
        self.config = config or Mpu9250Config()
        self._bus_arg = bus
        self._bus: SMBusLike | None = None
        self._owns_bus = False
        self._clock = clock
        self._sleep = sleep
        self.name = name or f"mpu9250@{bus if isinstance(bus, (int, str)) else 'bus'}"
        self.chip = ""
        self.asa: Vector3 = (1.0, 1.0, 1.0)
        self._accel_lsb_per_mps2 = 32768.0 / (self.config.accel_range_g * GRAVITY_MPS2)
        self._gyro_lsb_per_radps = GYRO_LSB_PER_DPS[self.config.gyro_range_dps] / math.radians(1.0)
        self._next_read_s = -math.inf
        self._mag_check = MagQualityCheck(self.config.mag_checks)
        self._imu_repeat = RepeatDetector(self.config.stuck_count)
        self._filter = MahonyFilter(self.config.filter_gains, self.config.declination_rad)

    # -- opening -------------------------------------------------------------------------

    def _open_bus(self) -> SMBusLike:
        bus = self._bus_arg
        if not isinstance(bus, (int, str)):
            return bus
        number = bus
        if isinstance(bus, str):
            digits = bus.rsplit("-", 1)[-1] if bus.startswith("/dev/i2c-") else bus
            if not digits.isdigit():
                raise SensorError(f"{self.name}: I2C bus must be a number or /dev/i2c-N, got {bus!r}")
            number = int(digits)
        from smbus2 import SMBus  # only needed on a real board

        try:
            smbus = SMBus(number)
        except OSError as err:
            raise SensorError(f"{self.name}: cannot open I2C bus /dev/i2c-{number}: {err} "
                              "(is I2C enabled and the user in group i2c?)") from err
        self._owns_bus = True
        return smbus

    def _write(self, address: int, register: int, value: int) -> None:
        self._bus.write_byte_data(address, register, value)  # type: ignore[union-attr]

    def _read(self, address: int, register: int) -> int:
        return self._bus.read_byte_data(address, register)  # type: ignore[union-attr]

    def open(self) -> None:
        self._bus = self._open_bus()
        cfg = self.config
        try:
            try:
                who = self._read(cfg.address, WHO_AM_I)
            except OSError as err:
                raise SensorError(
                    f"{self.name}: no MPU-9250 answers at I2C address {cfg.address:#04x} ({err}); "
                    "check wiring, power and AD0 (0x68 low, 0x69 high)") from err
            if who not in MPU_IDS:
                hint = " (an MPU-6500: it has no magnetometer)" if who == 0x70 else ""
                raise SensorError(
                    f"{self.name}: unexpected WHO_AM_I {who:#04x} at {cfg.address:#04x}{hint}; "
                    "expected 0x71 (MPU-9250) or 0x73 (MPU-9255)")
            self.chip = MPU_IDS[who]
            try:
                self._configure_mpu()
                self._configure_ak8963()
            except OSError as err:
                raise SensorError(f"{self.name}: I2C error while configuring the {self.chip}: {err}") from err
        except BaseException:
            self.close()
            raise
        self._next_read_s = -math.inf
        self._filter.reset()

    def _configure_mpu(self) -> None:
        cfg = self.config
        a = cfg.address
        self._write(a, PWR_MGMT_1, 0x80)  # device reset
        self._sleep(0.1)
        self._write(a, PWR_MGMT_1, 0x01)  # best clock source (gyro PLL)
        self._write(a, PWR_MGMT_2, 0x00)  # all axes on
        self._write(a, CONFIG, GYRO_DLPF_HZ[cfg.dlpf_hz])
        self._write(a, SMPLRT_DIV, cfg.smplrt_div)
        self._write(a, GYRO_CONFIG, GYRO_RANGES_DPS[cfg.gyro_range_dps] << 3)
        self._write(a, ACCEL_CONFIG, ACCEL_RANGES_G[cfg.accel_range_g] << 3)
        self._write(a, ACCEL_CONFIG2, cfg.accel_dlpf_cfg)
        self._write(a, USER_CTRL, 0x00)  # I2C master off, or bypass does not work
        self._write(a, INT_PIN_CFG, BYPASS_EN)
        self._sleep(0.01)

    def _configure_ak8963(self) -> None:
        try:
            wia = self._read(AK8963_ADDRESS, AK_WIA)
        except OSError as err:
            raise SensorError(
                f"{self.name}: the {self.chip}'s AK8963 magnetometer does not answer at 0x0c "
                f"after enabling bypass ({err})") from err
        if wia != AK8963_WIA:
            raise SensorError(f"{self.name}: unexpected AK8963 WIA {wia:#04x}, expected 0x48")
        self._write(AK8963_ADDRESS, AK_CNTL2, 0x01)  # soft reset
        self._sleep(0.01)
        self._write(AK8963_ADDRESS, AK_CNTL1, CNTL1_POWER_DOWN)
        self._sleep(0.01)
        self._write(AK8963_ADDRESS, AK_CNTL1, CNTL1_FUSE_ROM)
        self._sleep(0.01)
        asa = self._bus.read_i2c_block_data(AK8963_ADDRESS, AK_ASAX, 3)  # type: ignore[union-attr]
        self.asa = tuple((v - 128) * 0.5 / 128.0 + 1.0 for v in asa)  # type: ignore[assignment]
        # The datasheet asks for power-down between any two modes.
        self._write(AK8963_ADDRESS, AK_CNTL1, CNTL1_POWER_DOWN)
        self._sleep(0.01)
        mode = CNTL1_CONT_100HZ if self.config.mag_rate_hz == 100 else CNTL1_CONT_8HZ
        self._write(AK8963_ADDRESS, AK_CNTL1, CNTL1_16BIT | mode)
        self._sleep(0.01)

    def close(self) -> None:
        if self._bus is not None and self._owns_bus:
            try:
                self._bus.close()
            except OSError:
                pass  # closing a bus that vanished leaves nothing to release
        self._bus = None
        self._owns_bus = False

    # -- reading -------------------------------------------------------------------------

    def _chip_to_body(self, vec_chip: Vector3) -> Vector3:
        return _apply(self.config.mounting, vec_chip)

    def _read_imu(self, now_s: float) -> ImuSample | None:
        try:
            raw = self._bus.read_i2c_block_data(self.config.address, ACCEL_XOUT_H, 14)  # type: ignore[union-attr]
        except OSError as err:
            self.stats.record_error(f"IMU burst read: {err}")
            return None
        if len(raw) != 14:
            self.stats.record_error(f"IMU burst read returned {len(raw)} of 14 bytes")
            return None
        v = [_int16_be(raw[i], raw[i + 1]) for i in range(0, 14, 2)]
        flags = self._imu_repeat.check(tuple(v))
        accel_chip = (v[0] / self._accel_lsb_per_mps2, v[1] / self._accel_lsb_per_mps2,
                      v[2] / self._accel_lsb_per_mps2)
        gyro_chip = (v[4] / self._gyro_lsb_per_radps, v[5] / self._gyro_lsb_per_radps,
                     v[6] / self._gyro_lsb_per_radps)
        if any(abs(c) >= 32767 for c in (v[0], v[1], v[2], v[4], v[5], v[6])):
            flags |= SampleFlag.OVERFLOW  # saturated: beyond the configured full scale
        # The accelerometer measures the reaction to gravity, +g along chip Z when the
        # chip lies face up; rotated into the body frame this is ArduPilot's (0, 0, -g).
        return ImuSample(
            time_s=now_s,
            accel_body_mps2=self._chip_to_body(accel_chip),
            gyro_body_radps=self._chip_to_body(gyro_chip),
            temperature_c=v[3] / TEMP_LSB_PER_C + TEMP_OFFSET_C,
            flags=flags,
        )

    def _read_mag(self, now_s: float) -> MagSample | None:
        try:
            st1 = self._read(AK8963_ADDRESS, AK_ST1)
            if not st1 & ST1_DRDY:
                return None
            raw = self._bus.read_i2c_block_data(AK8963_ADDRESS, AK_HXL, 7)  # type: ignore[union-attr]
        except OSError as err:
            self.stats.record_error(f"AK8963 read: {err}")
            return None
        if len(raw) != 7:
            self.stats.record_error(f"AK8963 read returned {len(raw)} of 7 bytes")
            return None
        if st1 & ST1_DOR:
            self.stats.dropped += 1  # the chip overwrote a reading we never fetched
        hx, hy, hz = (_int16_le(raw[i], raw[i + 1]) for i in range(0, 6, 2))
        st2 = raw[6]
        ax, ay, az = self.asa
        # AK8963 axes in the MPU chip frame: x_mpu = y_ak, y_mpu = x_ak, z_mpu = -z_ak.
        ak = (hx * ax * MAG_NT_PER_LSB_16BIT, hy * ay * MAG_NT_PER_LSB_16BIT,
              hz * az * MAG_NT_PER_LSB_16BIT)
        mag_chip = (ak[1], ak[0], -ak[2])
        mag_body = self.config.calibration.apply(self._chip_to_body(mag_chip))
        flags = SampleFlag.NONE
        if st2 & ST2_HOFL or any(abs(c) > MAG_RAW_LIMIT for c in (hx, hy, hz)):
            flags |= SampleFlag.OVERFLOW
        flags |= self._mag_check.check((hx, hy, hz), mag_body)
        return MagSample(time_s=now_s, mag_body_nt=mag_body, flags=flags)

    def read_once(self) -> list[Sample]:
        """One read cycle now, without pacing: IMU, then mag if ready, then attitude."""
        if self._bus is None:
            raise SensorError(f"{self.name}: poll() before open()")
        now = self._clock()
        out: list[Sample] = []
        imu = self._read_imu(now)
        mag = self._read_mag(now)
        if imu is not None:
            out.append(imu)
        if mag is not None:
            out.append(mag)
        if self.config.attitude and imu is not None and imu.valid:
            roll, pitch, yaw = self._filter.update(
                now, imu.accel_body_mps2, imu.gyro_body_radps,
                mag.mag_body_nt if mag is not None and mag.valid else None)
            out.append(AttitudeSample(now, roll, pitch, yaw, yaw_reference=self._filter.yaw_reference))
        self.stats.count(out)
        return out

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        """Read when the next sample period is due, waiting up to ``timeout_s`` for it."""
        if self._bus is None:
            raise SensorError(f"{self.name}: poll() before open()")
        now = self._clock()
        wait = self._next_read_s - now
        if wait > 0.0:
            if wait > timeout_s:
                if timeout_s > 0.0:
                    self._sleep(timeout_s)
                return []
            self._sleep(wait)
            now = self._clock()
        period = 1.0 / self.config.sample_rate_hz
        # Keep a steady cadence; after a stall of more than a period restart it from now
        # rather than reading back-to-back to catch up (the chip keeps only the latest).
        late = now - self._next_read_s
        self._next_read_s = self._next_read_s + period if late < period else now + period
        return self.read_once()

"""A register-level MPU-9250 + AK8963 behind the ``smbus2.SMBus`` method signatures.

The emulated chip holds a physical state in SI units (body-frame field, specific force,
rate, temperature) and encodes it into registers the way the silicon does: chip axes via
the board mounting, big-endian accel/gyro with the configured full scale, little-endian
AK8963 output in its own axes with the factory sensitivity (ASA) folded in, overflow in
ST2. It is written from the datasheets independently of the driver, so decoding it back
is a real check of the driver.

Behaviour that matters for a driver: registers reset on PWR_MGMT_1 bit 7; the AK8963
answers only while INT_PIN_CFG BYPASS_EN is set and the I2C master is off; ASA reads
return the fuse ROM only in fuse-ROM mode; reading ST2 ends a measurement (DRDY clears
until ``mag_ready_every`` later ST1 reads, which stand in for the passing of time).
"""
from __future__ import annotations

import errno
import math

GRAVITY_MPS2 = 9.80665
MPU_ADDR = 0x68
AK_ADDR = 0x0C
# Chip frame (X forward, Y left, Z up) -> body frame (x forward, y right, z down).
BODY_FROM_CHIP = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))


def _nack() -> OSError:
    return OSError(errno.EREMOTEIO, "Remote I/O error")


def _clip16(value: float) -> int:
    return max(-32768, min(32767, int(round(value))))


def _be(value: int) -> list[int]:
    value &= 0xFFFF
    return [value >> 8, value & 0xFF]


def _le(value: int) -> list[int]:
    value &= 0xFFFF
    return [value & 0xFF, value >> 8]


class EmulatedMpu9250:
    """An MPU-9250 (or lookalike) and its AK8963 on one emulated I2C bus."""

    def __init__(
        self,
        *,
        field_body_nt: tuple[float, float, float] = (21000.0, 4500.0, -52000.0),
        accel_body_mps2: tuple[float, float, float] = (0.0, 0.0, -GRAVITY_MPS2),
        gyro_body_radps: tuple[float, float, float] = (0.0, 0.0, 0.0),
        temperature_c: float = 31.5,
        asa: tuple[int, int, int] = (176, 177, 165),
        who_am_i: int = 0x71,
        ak_wia: int = 0x48,
        body_from_chip: tuple = BODY_FROM_CHIP,
        present: bool = True,
    ) -> None:
        self.field_body_nt = field_body_nt
        self.accel_body_mps2 = accel_body_mps2
        self.gyro_body_radps = gyro_body_radps
        self.temperature_c = temperature_c
        self.asa = asa
        self.who_am_i = who_am_i
        self.ak_wia = ak_wia
        self.body_from_chip = body_from_chip
        self.present = present
        self.force_hofl = False
        # LSBs added to ax and hx on every other reading, so that readings are not all
        # identical (a real sensor's noise) and the driver's stuck detection stays quiet.
        self.noise_lsb = 0
        self._bursts = 0  # IMU burst reads so far
        self.mag_ready_every = 1  # driver cycles per magnetometer measurement
        self._st1_waits = 0
        self.closed = False
        self.writes: list[tuple[int, int, int]] = []
        self._fail: list[tuple[int | None, int]] = []  # (address or None, count)
        self._cycles = 0  # completed magnetometer read cycles (ST2 reads)
        self._reset_mpu()
        self.ak_cntl1 = 0x00
        self.drdy = False

    # -- error injection ---------------------------------------------------------------

    def fail_next(self, count: int = 1, address: int | None = None) -> None:
        """The next ``count`` transactions (to ``address``, or any) fail with a NACK."""
        self._fail.append((address, count))

    def _maybe_fail(self, address: int) -> None:
        if not self.present and address in (MPU_ADDR, AK_ADDR):
            raise _nack()
        for i, (addr, count) in enumerate(self._fail):
            if addr is None or addr == address:
                if count <= 1:
                    self._fail.pop(i)
                else:
                    self._fail[i] = (addr, count - 1)
                raise _nack()

    # -- register model ----------------------------------------------------------------

    def _reset_mpu(self) -> None:
        self.mpu = bytearray(128)
        self.mpu[0x6B] = 0x01  # PWR_MGMT_1 reset value
        self.mpu[0x75] = self.who_am_i

    def _to_chip(self, vec_body: tuple[float, float, float]) -> tuple[float, float, float]:
        r = self.body_from_chip  # chip = R^T body
        return tuple(sum(r[k][i] * vec_body[k] for k in range(3)) for i in range(3))  # type: ignore[return-value]

    def _imu_bytes(self) -> list[int]:
        accel_lsb_per_g = 16384.0 / (1 << ((self.mpu[0x1C] >> 3) & 3))
        # Datasheet sensitivities (LSB per deg/s), not 32768 / full scale.
        gyro_lsb_per_dps = (131.0, 65.5, 32.8, 16.4)[(self.mpu[0x1B] >> 3) & 3]
        a = self._to_chip(self.accel_body_mps2)
        g = self._to_chip(self.gyro_body_radps)
        out: list[int] = []
        noise = [self.noise_lsb * (self._bursts % 2), 0, 0]
        for c, n in zip(a, noise):
            out += _be(_clip16(c / GRAVITY_MPS2 * accel_lsb_per_g + n))
        out += _be(_clip16((self.temperature_c - 21.0) * 333.87))
        for c in g:
            out += _be(_clip16(math.degrees(c) * gyro_lsb_per_dps))
        return out

    def _ak_data(self) -> tuple[list[int], int]:
        """HXL..HZH bytes and ST2 for the current field."""
        bit16 = bool(self.ak_cntl1 & 0x10)
        nt_per_lsb = 150.0 if bit16 else 600.0
        limit = 32760 if bit16 else 8190
        m = self._to_chip(self.field_body_nt)
        ak = (m[1], m[0], -m[2])  # AK8963 axes: x = MPU y, y = MPU x, z = -MPU z
        raw = []
        for c, a in zip(ak, self.asa):
            sensitivity = (a - 128) * 0.5 / 128.0 + 1.0
            raw.append(max(-limit, min(limit, int(round(c / nt_per_lsb / sensitivity)))))
        raw[0] += self.noise_lsb * (self._cycles % 2)
        overflow = self.force_hofl or sum(abs(c) for c in ak) > 4912e3
        st2 = (0x10 if bit16 else 0x00) | (0x08 if overflow else 0x00)
        data: list[int] = []
        for r in raw:
            data += _le(r)
        return data, st2

    def _mpu_read(self, register: int) -> int:
        if 0x3B <= register < 0x3B + 14:
            return self._imu_bytes()[register - 0x3B]
        if register == 0x75:
            return self.who_am_i
        return self.mpu[register] if register < len(self.mpu) else 0

    def _ak_visible(self) -> bool:
        return bool(self.mpu[0x37] & 0x02) and not self.mpu[0x6A] & 0x20

    def _ak_read(self, register: int, data: tuple[list[int], int]) -> int:
        mode = self.ak_cntl1 & 0x0F
        if register == 0x00:
            return self.ak_wia
        if register == 0x02:
            if mode not in (0x02, 0x06):
                return 0x00
            if not self.drdy:
                # Each ST1 read stands in for the passing of one driver cycle: after
                # mag_ready_every of them the next measurement is ready.
                self._st1_waits += 1
                if self._st1_waits >= self.mag_ready_every:
                    self.drdy = True
            return 0x01 if self.drdy else 0x00
        if 0x03 <= register <= 0x08:
            return data[0][register - 0x03] if mode in (0x02, 0x06) else 0
        if register == 0x09:
            self.drdy = False  # reading ST2 ends the measurement cycle
            self._cycles += 1
            self._st1_waits = 0
            return data[1]
        if register == 0x0A:
            return self.ak_cntl1
        if 0x10 <= register <= 0x12:
            return self.asa[register - 0x10] if mode == 0x0F else 0
        return 0

    # -- smbus2.SMBus surface ----------------------------------------------------------

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        return self.read_i2c_block_data(i2c_addr, register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        self._maybe_fail(i2c_addr)
        self.writes.append((i2c_addr, register, value))
        if i2c_addr == MPU_ADDR:
            if register == 0x6B and value & 0x80:
                self._reset_mpu()
                return
            self.mpu[register] = value & 0xFF
        elif i2c_addr == AK_ADDR and self._ak_visible():
            if register == 0x0A:
                self.ak_cntl1 = value & 0x1F
                self.drdy = (value & 0x0F) in (0x02, 0x06)
            elif register == 0x0B and value & 0x01:
                self.ak_cntl1 = 0x00
                self.drdy = False
        else:
            raise _nack()

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        self._maybe_fail(i2c_addr)
        if i2c_addr == MPU_ADDR:
            out = [self._mpu_read(register + i) for i in range(length)]
            if register == 0x3B:
                self._bursts += 1
            return out
        if i2c_addr == AK_ADDR and self._ak_visible():
            data = self._ak_data()
            return [self._ak_read(register + i, data) for i in range(length)]
        raise _nack()

    def close(self) -> None:
        self.closed = True

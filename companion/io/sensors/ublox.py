"""u-blox GNSS receiver (MAX-M8Q and later) over a serial port: UBX NAV-PVT fixes.

The receiver's output is a mixed byte stream: UBX frames (``B5 62 class id len16
payload ck_a ck_b``), NMEA sentences (``$...*hh\\r\\n``) and, after a glitch, noise.
:class:`UbxStreamFramer` cuts that stream into frames without ever blocking on a partial
one, checks the UBX Fletcher checksum itself (so it can count bad frames) and hands good
frames to ``pyubx2.UBXReader.parse``. After a bad checksum it resynchronises on the next
``B5 62`` *after the bad frame's sync bytes*, not after its claimed length: a corrupted
length field then cannot swallow the good frames behind it.

Configuration on open sends both UBX-CFG-MSG (M8 and older) and UBX-CFG-VALSET
(M9 and later; an M8 answers it with ACK-NAK, harmless) to enable NAV-PVT on UART1 and USB.

``fix_type`` is mapped to MAVLink's numbers like ArduPilot does: without ``gnssFixOK``
(fix inside the receiver's DOP and accuracy masks) the fix counts as "no fix".
"""
from __future__ import annotations

import datetime as dt
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from pyubx2 import SET, UBXMessage, UBXReader
from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXTypeError

from companion.io.sensors.base import GpsSample, Sample, SampleKind, SensorError, SensorSource

__all__ = ["UbloxSource", "UbxStreamFramer", "configuration_messages", "gps_sample_from_nav_pvt"]

UBX_SYNC = b"\xb5\x62"
NMEA_START = 0x24  # '$'
MAX_UBX_PAYLOAD = 4096  # longer claimed lengths are corruption (NAV-PVT is 92 bytes)
MAX_NMEA_LENGTH = 120  # NMEA 0183 allows 82 characters; u-blox proprietary a little more
NAV_PVT_CLASS_ID = (0x01, 0x07)


def ubx_checksum(body: bytes) -> bytes:
    """8-bit Fletcher checksum over class, id, length and payload.

    >>> ubx_checksum(bytes([0x06, 0x01, 0x02, 0x00, 0x01, 0x07])).hex()  # poll CFG-MSG NAV-PVT
    '113a'
    """
    ck_a = ck_b = 0
    for byte in body:
        ck_a = (ck_a + byte) & 0xFF
        ck_b = (ck_b + ck_a) & 0xFF
    return bytes((ck_a, ck_b))


class UbxStreamFramer:
    """Incremental splitter of a UBX/NMEA byte stream into complete frames.

    ``feed(data)`` returns the good UBX frames completed by ``data`` (bytes, sync
    included); partial frames wait for the next feed. Counters: ``checksum_errors``,
    ``nmea_sentences``, ``garbage_bytes``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.checksum_errors = 0
        self.nmea_sentences = 0
        self.garbage_bytes = 0

    def _next_start(self) -> int:
        ubx = self._buf.find(UBX_SYNC)
        nmea = self._buf.find(b"$")
        candidates = [i for i in (ubx, nmea) if i >= 0]
        if not candidates:
            # Keep a trailing 0xB5: it may be the first half of a sync split across reads.
            return len(self._buf) - 1 if self._buf.endswith(b"\xb5") else len(self._buf)
        return min(candidates)

    def _discard(self, count: int) -> None:
        self.garbage_bytes += count
        del self._buf[:count]

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        frames: list[bytes] = []
        while self._buf:
            start = self._next_start()
            if start:
                self._discard(start)
            if len(self._buf) < 2:
                break
            if self._buf[0] == NMEA_START:
                end = self._nmea_end()
                if end is None:
                    break  # incomplete sentence
                if end > 0:
                    self.nmea_sentences += 1
                    del self._buf[:end]
                continue
            if len(self._buf) < 6:
                break
            length = self._buf[4] | (self._buf[5] << 8)
            if length > MAX_UBX_PAYLOAD:
                self._discard(2)  # not a real header: resync after these sync bytes
                continue
            total = 6 + length + 2
            if len(self._buf) < total:
                break
            frame = bytes(self._buf[:total])
            if ubx_checksum(frame[2:-2]) != frame[-2:]:
                self.checksum_errors += 1
                self._discard(2)
                continue
            frames.append(frame)
            del self._buf[:total]
        return frames

    def _nmea_end(self) -> int | None:
        """Length of the sentence at the buffer start, None if incomplete, 0 if broken.

        A broken sentence (non-printable byte before CR LF, or too long) loses only its
        '$', so a UBX frame that interrupted it is still found.
        """
        limit = min(len(self._buf), MAX_NMEA_LENGTH)
        for i in range(1, limit):
            c = self._buf[i]
            if c == 0x0A:
                return i + 1
            if c == 0x0D:
                continue
            if c < 0x20 or c > 0x7E:
                self._discard(1)
                return 0
        if len(self._buf) >= MAX_NMEA_LENGTH:
            self._discard(1)
            return 0
        return None


def _mavlink_fix_type(pvt: Any) -> int:
    fix_ok = bool(getattr(pvt, "gnssFixOk", 0))
    invalid_llh = bool(getattr(pvt, "invalidLlh", 0))  # flags3, protocol 27+
    if not fix_ok or invalid_llh:
        return 1
    fix = pvt.fixType
    if fix in (3, 4):  # 3D, GNSS + dead reckoning
        carr = getattr(pvt, "carrSoln", 0)
        if carr == 2:
            return 6
        if carr == 1:
            return 5
        return 4 if getattr(pvt, "diffSoln", 0) else 3
    if fix == 2:
        return 2
    return 1  # no fix, dead reckoning only, time only


def _utc_s(pvt: Any) -> float | None:
    if not (getattr(pvt, "validDate", 0) and getattr(pvt, "validTime", 0)):
        return None
    try:
        t = dt.datetime(pvt.year, pvt.month, pvt.day, pvt.hour, pvt.min, pvt.second,
                        tzinfo=dt.timezone.utc)
    except ValueError:
        return None
    return t.timestamp() + pvt.nano * 1e-9


def gps_sample_from_nav_pvt(pvt: Any, time_s: float) -> GpsSample:
    """A :class:`GpsSample` from a parsed NAV-PVT (pyubx2 scales lat/lon to degrees;
    heights, accuracies and velocities stay in mm and mm/s)."""
    return GpsSample(
        time_s=time_s,
        lat_deg=float(pvt.lat),
        lon_deg=float(pvt.lon),
        alt_m=pvt.height * 1e-3,
        fix_type=_mavlink_fix_type(pvt),
        h_acc_m=pvt.hAcc * 1e-3,
        v_acc_m=pvt.vAcc * 1e-3,
        vel_ned_mps=(pvt.velN * 1e-3, pvt.velE * 1e-3, pvt.velD * 1e-3),
        num_sv=int(pvt.numSV),
        alt_msl_m=pvt.hMSL * 1e-3,
        utc_s=_utc_s(pvt),
    )


def configuration_messages(nav_rate_hz: float | None = None) -> list[UBXMessage]:
    """Messages that make an M8 (CFG-MSG, CFG-RATE) or M9+ (CFG-VALSET) output NAV-PVT."""
    msgs = [
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x01, msgID=0x07,
                   rateDDC=0, rateUART1=1, rateUART2=0, rateUSB=1, rateSPI=0),
    ]
    cfg: list[tuple[str, int]] = [("CFG_MSGOUT_UBX_NAV_PVT_UART1", 1), ("CFG_MSGOUT_UBX_NAV_PVT_USB", 1)]
    if nav_rate_hz is not None:
        meas_ms = round(1000.0 / nav_rate_hz)
        msgs.append(UBXMessage("CFG", "CFG-RATE", SET, measRate=meas_ms, navRate=1, timeRef=1))
        cfg.append(("CFG_RATE_MEAS", meas_ms))
    msgs.append(UBXMessage.config_set(1, 0, cfg))  # layer RAM, no transaction
    return msgs


class SerialLike(Protocol):
    """The part of ``serial.Serial`` the source uses."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class UbloxConfig:
    """Settings of :class:`UbloxSource`.

    ``baudrate``: the M8Q's UART1 default is 9600 (a USB CDC port ignores it).
    ``configure``: send the NAV-PVT configuration on open. ``nav_rate_hz``: also set the
    navigation rate (None keeps the receiver's, 1 Hz by default).
    """

    port: str
    baudrate: int = 9600
    configure: bool = True
    nav_rate_hz: float | None = None

    def __post_init__(self) -> None:
        if self.baudrate <= 0:
            raise ValueError(f"UbloxConfig.baudrate must be > 0, got {self.baudrate}")
        if self.nav_rate_hz is not None and not 0.1 <= self.nav_rate_hz <= 25.0:
            raise ValueError(f"UbloxConfig.nav_rate_hz must be in [0.1, 25] Hz, got {self.nav_rate_hz}")


class UbloxSource(SensorSource):
    """NAV-PVT fixes from a u-blox receiver as :class:`GpsSample`.

    Samples are stamped with the host's monotonic clock when their last byte was read
    (see :mod:`companion.io.sensors.base`, Time); the receiver's UTC is in ``utc_s``.
    ``serial_port`` injects an already open port (tests); otherwise pyserial opens
    ``config.port``. Checksum errors go to ``stats.checksum_errors``.
    """

    provides = frozenset({SampleKind.GPS})

    def __init__(
        self,
        config: UbloxConfig | str,
        *,
        serial_port: SerialLike | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str | None = None,
    ) -> None:
        super().__init__()
        self.config = UbloxConfig(port=config) if isinstance(config, str) else config
        self._injected = serial_port
        self._serial: SerialLike | None = None
        self._clock = clock
        self.name = name or f"ublox@{self.config.port}"
        self.framer = UbxStreamFramer()
        self.acks: list[tuple[str, int, int]] = []  # ("ACK-ACK"|"ACK-NAK", class, id)

    def open(self) -> None:
        if self._injected is not None:
            self._serial = self._injected
        else:
            import serial  # pyserial

            try:
                self._serial = serial.Serial(self.config.port, self.config.baudrate, timeout=0)
            except (serial.SerialException, OSError) as err:
                raise SensorError(f"{self.name}: cannot open serial port {self.config.port!r} at "
                                  f"{self.config.baudrate} Bd: {err}") from err
        if self.config.configure:
            try:
                for msg in configuration_messages(self.config.nav_rate_hz):
                    self._serial.write(msg.serialize())
            except OSError as err:
                self.close()
                raise SensorError(f"{self.name}: cannot write the configuration: {err}") from err

    def close(self) -> None:
        if self._serial is not None and self._injected is None:
            try:
                self._serial.close()
            except OSError:
                pass  # the port vanished (USB unplugged): nothing left to release
        self._serial = None

    def _read_available(self, timeout_s: float) -> bytes:
        port = self._serial
        if port is None:
            raise SensorError(f"{self.name}: poll() before open()")
        try:
            waiting = port.in_waiting
            if waiting:
                return port.read(waiting)
            port.timeout = max(0.0, timeout_s)
            first = port.read(1)  # waits up to timeout_s for the first byte
            if not first:
                return b""
            rest = port.in_waiting
            return first + (port.read(rest) if rest else b"")
        except OSError as err:
            self.stats.record_error(f"serial read: {err}")
            return b""

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        """Decode what the port has; wait up to ``timeout_s`` for at least one fix."""
        deadline = self._clock() + timeout_s
        out: list[Sample] = []
        while True:
            remaining = deadline - self._clock()
            data = self._read_available(max(0.0, remaining))
            if data:
                now = self._clock()
                before = self.framer.checksum_errors
                for frame in self.framer.feed(data):
                    sample = self._decode(frame, now)
                    if sample is not None:
                        out.append(sample)
                self.stats.checksum_errors += self.framer.checksum_errors - before
            if out or self._clock() >= deadline:
                break
        self.stats.count(out)
        return out

    def _decode(self, frame: bytes, now_s: float) -> GpsSample | None:
        try:
            msg = UBXReader.parse(frame)
        except (UBXParseError, UBXMessageError, UBXTypeError) as err:
            # The checksum was good, so this is a message pyubx2 cannot decode.
            self.stats.record_error(f"UBX decode {frame[2]:#04x}/{frame[3]:#04x}: {err}")
            return None
        if msg.identity == "NAV-PVT":
            return gps_sample_from_nav_pvt(msg, now_s)
        if msg.identity in ("ACK-ACK", "ACK-NAK"):
            self.acks.append((msg.identity, msg.clsID, msg.msgID))
        return None

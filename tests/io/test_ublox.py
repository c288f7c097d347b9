"""u-blox NAV-PVT over a pseudo-terminal, with real pyubx2 frames, NMEA noise and a bad checksum."""
from __future__ import annotations

import os
import random
import select
import time
from functools import reduce

import pytest
import serial
from pyubx2 import GET, SET, UBXMessage, UBXReader

from companion.io.sensors import GpsSample, SensorError
from companion.io.sensors.ublox import UbloxConfig, UbloxSource, UbxStreamFramer, ubx_checksum


def nav_pvt(i: int, fix_type: int = 3, fix_ok: int = 1) -> bytes:
    """A NAV-PVT frame whose fields encode its index ``i``."""
    return UBXMessage(
        "NAV", "NAV-PVT", GET,
        iTOW=200 * i, year=2024, month=5, day=10, hour=12, min=0, second=i % 60, validDate=1, validTime=1,
        fixType=fix_type, gnssFixOk=fix_ok, numSV=5 + i % 20,
        lat=33.0 + 1e-4 * i, lon=152.0 - 2e-4 * i, height=50_000 + i, hMSL=20_000 + i,
        hAcc=1000 + 10 * i, vAcc=2000 + 10 * i, velN=100 * i, velE=-50 * i, velD=7,
    ).serialize()


def nmea(body: str) -> bytes:
    checksum = reduce(lambda a, c: a ^ ord(c), body, 0)
    return f"${body}*{checksum:02X}\r\n".encode()


NMEA = [
    nmea("GNGGA,120001.00,3300.00000,N,15200.00000,E,1,12,0.80,20.0,M,30.0,M,,"),
    nmea("GNRMC,120001.00,A,3300.00000,N,15200.00000,E,0.010,,100524,,,A,V"),
    nmea("GNGSA,A,3,01,03,06,09,17,19,,,,,,,1.50,0.80,1.27,1"),
]


def corrupt(frame: bytes) -> bytes:
    bad = bytearray(frame)
    bad[20] ^= 0x5A  # inside the payload: the checksum no longer matches
    return bytes(bad)


# -- the framer alone -----------------------------------------------------------------


def test_framer_byte_by_byte_with_nmea_and_garbage() -> None:
    frames = [nav_pvt(i) for i in range(5)]
    stream = b"\x00\xff\xb5" + NMEA[0] + frames[0] + b"junk" + frames[1] + NMEA[1] + frames[2] \
        + b"\xb5\x00" + frames[3] + NMEA[2] + frames[4]
    framer = UbxStreamFramer()
    got = [f for b in stream for f in framer.feed(bytes([b]))]
    assert got == frames
    assert framer.checksum_errors == 0
    assert framer.nmea_sentences == 3


def test_framer_resyncs_after_a_corrupted_length_field() -> None:
    good = [nav_pvt(i) for i in range(3)]
    bad = bytearray(nav_pvt(9))
    bad[4], bad[5] = 0xFF, 0x00  # claims 255 bytes: would swallow the next frames
    framer = UbxStreamFramer()
    got = framer.feed(good[0] + bytes(bad) + good[1] + good[2] + nav_pvt(3)[:10])
    got += framer.feed(nav_pvt(3)[10:])
    assert got == good + [nav_pvt(3)]
    assert framer.checksum_errors == 1


def test_framer_survives_an_nmea_sentence_cut_by_a_ubx_frame() -> None:
    frame = nav_pvt(1)
    framer = UbxStreamFramer()
    got = framer.feed(NMEA[0][:20] + frame + NMEA[1])
    assert got == [frame]


def test_checksum_matches_pyubx2() -> None:
    frame = nav_pvt(4)
    assert ubx_checksum(frame[2:-2]) == frame[-2:]


# -- end to end over a pseudo-terminal ------------------------------------------------


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    port = serial.Serial(path, 115200, timeout=0)
    yield master, port
    port.close()
    os.close(slave)
    os.close(master)


def read_master(master: int, wait_s: float = 0.5) -> bytes:
    data = b""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.05)
        if ready:
            data += os.read(master, 4096)
        elif data:
            break
    return data


def test_pty_stream_split_at_random_boundaries(pty_pair) -> None:
    master, port = pty_pair
    src = UbloxSource(UbloxConfig(port=port.port, nav_rate_hz=5.0), serial_port=port)
    src.open()

    # The configuration reached the receiver side as real UBX input messages.
    sent = read_master(master)
    idents = [msg.identity for _, msg in UBXReader(_BytesStream(sent), msgmode=SET)]
    assert idents == ["CFG-MSG", "CFG-RATE", "CFG-VALSET"]

    n = 40
    bad_index = 17
    stream = b""
    expected = []
    for i in range(n):
        if i % 3 == 0:
            stream += NMEA[i % len(NMEA)]
        if i == bad_index:
            stream += corrupt(nav_pvt(i))
            continue
        fix = (3, 2, 0)[i % 3] if i % 7 == 0 else 3
        stream += nav_pvt(i, fix_type=fix)
        expected.append((i, fix))

    rng = random.Random(20240510)
    got: list[GpsSample] = []
    pos = 0
    while pos < len(stream):
        step = rng.randint(1, 150)
        os.write(master, stream[pos:pos + step])
        pos += step
        got += src.poll(0.01)
    deadline = time.monotonic() + 2.0
    while len(got) < len(expected) and time.monotonic() < deadline:
        got += src.poll(0.05)
    src.close()

    assert len(got) == len(expected) == n - 1
    for sample, (i, fix) in zip(got, expected):
        assert sample.lat_deg == pytest.approx(33.0 + 1e-4 * i, abs=1e-9)
        assert sample.lon_deg == pytest.approx(152.0 - 2e-4 * i, abs=1e-9)
        assert sample.fix_type == {3: 3, 2: 2, 0: 1}[fix]
        assert sample.h_acc_m == pytest.approx((1000 + 10 * i) * 1e-3)
        assert sample.v_acc_m == pytest.approx((2000 + 10 * i) * 1e-3)
        assert sample.alt_m == pytest.approx(50.0 + i * 1e-3)
        assert sample.alt_msl_m == pytest.approx(20.0 + i * 1e-3)
        assert sample.vel_ned_mps == pytest.approx((0.1 * i, -0.05 * i, 0.007))
        assert sample.num_sv == 5 + i % 20
        assert sample.utc_s is not None
    assert src.stats.checksum_errors == 1
    assert src.framer.nmea_sentences == len(range(0, n, 3))
    times = [s.time_s for s in got]
    assert times == sorted(times)


def test_fix_without_gnss_fix_ok_counts_as_no_fix() -> None:
    framer = UbxStreamFramer()
    src = UbloxSource("unused")
    (frame,) = framer.feed(nav_pvt(1, fix_type=3, fix_ok=0))
    sample = src._decode(frame, 0.0)
    assert sample is not None and sample.fix_type == 1


def test_opening_a_missing_port_is_a_clear_error() -> None:
    with pytest.raises(SensorError, match=r"cannot open serial port '/dev/does-not-exist' at 9600 Bd"):
        UbloxSource("/dev/does-not-exist").open()


def test_poll_before_open_is_an_error() -> None:
    with pytest.raises(SensorError, match="before open"):
        UbloxSource("unused").poll()


class _BytesStream:
    """Just enough of a stream for UBXReader over recorded bytes."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._pos = 0

    def read(self, n: int = 1) -> bytes:
        out = self._data[self._pos:self._pos + n]
        self._pos += len(out)
        return out

"""Log replay: the real DataFlash log171.bin, generated tlogs, cut logs and non-logs."""
from __future__ import annotations

import math
import os
import struct
from collections import Counter
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion.io.sensors import (  # noqa: E402
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    SampleFlag,
    SensorError,
    StreamEnd,
    make_source,
)
from companion.io.sensors.replay import LogReplaySource  # noqa: E402


def replay_all(src: LogReplaySource) -> list:
    out = []
    with src:
        while not src.finished:
            out += src.poll()
    return out


@pytest.fixture(scope="module")
def log171_samples(log171: Path) -> list:
    return replay_all(LogReplaySource(log171, instances=None))


def test_log171_counts_and_time_span_match_pymavlink(log171_reference: dict, log171_samples: list) -> None:
    ref = log171_reference
    got: Counter = Counter()
    first: dict = {}
    last: dict = {}
    names = {MagSample: "MAG", ImuSample: "IMU", GpsSample: "GPS"}
    for s in log171_samples:
        if isinstance(s, AttitudeSample):
            key = "ATT"
        elif isinstance(s, StreamEnd):
            continue
        else:
            key = names[type(s)] + ("" if s.instance == 0 else str(s.instance + 1))
        got[key] += 1
        first.setdefault(key, s.time_s)
        last[key] = s.time_s
    assert got == ref["counts"]
    for key in ref["counts"]:
        assert first[key] == pytest.approx(ref["first"][key])
        assert last[key] == pytest.approx(ref["last"][key])
    # What the data README says: 243 s, MAG ~10 Hz, IMU ~50 Hz, GPS 5 Hz.
    span = last["MAG"] - first["MAG"]
    assert span == pytest.approx(243.0, abs=1.0)
    assert got["MAG"] / span == pytest.approx(10.0, rel=0.05)
    assert got["IMU"] / (last["IMU"] - first["IMU"]) == pytest.approx(50.0, rel=0.05)
    assert got["GPS"] / (last["GPS"] - first["GPS"]) == pytest.approx(5.0, rel=0.05)
    end = log171_samples[-1]
    assert isinstance(end, StreamEnd) and not end.truncated
    assert end.time_s == pytest.approx(max(ref["last"].values()))


def test_log171_units_and_accuracies(log171_reference: dict, log171_samples: list) -> None:
    mag = next(s for s in log171_samples if isinstance(s, MagSample))
    assert mag.mag_body_nt == tuple(100.0 * c for c in log171_reference["mag0"])  # 1 mG = 100 nT
    fixes = [s for s in log171_samples if isinstance(s, GpsSample) and s.has_3d_fix]
    lat, lon, alt = log171_reference["gps0"]
    assert (fixes[0].lat_deg, fixes[0].lon_deg, fixes[0].alt_msl_m) == pytest.approx((lat, lon, alt))
    assert math.isnan(fixes[0].alt_m)  # a DataFlash GPS record has MSL altitude only
    # UBX3 records carry the accuracies of (almost) every GPS record.
    with_acc = [s for s in fixes if math.isfinite(s.h_acc_m)]
    assert len(with_acc) >= 0.99 * len(fixes)
    assert all(0.3 < s.h_acc_m < 10.0 and 0.3 < s.v_acc_m < 20.0 for s in with_acc)
    times = [s.time_s for s in log171_samples if isinstance(s, ImuSample) and s.instance == 0]
    assert all(b > a for a, b in zip(times, times[1:]))
    imu = next(s for s in log171_samples if isinstance(s, ImuSample))
    assert imu.accel_body_mps2[2] == pytest.approx(-9.6, abs=0.3)  # at rest, z down
    att = [s for s in log171_samples if isinstance(s, AttitudeSample)]
    assert all(0.0 <= a.yaw_rad < 2.0 * math.pi for a in att)


def test_primary_instances_only_by_default(log171: Path, log171_reference: dict) -> None:
    samples = replay_all(make_source(f"replay:{log171}?speed=fast"))
    mags = [s for s in samples if isinstance(s, MagSample)]
    assert {s.instance for s in mags} == {0}
    assert len(mags) == log171_reference["counts"]["MAG"]


@pytest.mark.parametrize("cut", [100_003, 1_490_951])
def test_a_truncated_log_ends_flagged(log171: Path, tmp_path: Path, cut: int) -> None:
    data = log171.read_bytes()
    path = tmp_path / "cut.bin"
    path.write_bytes(data[:cut])
    samples = replay_all(LogReplaySource(path))
    end = samples[-1]
    assert isinstance(end, StreamEnd) and end.truncated
    assert end.flags == SampleFlag.END | SampleFlag.TRUNCATED
    assert "bytes left unparsed" in end.detail
    assert sum(isinstance(s, StreamEnd) for s in samples) == 1
    assert len(samples) > 10


def test_a_dataflash_log_with_another_extension(log171: Path, tmp_path: Path) -> None:
    path = tmp_path / "flight.dat"
    path.write_bytes(log171.read_bytes()[:200_000])
    samples = replay_all(LogReplaySource(path))
    assert any(isinstance(s, MagSample) for s in samples)


@pytest.mark.parametrize("content, message", [
    (b"", "is empty"),
    (b"hello, this is not a flight log\n" * 20, "neither an ArduPilot DataFlash .bin log"),
    (bytes(range(256)) * 8, "it starts 00 01 02"),
])
def test_a_file_that_is_not_a_log_is_a_clear_error(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "notalog.bin"
    path.write_bytes(content)
    with pytest.raises(SensorError, match=message):
        LogReplaySource(path).open()


def test_a_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SensorError, match="cannot read log"):
        LogReplaySource(tmp_path / "nope.tlog").open()


# -- tlogs -----------------------------------------------------------------------------

UNIX0_US = 1_700_000_000_000_000
BOOT_OFFSET_US = UNIX0_US - 10_000_000  # UNIX time at boot: the autopilot booted 10 s before UNIX0


def write_tlog(path: Path, steps: int = 50, *, other_system: bool = False, scaled_too: bool = False,
               highres_from: int | None = None) -> Path:
    """A tlog like ArduPilot's: boot-time IMU/attitude, UNIX-time GPS_RAW_INT, SYSTEM_TIME;
    ``highres_from``: the autopilot (MAV_AUTOPILOT_*) of a heartbeat and HIGHRES_IMU instead of RAW_IMU,
    its magnetometer 21.0/4.5/-52.0 mG in that autopilot's unit."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    out = bytearray()
    for i in range(steps):
        boot_ms = 10_000 + 100 * i
        capture_us = UNIX0_US + 100_000 * i + 3_000  # recorded 3 ms after sending
        msgs = [(mav, mavlink.MAVLink_attitude_message(boot_ms, 0.1, -0.05, -0.5, 0.0, 0.0, 0.0)),
                (mav, mavlink.MAVLink_raw_imu_message(boot_ms * 1000, 10, -20, -1000, 1, 2, 3,
                                                       210, 45, -520, 0, 3150)),
                (mav, mavlink.MAVLink_system_time_message(BOOT_OFFSET_US + boot_ms * 1000, boot_ms))]
        if highres_from is not None:
            per_mg = 1000.0 if highres_from == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA else 1e-3   # -> its unit
            msgs[1] = (mav, mavlink.MAVLink_highres_imu_message(
                boot_ms * 1000, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 210 * per_mg, 45 * per_mg, -520 * per_mg,
                1013.0, 0.0, 0.0, 25.0, 0x1FF, 0))
            if i == 0:
                msgs.insert(0, (mav, mavlink.MAVLink_heartbeat_message(11, highres_from, 0, 0, 3, 3)))
        if scaled_too:
            msgs.append((mav, mavlink.MAVLink_scaled_imu_message(boot_ms, 0, 0, -1000, 0, 0, 0, 999, 999, 999, 0)))
        if i % 5 == 0:
            msgs.append((mav, mavlink.MAVLink_gps_raw_int_message(
                BOOT_OFFSET_US + boot_ms * 1000 + 500, 3, -353623714, 1491658533, 590080, 120, 200,
                150, 9000, 10, 610000, 1500, 2500, 0, 0, 0)))
        if other_system:
            msgs.append((gcs, mavlink.MAVLink_attitude_message(boot_ms, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)))
        for link, m in msgs:
            out += struct.pack(">Q", capture_us) + m.pack(link)
    path.write_bytes(bytes(out))
    return path


def test_tlog_units_and_boot_time(tmp_path: Path) -> None:
    samples = replay_all(LogReplaySource(write_tlog(tmp_path / "a.tlog"), instances=None))
    kinds = Counter(type(s).__name__ for s in samples)
    assert kinds == {"AttitudeSample": 50, "ImuSample": 50, "MagSample": 50, "GpsSample": 10, "StreamEnd": 1}
    att = next(s for s in samples if isinstance(s, AttitudeSample))
    assert att.time_s == pytest.approx(10.0)
    assert att.yaw_rad == pytest.approx(2 * math.pi - 0.5)
    imu = next(s for s in samples if isinstance(s, ImuSample))
    assert imu.accel_body_mps2 == pytest.approx((0.0980665, -0.196133, -9.80665))  # mG
    assert imu.gyro_body_radps == pytest.approx((0.001, 0.002, 0.003))  # mrad/s
    assert imu.temperature_c == pytest.approx(31.5)
    mag = next(s for s in samples if isinstance(s, MagSample))
    assert mag.mag_body_nt == (21050.0, 4550.0, -52050.0)  # mG -> nT, the midpoint of the truncated count
    gps = next(s for s in samples if isinstance(s, GpsSample))
    assert gps.time_s == pytest.approx(10.0005, abs=1e-6)  # UNIX stamp put on the boot clock
    assert gps.utc_s == pytest.approx((BOOT_OFFSET_US + 10_000_500) * 1e-6)
    assert (gps.lat_deg, gps.lon_deg) == (-35.3623714, 149.1658533)
    assert (gps.alt_m, gps.alt_msl_m, gps.h_acc_m, gps.v_acc_m) == pytest.approx((610.0, 590.08, 1.5, 2.5))
    assert gps.vel_ned_mps[:2] == pytest.approx((0.0, 1.5), abs=1e-9)
    assert math.isnan(gps.vel_ned_mps[2])
    assert samples[-1].flags == SampleFlag.END


def test_tlog_ignores_other_systems_and_duplicate_imu_messages(tmp_path: Path) -> None:
    samples = replay_all(LogReplaySource(write_tlog(tmp_path / "b.tlog", other_system=True, scaled_too=True)))
    atts = [s for s in samples if isinstance(s, AttitudeSample)]
    mags = [s for s in samples if isinstance(s, MagSample)]
    assert len(atts) == 50 and all(a.roll_rad == pytest.approx(0.1) for a in atts)
    assert len(mags) == 50 and all(m.mag_body_nt[0] == 21050.0 for m in mags)  # RAW_IMU came first


@pytest.mark.parametrize("autopilot", [mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4],
                         ids=["ardupilot", "px4"])
def test_tlog_highres_imu_in_the_recording_autopilots_unit(tmp_path: Path, autopilot: int) -> None:
    """ArduPilot's HIGHRES_IMU magnetometer is milligauss x 1000, PX4's gauss: the log's heartbeat says which."""
    samples = replay_all(LogReplaySource(write_tlog(tmp_path / "h.tlog", highres_from=autopilot)))
    mags = [s for s in samples if isinstance(s, MagSample)]
    assert len(mags) == 50
    assert all(m.mag_body_nt == pytest.approx((21000.0, 4500.0, -52000.0), rel=1e-6) for m in mags)


def test_truncated_tlog_ends_flagged(tmp_path: Path) -> None:
    full = write_tlog(tmp_path / "full.tlog").read_bytes()
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(full[:-7])
    samples = replay_all(LogReplaySource(cut))
    assert samples[-1].truncated
    assert len(samples) > 100


class FakeTime:
    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def test_recorded_speed_pacing_uses_the_injected_clock(tmp_path: Path) -> None:
    t = FakeTime()
    src = LogReplaySource(write_tlog(tmp_path / "c.tlog"), speed=2.0, clock=t.clock, sleep=t.sleep)
    with src:
        first = src.poll(0.0)
        assert [type(s) for s in first] == [AttitudeSample, ImuSample, MagSample]
        # GPS_RAW_INT was stamped 0.5 ms after them: 0.25 ms of wall time at 2x.
        assert [type(s) for s in src.poll(0.001)] == [GpsSample]
        assert t.sleeps == [pytest.approx(0.00025, abs=1e-6)]
        assert src.poll(0.0) == []  # the next record is 50 ms of wall time away at 2x
        assert src.poll(0.01) == [] and t.now == pytest.approx(1000.01)
        got = src.poll(1.0)
        assert got and got[0].time_s == pytest.approx(10.1)
        assert t.now == pytest.approx(1000.05)
        while not src.finished:
            src.poll(1.0)
    # 4.9 s of log at twice the recorded speed.
    assert t.now - 1000.0 == pytest.approx(4.9 / 2.0, abs=1e-6)


def test_speed_is_validated(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="speed must be > 0"):
        LogReplaySource(tmp_path / "x.tlog", speed=0.0)
    with pytest.raises(ValueError, match="speed must be a number > 0 or 'fast'"):
        make_source("replay:x.tlog?speed=slow")


# -- a DataFlash log in the current ArduPilot format (TimeUS, instance fields, GPA) --------

_DF_STRUCT = {"B": "B", "b": "b", "H": "H", "h": "h", "I": "I", "i": "i", "f": "f", "Q": "Q",
              "c": "h", "C": "H", "e": "i", "L": "i", "n": "4s", "N": "16s", "Z": "64s"}
_DF_SCALE = {"c": 100.0, "C": 100.0, "e": 100.0, "L": 1e7}
_DF_FORMATS = {  # name: (type id, format, columns) as ArduPilot 4.x writes them
    "MAG": (10, "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"),
    "IMU": (11, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "ATT": (12, "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"),
    "GPS": (13, "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    "GPA": (14, "QBCCCCfBIHfHH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta,Und,RTCMFU,RTCMFD"),
}


def _df_record(type_id: int, fmt: str, values: tuple) -> bytes:
    packed = []
    for ch, v in zip(fmt, values):
        if ch in _DF_SCALE:
            v = round(v * _DF_SCALE[ch])
        elif ch in "nNZ":
            v = v.encode()
        packed.append(v)
    return b"\xa3\x95" + bytes([type_id]) + struct.pack("<" + "".join(_DF_STRUCT[c] for c in fmt), *packed)


def write_dataflash(path: Path) -> Path:
    out = bytearray()
    for name, (tid, fmt, cols) in _DF_FORMATS.items():
        length = 3 + struct.calcsize("<" + "".join(_DF_STRUCT[c] for c in fmt))
        out += _df_record(0x80, "BBnNZ", (tid, length, name, fmt, cols))
    for k in range(20):
        us = 5_000_000 + 100_000 * k
        for inst in (0, 1):
            out += _df_record(10, _DF_FORMATS["MAG"][1], (us, inst, 231 + inst, 51, -531, 10, 20, 30, 0, 0, 0,
                                                         1 if k != 7 else 0, 0))
            out += _df_record(11, _DF_FORMATS["IMU"][1], (us, inst, 0.01, 0.02, 0.03, 0.1, 0.2, -9.8,
                                                         k // 10, 0, 35.5, 1, 1, 400, 400))
        out += _df_record(12, _DF_FORMATS["ATT"][1], (us, 0.0, 5.0, 0.0, -3.0, 0.0, 271.5, 0.1, 0.1, 3))
        if k % 2 == 0:  # GPS then its GPA, as AP_GPS::Write_GPS does
            out += _df_record(13, _DF_FORMATS["GPS"][1], (us, 0, 3, 12345, 2300, 14, 0.7, -35.3622797,
                                                         149.1659262, 590.14, 2.0, 90.0, -0.5, 0.0, 1))
            out += _df_record(14, _DF_FORMATS["GPA"][1], (us, 0, 0.9, 1.25, 2.5, 0.3, 0.0, 1, 12345, 200,
                                                         20.0, 0, 0))
    path.write_bytes(bytes(out))
    return path


def test_current_dataflash_format_with_instance_fields_and_gpa(tmp_path: Path) -> None:
    samples = replay_all(LogReplaySource(write_dataflash(tmp_path / "new.bin"), instances=None))
    mags = [s for s in samples if isinstance(s, MagSample)]
    imus = [s for s in samples if isinstance(s, ImuSample)]
    gpss = [s for s in samples if isinstance(s, GpsSample)]
    atts = [s for s in samples if isinstance(s, AttitudeSample)]
    assert (len(mags), len(imus), len(gpss), len(atts)) == (40, 40, 10, 20)
    assert {m.instance for m in mags} == {0, 1}
    m1 = next(m for m in mags if m.instance == 1)
    assert m1.time_s == pytest.approx(5.0) and m1.mag_body_nt == (23200.0, 5100.0, -53100.0)
    assert [m.valid for m in mags if m.instance == 0].count(False) == 1  # Health 0 at k = 7
    imu = imus[0]
    assert imu.temperature_c == pytest.approx(35.5) and imu.accel_body_mps2 == pytest.approx((0.1, 0.2, -9.8))
    assert [i.valid for i in imus if i.instance == 0].count(False) == 1  # EG counter went up once
    gps = gpss[0]
    assert (gps.h_acc_m, gps.v_acc_m) == pytest.approx((1.25, 2.5))  # GPA written after GPS
    assert gps.vel_ned_mps == pytest.approx((0.0, 2.0, -0.5), abs=1e-9)
    assert (gps.lat_deg, gps.lon_deg, gps.alt_msl_m, gps.num_sv) == pytest.approx(
        (-35.3622797, 149.1659262, 590.14, 14))
    assert math.degrees(atts[0].yaw_rad) == pytest.approx(271.5)
    assert math.degrees(atts[0].roll_rad) == pytest.approx(5.0)
    assert not samples[-1].truncated

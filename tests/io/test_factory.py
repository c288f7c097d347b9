"""make_source specs, option handling and the combined source."""
from __future__ import annotations

from pathlib import Path

import pytest

from companion.io.sensors import (
    CombinedSource,
    GpsSample,
    ImuSample,
    MagSample,
    SampleKind,
    SensorError,
    SensorSource,
    StalenessMonitor,
    make_source,
    parse_spec,
)
from companion.io.sensors.dronecan_mag import DroneCanMagSource
from companion.io.sensors.mpu9250 import Mpu9250Source
from companion.io.sensors.replay import LogReplaySource
from companion.io.sensors.ublox import UbloxSource
from companion.process.intake import source_kinds
from tests.io.emulated_mpu9250 import EmulatedMpu9250


def test_parse_spec() -> None:
    assert parse_spec("i2c:/dev/i2c-1") == ("i2c", "/dev/i2c-1", {})
    assert parse_spec("replay:a/b.bin?speed=fast&instances=all") == (
        "replay", "a/b.bin", {"speed": "fast", "instances": "all"})
    assert parse_spec("i2c:1?address=0x69&attitude=false&declination_rad=0.2") == (
        "i2c", "1", {"address": 0x69, "attitude": False, "declination_rad": 0.2})
    with pytest.raises(ValueError, match="expected one of i2c:..., ubx:..., dronecan:..., replay:..."):
        parse_spec("gps:/dev/ttyS0")
    with pytest.raises(ValueError, match="nothing after 'ubx:'"):
        parse_spec("ubx:")
    with pytest.raises(ValueError, match="is not key=value"):
        parse_spec("replay:x.bin?fast")


def test_each_scheme_builds_its_source_with_options() -> None:
    i2c = make_source("i2c:/dev/i2c-1?address=0x69", gyro_range_dps=2000)
    assert isinstance(i2c, Mpu9250Source)
    assert (i2c.config.address, i2c.config.gyro_range_dps) == (0x69, 2000)

    ubx = make_source("ubx:/dev/ttyACM0:115200", nav_rate_hz=5.0)
    assert isinstance(ubx, UbloxSource)
    assert (ubx.config.port, ubx.config.baudrate, ubx.config.nav_rate_hz) == ("/dev/ttyACM0", 115200, 5.0)
    assert make_source("ubx:/dev/ttyAMA0").config.baudrate == 9600

    can0 = make_source("dronecan:can0")
    assert isinstance(can0, DroneCanMagSource)
    assert (can0.config.bustype, can0.config.channel) == ("socketcan", "can0")
    vcan = make_source("dronecan:virtual:vbus0?sensor_id=1")
    assert (vcan.config.bustype, vcan.config.channel, vcan.config.sensor_id) == ("virtual", "vbus0", 1)

    rep = make_source("replay:logs/log171.bin?speed=1.5&instances=0,1")
    assert isinstance(rep, LogReplaySource)
    assert (rep.speed, rep.instances) == (1.5, frozenset({0, 1}))
    assert make_source("replay:x.bin?speed=fast&instances=all").instances is None


def test_unknown_and_mistyped_options_are_clear_errors() -> None:
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['gyro_range'\]"):
        make_source("i2c:1", gyro_range=250)
    with pytest.raises(ValueError, match="gyro_range_dps must be one of"):
        make_source("i2c:1?gyro_range_dps=300")
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['rate'\]"):
        make_source("replay:x.bin?rate=2")


def test_a_combination_shares_the_host_clock_and_takes_options_per_kind() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1
    src = make_source("i2c:1+dronecan:virtual:vbus-combined", i2c={"bus": chip, "sleep": lambda s: None},
                      dronecan={"sensor_id": 3})
    assert isinstance(src, CombinedSource)
    assert [type(s) for s in src.sources] == [Mpu9250Source, DroneCanMagSource]
    assert src.sources[1].config.sensor_id == 3
    assert src.time_base == "host"
    with pytest.raises(ValueError, match="given per kind"):
        make_source("i2c:1+ubx:/dev/ttyS0", address=0x69)


def test_each_source_type_declares_the_kinds_it_replaces() -> None:
    """The companion ignores the flight controller's samples of the kinds a --sensors source
    provides: declared by the source's type, a combination the union of its parts'."""
    mag, att, gps = SampleKind.MAG, SampleKind.ATTITUDE, SampleKind.GPS
    assert source_kinds(make_source("i2c:1")) == {mag, att}
    assert source_kinds(make_source("dronecan:can0")) == {mag}
    assert source_kinds(make_source("ubx:/dev/ttyS0")) == {gps}
    assert source_kinds(make_source("replay:x.bin")) == {mag, att, gps}
    assert source_kinds(make_source("dronecan:can0+ubx:/dev/ttyS0")) == {mag, gps}


def test_a_combination_polls_all_its_sources() -> None:
    chip = EmulatedMpu9250()
    chip.noise_lsb = 1

    class FixedGps(SensorSource):
        name = "fixed-gps"

        def __init__(self) -> None:
            super().__init__()
            self.opened = False

        def open(self) -> None:
            self.opened = True

        def close(self) -> None:
            self.opened = False

        def poll(self, timeout_s: float = 0.0) -> list:
            return [GpsSample(0.0, -35.36, 149.17, 600.0, 3)]

    gps = FixedGps()
    src = CombinedSource([make_source("i2c:1", bus=chip, sleep=lambda s: None), gps])
    monitor = StalenessMonitor()
    with src:
        assert gps.opened
        samples = src.poll(0.1)
        monitor.update(samples)
    assert not gps.opened
    kinds = {type(s) for s in samples}
    assert {ImuSample, MagSample, GpsSample} <= kinds
    assert src.stats.samples == len(samples)
    assert not monitor.is_stale("gps", 0.5, 1.0)


def test_a_combination_closes_what_it_opened_when_one_source_fails() -> None:
    chip = EmulatedMpu9250()
    ok = make_source("i2c:1", bus=chip, sleep=lambda s: None)
    bad = make_source("i2c:1", bus=EmulatedMpu9250(present=False), sleep=lambda s: None)
    with pytest.raises(SensorError, match="no MPU-9250 answers"):
        CombinedSource([ok, bad]).open()
    with pytest.raises(SensorError, match="before open"):
        ok.poll()


def test_replay_and_live_sources_cannot_be_combined(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="cannot mix time bases"):
        CombinedSource([LogReplaySource(tmp_path / "x.bin"), make_source("i2c:1")])


def test_replay_through_the_factory_end_to_end(shared_data: Path) -> None:
    path = shared_data / "logs" / "log171.bin"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    monitor = StalenessMonitor()
    sizes = []
    with make_source(f"replay:{path}?speed=fast") as src:
        while not src.finished:
            samples = src.poll()
            monitor.update(samples)
            sizes.append(len(samples))
        assert src.poll(1.0) == []  # finished: returns at once
    # Primary instances: 11916 IMU + 2384 MAG + 2383 ATT + 1199 GPS, and the end marker.
    assert sum(sizes) == 17883
    assert max(sizes) == 1000  # max_batch
    assert monitor.last_time("imu") == pytest.approx(254.061)
    assert not monitor.is_stale("gps", now_s=254.1, timeout_s=0.5)

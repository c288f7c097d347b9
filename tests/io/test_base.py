"""The sample types, flags, staleness monitor and plausibility checks."""
from __future__ import annotations

import dataclasses
import math

import pytest

from companion.io.sensors import (
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    SampleFlag,
    SampleKind,
    SourceStats,
    StalenessMonitor,
    StreamEnd,
)
from companion.io.sensors.quality import MagChecks, MagQualityCheck, RepeatDetector


def test_samples_are_immutable_and_know_their_kind() -> None:
    mag = MagSample(1.0, (20000.0, 0.0, -50000.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        mag.time_s = 2.0  # type: ignore[misc]
    assert mag.kind is SampleKind.MAG
    assert ImuSample(1.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0)).kind is SampleKind.IMU
    assert AttitudeSample(1.0, 0.0, 0.0, 0.0).kind is SampleKind.ATTITUDE
    assert GpsSample(1.0, -35.0, 149.0, 600.0, 3).kind is SampleKind.GPS
    assert StreamEnd(1.0).kind is SampleKind.END


@pytest.mark.parametrize("flag", [SampleFlag.STUCK, SampleFlag.OVERFLOW, SampleFlag.SPIKE,
                                  SampleFlag.READ_ERROR, SampleFlag.UNHEALTHY])
def test_any_quality_flag_invalidates_a_sample(flag: SampleFlag) -> None:
    assert MagSample(1.0, (1.0, 2.0, 3.0)).valid
    assert not MagSample(1.0, (1.0, 2.0, 3.0), flags=flag).valid
    assert not ImuSample(1.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), flags=flag).valid
    assert not GpsSample(1.0, 0.0, 0.0, 0.0, 3, flags=flag).valid


def test_stream_end_flags() -> None:
    assert StreamEnd(5.0).valid and not StreamEnd(5.0).truncated
    cut = StreamEnd(5.0, SampleFlag.END | SampleFlag.TRUNCATED, "cut")
    assert cut.truncated and not cut.valid


def test_gps_altitude_fallback_to_msl() -> None:
    assert GpsSample(1.0, 0.0, 0.0, 612.0, 3, alt_msl_m=590.0).alt_approx_m == 612.0
    assert GpsSample(1.0, 0.0, 0.0, math.nan, 3, alt_msl_m=590.0).alt_approx_m == 590.0
    assert GpsSample(1.0, 0.0, 0.0, 0.0, 3).has_3d_fix
    assert not GpsSample(1.0, 0.0, 0.0, 0.0, 2).has_3d_fix


def test_staleness_per_kind_ignores_flagged_samples() -> None:
    m = StalenessMonitor()
    assert m.is_stale("mag", 0.0, 1.0) and m.age(SampleKind.MAG, 0.0) == math.inf
    m.update([MagSample(10.0, (1.0, 0.0, 0.0)), GpsSample(9.0, 0.0, 0.0, 0.0, 3)])
    m.update([MagSample(12.0, (1.0, 0.0, 0.0), flags=SampleFlag.OVERFLOW), StreamEnd(20.0)])
    assert m.last_time("mag") == 10.0
    assert not m.is_stale("mag", 10.5, timeout_s=1.0)
    assert m.is_stale("mag", 11.5, timeout_s=1.0)
    assert m.age("gps", 10.0) == pytest.approx(1.0)
    assert m.is_stale(SampleKind.IMU, 10.0, 100.0)
    m.update([MagSample(8.0, (1.0, 0.0, 0.0))])  # an older sample does not go back in time
    assert m.last_time("mag") == 10.0
    with pytest.raises(ValueError):
        m.is_stale("magnetometer", 0.0, 1.0)


def test_source_stats_count_flagged_samples() -> None:
    stats = SourceStats()
    stats.count([MagSample(1.0, (1.0, 0.0, 0.0)), MagSample(1.1, (1.0, 0.0, 0.0), flags=SampleFlag.SPIKE),
                 StreamEnd(2.0)])
    stats.record_error(OSError(121, "Remote I/O error"))
    assert (stats.samples, stats.flagged, stats.read_errors) == (2, 1, 1)
    assert "Remote I/O error" in (stats.last_error or "")


def test_repeat_detector() -> None:
    d = RepeatDetector(3)
    assert [d.check(r) for r in [1, 1, 1, 1, 2, 2]] == [
        SampleFlag.NONE, SampleFlag.NONE, SampleFlag.STUCK, SampleFlag.STUCK, SampleFlag.NONE, SampleFlag.NONE]
    with pytest.raises(ValueError, match="stuck limit"):
        RepeatDetector(1)


def test_spike_is_flagged_and_a_persistent_step_is_accepted() -> None:
    check = MagQualityCheck(MagChecks(stuck_count=100, spike_nt=10000.0, rebase_count=3))
    field = (20000.0, 0.0, -50000.0)
    step = (20000.0, 0.0, -70000.0)
    flags = [check.check(i, v) for i, v in enumerate(
        [field, field, step, field, field, step, step, step, step])]
    assert flags == [SampleFlag.NONE, SampleFlag.NONE, SampleFlag.SPIKE, SampleFlag.NONE, SampleFlag.NONE,
                     SampleFlag.SPIKE, SampleFlag.SPIKE, SampleFlag.SPIKE, SampleFlag.NONE]


def test_a_rotation_is_not_a_spike() -> None:
    check = MagQualityCheck(MagChecks(spike_nt=1000.0))
    for k in range(36):
        a = math.radians(10.0 * k)
        assert check.check(k, (50000.0 * math.cos(a), 50000.0 * math.sin(a), -20000.0)) == SampleFlag.NONE


def test_mag_checks_validate_their_thresholds() -> None:
    with pytest.raises(ValueError, match="spike_nt"):
        MagChecks(spike_nt=0.0)

"""What the report and the plots say (issue 12 items 11-13), on pymavlink-written tlogs."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from fcmpc.replay import evaluate, format_report
from fcmpc.replay.plots import di_figure, errors_figure
from tests.replay.synth import UNIX_2018, Phase, fly, write_tlog

W = (10.0,)


@pytest.fixture(scope="module")
def one_hz_ground(tmp_path_factory: pytest.TempPathFactory):
    """A 1 Hz recording carried around on the ground, never armed."""
    track = fly([Phase(120.0, speed_mps=1.5, course_deg=30.0), Phase(120.0, speed_mps=1.5, course_deg=200.0)],
                rate_hz=1.0, seed=6)
    path = write_tlog(tmp_path_factory.mktemp("slow") / "one_hz.tlog", [(track, UNIX_2018)], gps_every=1)
    return evaluate(path, windows_s=W)


def test_a_recording_that_is_no_flight_is_never_called_one(one_hz_ground) -> None:
    ev = one_hz_ground
    assert not ev.is_flight
    report = format_report(ev)
    assert "recording, not a flight" in report
    assert not re.search(r"\bflight\b(?! controller)", report.replace("not a flight", "")), \
        "the report calls a recording a flight"


def test_one_hz_imu_data_is_flagged_in_the_report_and_on_the_ins_figure(one_hz_ground) -> None:
    ev = one_hz_ground
    assert ev.imu_rate_hz == pytest.approx(1.0, rel=0.01)
    assert "IMU is logged at 1 Hz" in format_report(ev)
    fig = errors_figure(ev)
    assert "IMU at 1 Hz" in fig.axes[0].get_title()


def test_di_plot_axes_come_from_the_data_and_its_legend_has_the_real_rate(one_hz_ground, tmp_path: Path) -> None:
    ev = one_hz_ground
    fig = di_figure(ev)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "measured, 1 Hz" in labels and not any("10 Hz" in t for t in labels)
    s = ev.series
    for ax, key in zip(fig.axes, ("decl", "incl")):
        lo, hi = ax.get_ylim()
        data = np.concatenate([s[f"{key}_meas"][s["accepted"]], s[f"{key}_wmm"]])
        assert lo <= np.percentile(data, 1) and np.percentile(data, 99) <= hi
        assert hi - lo < 10.0 * (np.ptp(data) + 2.0)   # zoomed on the data, not a fixed wide range


@pytest.fixture(scope="module")
def uncalibrated(tmp_path_factory: pytest.TempPathFactory):
    """A magnetometer reading 1.7 times the field, mounted turned by 180 deg about z: D is off by
    180 deg, so its errors straddle +-180 and a linear mean of them is meaningless."""
    track = fly([Phase(10.0), Phase(100.0, armed=True, speed_mps=5.0, course_deg=120.0)], mag_scale=1.7, seed=7)
    track.mag_nt[:, :2] *= -1.0
    return evaluate(write_tlog(tmp_path_factory.mktemp("uncal") / "uncal.tlog", [(track, UNIX_2018)]), windows_s=W)


def test_an_uncalibrated_magnetometer_is_detected_and_said(uncalibrated) -> None:
    ev = uncalibrated
    assert ev.uncalibrated and ev.f_ratio == pytest.approx(1.7, abs=0.02)
    report = format_report(ev)
    assert report.index("UNCALIBRATED MAGNETOMETER") < report.index("## 1.")


def test_declination_statistics_are_circular(uncalibrated) -> None:
    air = uncalibrated.di_row("airborne")
    assert abs(air.decl_bias_deg) > 175.0          # a linear mean of errors near +-180 gives ~0
    assert air.decl_std_deg < 5.0                   # and a linear spread ~180 deg
    fix = uncalibrated.fix_row(10.0)
    assert abs(fix.err_decl_mean_deg) > 175.0 and fix.err_decl_std_deg < 5.0


def test_every_fix_median_carries_the_failed_share(one_hz_ground) -> None:
    ev = one_hz_ground
    row = ev.fix_row(10.0)
    failed = dataclasses.replace(row, failed=row.n // 2)
    report = format_report(dataclasses.replace(ev, fix_rows=[failed]))
    share = f"{100.0 * failed.failed / failed.n:.0f} % of {failed.n} failed"
    medians = [line for line in report.splitlines() if line.startswith("| 10 |")]
    assert sum(share in line for line in medians) == 2                   # fix table and fused table
    assert f"from GPS ({share}" in report                                 # and in the words


def test_di_plot_shows_a_declination_near_180_deg_in_one_piece(uncalibrated) -> None:
    fig = di_figure(uncalibrated)
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    measured = [line for line in ax.lines if line.get_label().startswith("measured")]
    assert len(measured) == 2                                              # samples and the 10 s means
    for line in measured:
        y = np.asarray(line.get_ydata(), dtype=float)
        assert lo <= y.min() and y.max() <= hi
        assert np.ptp(y) < 20.0                                            # not split at +-180 deg
    assert "uncalibrated" in ax.get_title()

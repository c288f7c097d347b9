"""PX4 ULog through pyulog and the generic CSV import with its frame check (issue 12 items 14, 16).

The ULog is written by a small writer of the ULog format (tests/replay/ulog_writer.py) and read
back by pyulog inside the replay; the CSVs carry a car-like drive with turns, once right and
once with a mirrored axis, which must be refused.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.io.sensors.base import SensorError
from fcmpc.replay import evaluate
from fcmpc.replay.cli import main
from fcmpc.replay.reading import read_boots
from fcmpc.replay.ulog import ULOG_GPS_SOURCE, euler_from_quaternion
from tests.replay.synth import UNIX_2018, Phase, fly, quaternion, write_csv, write_ulog

W = (10.0,)


def drive(seed: int = 8):
    """Disarmed, then armed: a drive east, a right turn through 180 deg, a drive west, a left turn."""
    return fly([Phase(10.0), Phase(3.0, armed=True), Phase(40.0, armed=True, speed_mps=8.0, course_deg=80.0),
                Phase(30.0, armed=True, speed_mps=8.0, turn_dps=6.0),
                Phase(40.0, armed=True, speed_mps=8.0, turn_dps=0.0),
                Phase(30.0, armed=True, speed_mps=8.0, turn_dps=-4.0)], seed=seed)


def test_quaternion_to_euler_round_trip() -> None:
    rng = np.random.default_rng(0)
    angles = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(-1.4, 1.4, 50), rng.uniform(-3, 3, 50)])
    back = euler_from_quaternion(quaternion(*angles.T))
    assert np.allclose(np.angle(np.exp(1j * (back - angles))), 0.0, atol=1e-9)


def test_a_px4_ulog_is_read_with_pyulog_and_evaluated(tmp_path: Path) -> None:
    track = drive()
    path = write_ulog(tmp_path / "px4.ulg", track, UNIX_2018)
    assert path.stat().st_size < 200_000
    (data,) = read_boots(path)
    assert data.format == "ulog" and data.armed_source == "vehicle_status.arming_state"
    assert data.counts["MAG"] == data.counts["ATT"] == len(track.t)
    assert np.allclose(data.mag[:, 1:], track.mag_nt, atol=0.1)       # gauss in the file, nT here
    ev = evaluate(path, windows_s=W)
    assert ev.date == "2018-06-01" and ev.date_source == ULOG_GPS_SOURCE
    assert ev.is_flight and ev.segments.takeoff_s == pytest.approx(track.takeoffs[0], abs=1.0)
    air = ev.di_row("airborne")
    assert abs(air.decl_bias_deg) < 0.5 and abs(air.incl_bias_deg) < 0.5   # the synthetic field is WMM2015's


def test_a_damaged_ulog_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    good = write_ulog(tmp_path / "px4.ulg", drive(), UNIX_2018).read_bytes()
    bad = tmp_path / "header_only.ulg"
    bad.write_bytes(good[:16])
    assert main([str(bad), "--no-plots", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fcmpc-replay: ") and "header_only.ulg" in err and "\n" not in err


def test_a_csv_recording_is_evaluated_and_its_frame_checked(tmp_path: Path) -> None:
    track = drive()
    ev = evaluate(write_csv(tmp_path / "car.csv", track, UNIX_2018), windows_s=W)
    assert ev.format == "csv" and ev.date == "2018-06-01"
    assert ev.is_flight and ev.segments.armed_s is not None
    assert not any("frame" in w for w in ev.warnings)                  # checked, and it passed
    assert abs(ev.di_row("airborne").decl_bias_deg) < 0.5


@pytest.mark.parametrize("what", ["mag_y", "yaw"])
def test_mirrored_axes_are_refused_with_the_columns_to_fix(tmp_path: Path, what: str) -> None:
    track = drive()
    if what == "mag_y":
        track.mag_nt[:, 1] *= -1.0                                    # a left-handed magnetometer
        words = "magnetometer axes are mirrored"
    else:
        track.yaw[:] = -track.yaw                                      # yaw counter-clockwise
        words = "yaw_deg turns against the GPS course"
    path = write_csv(tmp_path / f"mirrored_{what}.csv", track, UNIX_2018)
    with pytest.raises(SensorError, match=words):
        evaluate(path, windows_s=W)


def test_csv_user_errors_name_the_file_and_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "short.csv"
    path.write_text("time_s,mag_x_ut\n0,20\n1,21\n")
    assert main([str(path), "--no-plots", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "short.csv: line 1 lacks the column(s) mag_y_ut" in err and err.count("\n") == 1
    track = drive()
    path = write_csv(tmp_path / "up.csv", track, UNIX_2018)
    text = path.read_text().replace(",-9.8066,", ",9.8066,")             # z axis up
    path.write_text(text)
    with pytest.raises(SensorError, match="z axis points up"):
        read_boots(path)


def test_a_log_without_any_date_asks_for_one_instead_of_guessing(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "undated.csv", drive())                  # no unix_time_s column
    with pytest.raises(ValueError, match="pass --date"):
        evaluate(path, model_spec="WMM2015", windows_s=W)
    ev = evaluate(path, model_spec="WMM2015", windows_s=W, date="2018-06-01")
    assert ev.date == "2018-06-01" and ev.date_source == "--date" and ev.decimal_year == pytest.approx(2018.41, abs=0.01)

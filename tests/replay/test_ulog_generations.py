"""Both PX4 ULog schema generations (issue 47 item 4) on public logs (tests/data/ulog/SOURCE.md).

The 1.6-era log keeps its magnetometer in ``sensor_combined`` and its position only in
``vehicle_local_position``; the current one has ``sensor_mag``/``vehicle_magnetometer`` and
``vehicle_gps_position``. Expected values are read here with pyulog directly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fcmpc.replay import evaluate_log
from fcmpc.replay.calibrate import main as calibrate_main
from fcmpc.replay.reading import read_boots
from fcmpc.replay.ulog import ULOG_GPS_SOURCE
from tests.replay.synth import UNIX_2018, Phase, fly, write_ulog

DATA = Path(__file__).resolve().parents[1] / "data" / "ulog"
OLD = DATA / "px4-2017-sensor-combined.ulg"
CURRENT = DATA / "px4-2021-sensor-mag.ulg"


def _pyulog_topic(path: Path, name: str) -> dict[str, np.ndarray]:
    from pyulog import ULog

    return next(d.data for d in ULog(str(path), [name]).data_list if d.name == name and d.multi_id == 0)


def test_old_generation_magnetometer_is_read_from_sensor_combined(capsys: pytest.CaptureFixture) -> None:
    sc = _pyulog_topic(OLD, "sensor_combined")
    valid = sc["magnetometer_timestamp_relative"] != 2147483647
    t = (sc["timestamp"][valid] + sc["magnetometer_timestamp_relative"][valid]) * 1e-6
    first = np.concatenate([[True], np.diff(t) > 0])
    (data,) = read_boots(OLD)
    assert data.counts["MAG"] == int(first.sum()) > 400
    assert np.allclose(data.mag[:, 0], t[first])
    assert np.allclose(data.mag[:, 1:], 1e5 * np.column_stack(
        [sc[f"magnetometer_ga[{k}]"][valid][first] for k in range(3)]), rtol=1e-6)
    assert any("sensor_combined.magnetometer_ga" in n for n in data.notes)
    # this log's vehicle_local_position has no global reference: no position, said as such
    lp = _pyulog_topic(OLD, "vehicle_local_position")
    assert not lp["xy_global"].any() and not lp["ref_lat"].any()
    assert len(data.gps) == 0
    with pytest.raises(ValueError, match="0 3D GPS fixes, 444 magnetometer 0"):
        evaluate_log(OLD)
    assert calibrate_main([str(OLD)]) == 2
    assert "no 3D GPS fix" in capsys.readouterr().err


def test_current_generation_is_read_and_evaluated(tmp_path: Path) -> None:
    gps = _pyulog_topic(CURRENT, "vehicle_gps_position")
    vm = _pyulog_topic(CURRENT, "vehicle_magnetometer")
    (data,) = read_boots(CURRENT)
    fixed = gps["fix_type"] >= 3
    assert data.counts["GPS"] == int(fixed.sum()) == 32
    assert np.allclose(data.gps[:, 1], gps["lat"][fixed] * 1e-7)
    assert data.counts["MAG"] == len(vm["timestamp"])
    assert ULOG_GPS_SOURCE in data.unix_minus_boot_s
    result = evaluate_log(CURRENT, windows_s=(1.0,), calibrate=True)
    (ev,) = result.evaluations
    assert ev.date == "2021-04-21" and ev.model.startswith("WMM2020")
    # 6 s on the ground: far too little rotation for a calibration, which is refused and said
    assert ev.calibration.startswith("not applied") and "sphere" in ev.calibration


def test_old_generation_position_comes_from_the_local_position_reference(tmp_path: Path) -> None:
    track = fly([Phase(10.0), Phase(3.0, armed=True), Phase(40.0, armed=True, speed_mps=8.0, course_deg=80.0),
                 Phase(30.0, armed=True, speed_mps=8.0, turn_dps=6.0)], seed=4)
    path = write_ulog(tmp_path / "px4-1.6.ulg", track, UNIX_2018, generation="px4-1.6")
    (data,) = read_boots(path)
    assert data.counts["MAG"] == len(track.t)
    assert np.allclose(data.mag[:, 1:], track.mag_nt, atol=0.1)
    assert len(data.gps) == len(track.t[::2])
    assert np.allclose(data.gps[:, 1], track.lat[::2], atol=2e-6)     # < 0.2 m
    assert np.allclose(data.gps[:, 2], track.lon[::2], atol=2e-6)
    assert np.allclose(data.gps[:, 3], track.alt[::2], atol=0.01)
    assert any("vehicle_local_position" in n for n in data.notes)
    with pytest.raises(ValueError, match="pass --date"):              # no GPS topic, no date
        evaluate_log(path, model_spec="WMM2015", windows_s=(10.0,))
    (ev,) = evaluate_log(path, model_spec="WMM2015", windows_s=(10.0,), date="2018-06-01").evaluations
    air = ev.di_row("airborne")
    assert abs(air.decl_bias_deg) < 0.5 and abs(air.incl_bias_deg) < 0.5


def test_fcmpc_replay_calibrates_by_default(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from fcmpc.replay.cli import main as replay_main

    assert replay_main([str(CURRENT), "--no-plots", "--window-s", "1", "--out", str(tmp_path / "a")]) == 0
    report = capsys.readouterr().out
    assert "## 0. Magnetometer calibration" in report and "not applied" in report
    assert replay_main([str(CURRENT), "--no-plots", "--window-s", "1", "--no-calibration",
                        "--out", str(tmp_path / "b")]) == 0
    assert "## 0. Magnetometer calibration" not in capsys.readouterr().out

"""Boots, flights and dates of real MAVLink frames (pymavlink-written tlogs), issue 12 items 8-10.

The tlogs are built by :mod:`tests.replay.synth`: a vehicle flown through phases over WMM2015,
its sensors packed as ATTITUDE, RAW_IMU, GPS_RAW_INT, HEARTBEAT and SYSTEM_TIME frames.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from fcmpc.replay import evaluate, evaluate_log
from fcmpc.replay.events import GPS_RAW_SOURCE, SYSTEM_TIME_SOURCE, TLOG_SOURCE
from fcmpc.replay.reading import read_boots
from tests.replay.synth import UNIX_2018, Phase, fly, write_tlog

W = (10.0,)


@pytest.fixture(scope="module")
def reboot_tlog(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[float]]:
    """Boot 1: a compass-calibration dance on the ground, never armed (225 s of boot time).
    Boot 2 (boot time back to 2 s): 20 s disarmed, armed, a 90 s flight, landed, disarmed."""
    dance = fly([Phase(40.0), Phase(60.0, tumble=True), Phase(125.0)], seed=1)
    flight = fly([Phase(20.0), Phase(5.0, armed=True), Phase(90.0, armed=True, speed_mps=6.0, course_deg=70.0),
                  Phase(10.0, armed=True), Phase(10.0)], seed=2)
    path = write_tlog(tmp_path_factory.mktemp("reboot") / "reboot.tlog",
                      [(dance, UNIX_2018), (flight, UNIX_2018 + 240.0)])
    return path, flight.takeoffs


def test_a_reboot_splits_the_log_into_boots(reboot_tlog) -> None:
    path, _ = reboot_tlog
    boots = read_boots(path)
    assert [b.boot for b in boots] == [0, 1] and all(b.boots == 2 for b in boots)
    assert boots[0].span_s[1] == pytest.approx(227.0, abs=0.5)   # the dance's boot ends at 227 s
    assert boots[1].span_s[0] == pytest.approx(2.0, abs=0.2)     # the next boot starts again near 0
    assert [e[1] for e in boots[1].armed] == [False, True, False]
    assert not any(armed for _, armed in boots[0].armed)


def test_the_dance_before_a_reboot_is_not_a_flight_and_the_flight_after_it_is_found(reboot_tlog) -> None:
    path, takeoffs = reboot_tlog
    result = evaluate_log(path, windows_s=W)
    assert result.boots == 2
    dance, flight = result.evaluations
    assert (dance.boot, dance.is_flight) == (0, False)
    assert dance.segments.crash_s is None                       # a tumble on the ground is no crash
    assert any(w.startswith("not a flight: the vehicle was never armed") for w in dance.warnings)
    assert (flight.boot, flight.is_flight, flight.flight) == (1, True, 1)
    assert flight.segments.takeoff_s == pytest.approx(takeoffs[0], abs=1.0)
    assert flight.segments.end_s <= takeoffs[0] + 91.0
    assert result.labels == ["boot1-recording", "boot2-flight1"]


@pytest.fixture(scope="module")
def two_flights_tlog(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[float]]:
    """400 s disarmed with GPS altitude drifting up 4 m, then two armed flights with a
    disarmed minute between them."""
    track = fly([Phase(400.0, alt_drift_mps=0.01), Phase(5.0, armed=True),
                 Phase(60.0, armed=True, speed_mps=5.0, course_deg=90.0), Phase(5.0, armed=True),
                 Phase(60.0, alt_drift_mps=-0.01), Phase(5.0, armed=True),
                 Phase(60.0, armed=True, speed_mps=5.0, course_deg=0.0), Phase(5.0, armed=True), Phase(10.0)],
                seed=3)
    return write_tlog(tmp_path_factory.mktemp("flights") / "two.tlog", [(track, UNIX_2018)]), track.takeoffs


def test_take_off_needs_the_armed_state_and_each_armed_span_is_a_flight(two_flights_tlog) -> None:
    path, takeoffs = two_flights_tlog
    assert len(takeoffs) == 2
    result = evaluate_log(path, windows_s=W)
    flights = [ev for ev in result.evaluations if ev.is_flight]
    assert len(flights) == 2 and [ev.flight for ev in flights] == [1, 2]
    for ev, true_takeoff in zip(flights, takeoffs):
        seg = ev.segments
        assert seg.armed_s is not None and seg.armed_s <= seg.takeoff_s
        assert seg.takeoff_s == pytest.approx(true_takeoff, abs=1.0)  # not the ground drift at ~150 s
        assert seg.end_s - seg.takeoff_s == pytest.approx(60.0, abs=2.0)
        assert "HEARTBEAT base_mode" in " ".join(seg.rules)
    with pytest.raises(ValueError, match="2 flights"):
        evaluate(path, windows_s=W)


def test_without_armed_state_the_rule_says_so(tmp_path: Path) -> None:
    track = fly([Phase(30.0), Phase(60.0, armed=True, speed_mps=5.0, course_deg=45.0)], seed=4)
    ev = evaluate(write_tlog(tmp_path / "noheartbeat.tlog", [(track, UNIX_2018)], heartbeat=False), windows_s=W)
    assert ev.is_flight and ev.segments.armed_s is None
    assert any("no armed state" in rule for rule in ev.segments.rules)


def _short(tmp_path: Path, name: str, **kwargs) -> Path:
    track = fly([Phase(10.0), Phase(40.0, armed=True, speed_mps=5.0, course_deg=10.0)], seed=5)
    return write_tlog(tmp_path / name, [(track, UNIX_2018 + 3600.0)], **kwargs)


def test_boot_time_in_gps_raw_int_takes_the_date_from_system_time(tmp_path: Path) -> None:
    ev = evaluate(_short(tmp_path, "boot_gps.tlog", gps_time="boot"), windows_s=W)
    assert ev.date == "2018-06-01" and ev.date_source == SYSTEM_TIME_SOURCE
    assert ev.model == "WMM2015" and ev.decimal_year == pytest.approx(2018.41, abs=0.01)
    assert SYSTEM_TIME_SOURCE in (Path(ev.log).name + ev.model_note)


def test_the_date_falls_back_on_the_recording_and_prefers_the_gps(tmp_path: Path) -> None:
    ev = evaluate(_short(tmp_path, "nosystime.tlog", gps_time="boot", system_time=False), windows_s=W)
    assert ev.date == "2018-06-01" and ev.date_source == TLOG_SOURCE
    ev = evaluate(_short(tmp_path, "unix_gps.tlog"), windows_s=W)
    assert ev.date_source == GPS_RAW_SOURCE


def test_a_model_outside_its_validity_is_refused_with_the_date_and_its_source(tmp_path: Path) -> None:
    path = _short(tmp_path, "boot_gps.tlog", gps_time="boot")
    with pytest.raises(ValueError, match=r"2018-06-01.*SYSTEM_TIME"):
        evaluate(path, model_spec="WMM2025", windows_s=W)


def test_a_flight_that_cannot_be_judged_is_listed_and_the_others_evaluated(tmp_path: Path) -> None:
    """Two flights in a CSV whose magnetometer columns go empty before the second take-off."""
    from tests.replay.synth import write_csv

    track = fly([Phase(10.0), Phase(3.0, armed=True), Phase(40.0, armed=True, speed_mps=8.0, course_deg=80.0),
                 Phase(30.0, armed=True, speed_mps=8.0, turn_dps=6.0), Phase(15.0), Phase(3.0, armed=True),
                 Phase(40.0, armed=True, speed_mps=8.0, course_deg=200.0), Phase(5.0)], seed=9)
    path = write_csv(tmp_path / "mag_lost.csv", track, UNIX_2018)
    lines = path.read_text().splitlines()
    cut = track.takeoffs[1] - 10.0
    blanked = [lines[0]] + [",".join(cells[:1] + [""] * 3 + cells[4:]) if float(cells[0]) > cut else line
                            for line in lines[1:] for cells in [line.split(",")]]
    path.write_text("\n".join(blanked) + "\n")
    result = evaluate_log(path, windows_s=W)
    assert [ev.flight for ev in result.evaluations] == [1]
    assert any("flight 2: not evaluated" in s and "magnetometer" in s for s in result.skipped)

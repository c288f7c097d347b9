"""fcmpc-calibrate and the replay's calibration on the real log171.bin (issue 47 item 2).

log171's compass was calibrated by its flight controller; a car-like distortion (15 uT of hard
iron, 10 % soft iron) applied to it stands for an uncalibrated magnetometer. The replay fits and
applies the calibration, fitted on the first part of the log and judged on the rest: the
distorted field's fixes fail, the calibrated ones are back to the level of the log as logged. The
alignment (companion/nav/alignment.py) recovers a rotation applied to the log's magnetometer.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from companion.nav.alignment import rotation_matrix
from companion.nav.magnetometer import MagCalibration
from companion.params import read_parm_file
from fcmpc.replay.calibrate import calibrate_boot, main
from fcmpc.replay.logeval import evaluate_boots, evaluate_log
from fcmpc.replay.reading import read_boots

DISTORTION = np.array([[1.12, 0.06, -0.03], [0.06, 0.9, 0.05], [-0.03, 0.05, 1.05]])
HARD_IRON_NT = np.array([15000.0, -8000.0, 5000.0])
CAR_W = np.array([[1.15, 0.08, 0.0], [0.08, 0.85, 0.0], [0.0, 0.0, 1.0]])   # W33 = mean of W11, W22
CAR_O = np.array([25000.0, -18000.0, 9000.0])                              # a car's steel: ~half the field
MOUNTING_DEG = (2.0, -3.0, 0.0)                                             # a bracket 2 and 3 deg off


@pytest.fixture(scope="module")
def log171_data(log171: Path):
    (data,) = read_boots(log171)
    return data


def test_fcmpc_calibrate_writes_both_parameter_files(log171: Path, log171_data, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    assert main([str(log171), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "residual 540 nT rms" in printed and "42 % of 72 sphere cells" in printed
    ours = read_parm_file(tmp_path / "companion-mag.parm")   # validated against the registry
    cal = MagCalibration.from_mgauss(tuple(ours[f"MAG_OFS_{a}"] for a in "XYZ"),
                                     tuple(ours[f"MAG_SCALE_{a}"] for a in "XYZ"),
                                     tuple(ours[f"MAG_SOFT_{a}"] for a in ("XY", "XZ", "YZ")))
    corrected = np.array([cal.apply(tuple(m)) for m in log171_data.mag[:, 1:]])
    assert np.median(np.linalg.norm(corrected, axis=1)) == pytest.approx(58170.0, rel=0.005)
    ardupilot = dict(line.split() for line in (tmp_path / "ardupilot-compass.parm").read_text().splitlines()
                     if not line.startswith("#"))
    assert set(ardupilot) == {f"COMPASS_{k}_{a}" for k in ("OFS", "DIA", "ODI") for a in "XYZ"}
    assert "composed with the log's 9 COMPASS_* values" in printed
    # the alignment (roll from the level trim, pitch from the mounting: docs/calibration.md)
    assert ours["MAG_ROT_ROLL"] == pytest.approx(0.87, abs=0.05) and ours["MAG_ROT_PIT"] == pytest.approx(-2.73, abs=0.05)
    assert ours["MAG_ROT_YAW"] == 0.0 and "inclination bias -2.62 -> +0.05 deg" in printed


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle of the rotation between two rotation matrices."""
    return math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(a.T @ b) - 1.0) / 2.0))))


def test_calibration_recovers_a_rotation_applied_to_log171(log171_data) -> None:
    """log171's magnetometer turned by MOUNTING_DEG: the calibration (hard/soft iron, then the xy
    alignment, on every sample) finds the log's own alignment composed with it within 0.2 deg
    (measured 0.06 deg: the composition's small yaw, which the xy fit leaves out). Without the
    alignment the corrected fields differ by 3.6 deg: the soft iron is symmetric and cannot hold a
    rotation."""
    data = log171_data
    turned = dataclasses.replace(data, mag=np.column_stack([data.mag[:, 0], data.mag[:, 1:]
                                                            @ np.array(rotation_matrix(MOUNTING_DEG))]))
    own, cal = calibrate_boot(data), calibrate_boot(turned)
    assert own.alignment is not None and cal.alignment is not None
    expected = np.array(own.alignment.matrix) @ np.array(rotation_matrix(MOUNTING_DEG))
    assert _angle_deg(np.array(cal.alignment.matrix), expected) < 0.2
    # what each replays: the turned log's corrected field is the log's own, within 0.2 deg
    m = data.mag[::10, 1:]
    a = (m - own.calibration.offset_nt) @ np.array(own.calibration.soft_iron).T
    b = (m @ np.array(rotation_matrix(MOUNTING_DEG)) - cal.calibration.offset_nt) @ np.array(cal.calibration.soft_iron).T
    cosine = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    assert math.degrees(float(np.arccos(np.clip(cosine, -1.0, 1.0)).max())) < 0.2


def test_replay_calibrates_a_distorted_log171(log171_data) -> None:
    """Fitted on the first part (to 149.6 s: the first share whose fits are accepted) and judged
    on the rest: the distorted log's 10 s fixes all fail before; after, none fails and their
    median is back to the level of the log as ArduPilot calibrated it (measured 428 km against
    430 km as logged, on the same judged span), not better: D is measured against the logged yaw,
    which the flight controller computed from its own calibration of this compass."""
    data = log171_data
    own = evaluate_boots([data], windows_s=(10.0,), calibrate=True).evaluations[0]
    mag = data.mag.copy()
    mag[:, 1:] = mag[:, 1:] @ DISTORTION.T + HARD_IRON_NT
    ev = evaluate_boots([dataclasses.replace(data, mag=mag)], windows_s=(10.0,), calibrate=True).evaluations[0]
    (before,), (after,), (as_logged,) = ev.fix_rows_before, ev.fix_rows, own.fix_rows_before
    assert "judged from 149.6 s only" in ev.calibration and "level fit" in ev.calibration
    assert ev.segments.nav_start_s == pytest.approx(149.6, abs=0.1)
    assert "alignment (xy" in ev.calibration
    assert before.failed == before.n
    assert after.failed == 0 and after.fix_median_m < 1.1 * as_logged.fix_median_m


def test_all_samples_fit_is_the_named_option(log171_data) -> None:
    """--calibration-fit all-samples fits on every sample and judges them all (from take-off)."""
    ev = evaluate_boots([log171_data], windows_s=(30.0,), calibrate=True,
                        calibration_fit="all-samples").evaluations[0]
    assert ev.calibration.startswith("fitted on every sample of the boot, judged on the same samples")
    assert ev.segments.nav_start_s == pytest.approx(ev.segments.takeoff_s)


def test_replay_calibrates_a_car_that_only_turns_about_its_vertical(tmp_path: Path) -> None:
    """A written ULog of a car (level, a full circle then straight roads) with a car-like
    uncalibrated magnetometer: the full fit is refused, the level fit is applied, and the 10 s
    fixes' median error falls at least 5x (the issue's target for an uncalibrated magnetometer)."""
    from tests.replay.synth import UNIX_2018, Phase, fly, write_ulog

    track = fly([Phase(10.0), Phase(3.0, armed=True), Phase(20.0, armed=True, speed_mps=8.0, course_deg=80.0),
                 Phase(60.0, armed=True, speed_mps=8.0, turn_dps=6.0),
                 Phase(120.0, armed=True, speed_mps=8.0, turn_dps=0.0),
                 Phase(30.0, armed=True, speed_mps=8.0, turn_dps=3.0),
                 Phase(120.0, armed=True, speed_mps=8.0, turn_dps=0.0)], seed=5)
    car = dataclasses.replace(track, mag_nt=np.linalg.solve(CAR_W, track.mag_nt.T).T + CAR_O)
    path = write_ulog(tmp_path / "car.ulg", car, UNIX_2018)
    (ev,) = evaluate_log(path, windows_s=(10.0,), calibrate=True).evaluations
    assert "level fit" in ev.calibration and "full fit was refused" in ev.calibration
    (before,), (after,) = ev.fix_rows_before, ev.fix_rows
    assert after.failed == 0
    assert before.failed == before.n or before.fix_median_m > 5.0 * after.fix_median_m

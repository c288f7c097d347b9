"""The magnetometer's alignment to the body (companion/nav/alignment.py, issue 47.2's direction bias).

A rotation applied to the real log171.bin's magnetometer is recovered by the replay's calibration
step; a vehicle that never turned is refused; the companion applies MAG_ROT_* after MAG_OFS/SCALE/SOFT.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from companion.frames import mats_nb_from_euler
from companion.nav.alignment import AlignmentRefused, fit_alignment, rotation_matrix
from companion.params import CompanionConfig, default_values
from companion.process.settings import mag_calibration
from fcmpc.replay.calibrate import calibrate_boot
from fcmpc.replay.reading import read_boots

FIELD_NED = np.array([20000.0, 5000.0, -50000.0])
MOUNTING_DEG = (2.0, -3.0, 0.0)     # a bracket two and three degrees off


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle of the rotation between two rotation matrices."""
    return math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(a.T @ b) - 1.0) / 2.0))))


def _sensor(yaw: np.ndarray, rotation_deg, roll: float = 0.0) -> np.ndarray:
    """What a magnetometer mounted ``rotation_deg`` off reads of FIELD_NED at these headings."""
    body = np.einsum("kji,kj->ki", mats_nb_from_euler(np.full_like(yaw, roll), np.zeros_like(yaw), yaw),
                     np.tile(FIELD_NED, (len(yaw), 1)))
    return body @ np.array(rotation_matrix(rotation_deg))   # R^T b, as rows


@pytest.mark.parametrize("axes, rotation", [("xy", MOUNTING_DEG), ("xyz", (2.0, -3.0, 4.0))])
def test_a_rotation_is_recovered_over_a_full_turn(axes: str, rotation) -> None:
    yaw = np.linspace(0.0, 2 * math.pi, 200, endpoint=False)
    zero = np.zeros_like(yaw)
    fit = fit_alignment(_sensor(yaw, rotation), zero, zero, yaw, FIELD_NED, axes=axes)
    assert fit.rotation_deg == pytest.approx(rotation, abs=1e-6)
    assert fit.residual_deg < 1e-6 < fit.before_deg
    assert fit.information[0] > 0.1   # even headings: every fitted angle seen (yaw moves the field by cos I)


def test_one_heading_cannot_tell_a_tilt_and_is_refused() -> None:
    yaw = np.full(300, 0.3) + np.random.default_rng(0).normal(0.0, 0.002, 300)
    zero = np.zeros_like(yaw)
    with pytest.raises(AlignmentRefused, match="leave an angle unseen"):
        fit_alignment(_sensor(yaw, MOUNTING_DEG), zero, zero, yaw, FIELD_NED)


def test_the_companion_applies_mag_rot_after_the_soft_iron() -> None:
    values = dict(default_values(), MAG_OFS_X=10.0, MAG_ROT_ROLL=MOUNTING_DEG[0], MAG_ROT_PIT=MOUNTING_DEG[1])
    cal = mag_calibration(CompanionConfig.from_values(values))
    raw = np.array([21000.0, 4000.0, -48000.0])
    expected = np.array(rotation_matrix(MOUNTING_DEG)) @ (raw - (1000.0, 0.0, 0.0))   # 10 mG = 1000 nT
    assert np.allclose(cal.apply(tuple(raw)), expected)


def test_replay_calibration_recovers_a_rotation_applied_to_log171(log171: Path) -> None:
    """log171's magnetometer turned by MOUNTING_DEG: the replay's calibration (hard/soft iron, then
    the xy alignment, on every sample) finds the log's own alignment composed with it, within 0.2 deg;
    without the alignment the rotation stays in the field it replays (measured 3.6 deg)."""
    (data,) = read_boots(log171)
    turned = dataclasses.replace(data, mag=np.column_stack([data.mag[:, 0], data.mag[:, 1:]
                                                            @ np.array(rotation_matrix(MOUNTING_DEG))]))
    own, cal = calibrate_boot(data), calibrate_boot(turned)
    assert own.alignment is not None and cal.alignment is not None
    expected = np.array(own.alignment.matrix) @ np.array(rotation_matrix(MOUNTING_DEG))
    assert _angle_deg(np.array(cal.alignment.matrix), expected) < 0.2
    # what each replays: the turned log's corrected field is the log's own, within 0.2 deg
    m = data.mag[::10, 1:]
    w_own, w_turned = np.array(own.calibration.soft_iron), np.array(cal.calibration.soft_iron)
    a = (m - own.calibration.offset_nt) @ w_own.T
    b = (m @ np.array(rotation_matrix(MOUNTING_DEG)) - cal.calibration.offset_nt) @ w_turned.T
    cosine = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    assert math.degrees(float(np.arccos(np.clip(cosine, -1.0, 1.0)).max())) < 0.2

"""The magnetometer's alignment to the body (companion/nav/alignment.py, issue 47.2's direction bias).

A known rotation is recovered from a full turn; a vehicle that never turned is refused; the
companion applies MAG_ROT_* after MAG_OFS/SCALE/SOFT. The recovery on the real log171.bin is in
tests/replay/test_calibrate.py.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.frames import mats_nb_from_euler
from companion.nav.alignment import AlignmentRefused, fit_alignment, rotation_matrix
from companion.params import CompanionConfig, default_values
from companion.process.settings import mag_calibration

FIELD_NED = np.array([20000.0, 5000.0, -50000.0])
MOUNTING_DEG = (2.0, -3.0, 0.0)     # a bracket two and three degrees off


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

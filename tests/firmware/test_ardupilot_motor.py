"""ArduPilot's compass with motor interference on our world's boat (``--physics json``), and its compensation.

SITL adds ``SIM_MAG_MOT`` times the physics backend's battery current to the body field
(``Aircraft::update_mag_field_bf``), and the shared binary's JSON backend sets no current: before this,
the field did not move with the throttle at all (the same run-up fitted +0.07 mGauss/A for -0.71). Our
world now puts that field on the compass through ``SIM_MAG1_OFS`` (:mod:`sitl.physics.motor_field`;
docs/notes/2026-12-06-ardupilot-json-lockstep.md, section 9).
"""
from __future__ import annotations

import pytest

from fcmpc.firmware.ardupilot_json_rig import motor_field
from fcmpc.firmware.compass import ARDUPILOT_REAL, calibrate_motor_interference, measure_motor_interference
from tests.firmware.test_ardupilot_json import WALL_S, json_rig  # noqa: F401  (the fixture)

SIM_MAG_MOT = (ARDUPILOT_REAL["SIM_MAG_MOT_X"], ARDUPILOT_REAL["SIM_MAG_MOT_Y"], ARDUPILOT_REAL["SIM_MAG_MOT_Z"])
# tolerance of the fitted change per ampere, each axis: the compass's soft iron (uncorrected here: DIA
# 0.996-1.008, ODI up to 0.018) scales SIM_MAG_MOT by up to 2 % (0.02 mGauss/A), the noise (SIM_MAG_RND 2.6
# mGauss) and what the roll and pitch regressors leave of the waves over ~800 samples add about as much
TOLERANCE_MGAUSS_PER_A = 0.05


def test_the_motor_moves_ardupilots_compass_and_the_mooring_run_up_recovers_sim_mag_mot(json_rig):
    """The real compass (SIM_MAG_MOT -0.71, -0.14, +0.68 mGauss/A) on our world: a throttle run-up on the
    mooring moves ArduPilot's corrected field (RAW_IMU) with its battery monitor's current (SYS_STATUS,
    0 to 50 A) by SIM_MAG_MOT per ampere; COMPASS_MOT (= -SIM_MAG_MOT) set from it, a second run-up sees
    the field stay within a tenth of that."""
    params, field = motor_field({**ARDUPILOT_REAL, "GPS2_TYPE": 0})
    rig = json_rig("motor", params=params, relay=False, motor_field=field)
    mon = rig.monitor
    mon.pump(lambda m: m.time_s > 20.0, WALL_S, "the compass running")
    fit = calibrate_motor_interference(mon, WALL_S)
    words = fit.words()
    assert fit.current_span_a[0] < 1.0 and fit.current_span_a[1] > 45.0, fit
    for got, sim in zip(fit.per_amp, SIM_MAG_MOT):
        assert got == pytest.approx(sim, abs=TOLERANCE_MGAUSS_PER_A), (words, fit)
    params = mon.read_params(("COMPASS_MOTCT", "COMPASS_MOT_X", "COMPASS_MOT_Y", "COMPASS_MOT_Z"), WALL_S)
    assert params["COMPASS_MOTCT"] == 2
    after = measure_motor_interference(mon, WALL_S)
    assert max(abs(v) for v in after.per_amp) < 0.1 * max(abs(v) for v in SIM_MAG_MOT), after

"""The companion against real PX4 SITL with SIH: GPS lost after start-up (issue 15).

Not in CI since 2026-12-06 (``FCMPC_PX4_SIH_GPS_LOST=1`` runs it): the lockstep test of the same
claim (``test_px4_hil.py``) replaced it there. This one is wall-paced (30 simulated minutes at 5x,
419 s in CI, CI's longest test, and a loaded machine starved PX4's offboard link); SIH's own physics
stays checked in CI by the quadrant tests (``test_px4.py``).
"""
from __future__ import annotations

import os

import pytest

from tests.firmware.conftest import commands_flown
from tests.firmware.test_px4 import OFFBOARD, PROBE_S, ROVER_MIN_SPEED, WALL_S


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("FCMPC_PX4_SIH_GPS_LOST") != "1",
                    reason="wall-paced SIH GPS-lost test: replaced in CI by test_px4_hil.py's lockstep one; "
                           "FCMPC_PX4_SIH_GPS_LOST=1 runs it")
def test_gps_lost_after_start_up_offboard_kept_and_on_course(px4_factory):
    """SIH's receiver loses its fix 30 s after arming (SIM_GPS_USED 0): the companion feeds HIL_GPS,
    EKF2 keeps a position, PX4 stays in OFFBOARD for 30 simulated minutes and the true track follows
    the companion's courses.

    What it does not judge: where those courses lead. On SIH a period's fix scatters by tens of km
    (one run, 415 s wall at 8x: 11 steps, none excluded, fixes 20-189 km from the prediction, the
    distance to go wandering 79 -> 124-144 km; since the plausibility check judges a jump against
    Table 3's own covariance, 1-4 of the 11 periods are excluded and fly the last command on), so
    the mission flies, but not toward its destination."""
    from fcmpc.firmware.px4_rig import deny_gps

    # 8x, not 12x: HIL_GPS must keep coming through a loaded machine's stalls (EKF2_NOAID_TOUT of
    # simulated time); one run at 12x on a machine at load 16 lost the feed for over 5 s at GPS loss
    # 5x: at 8x, beside a PX4 flight and other sessions' runs (load 3-6), two runs lost the onboard link
    # ("Connection to mission computer lost") and PX4 failed safe, at 400 s and at 1800 s after the loss,
    # with either start-up average (30 s or 160 s); SIH runs at about 1x until armed, so the rig's 30 s
    # start-up pays for most of the slower factor
    rig = px4_factory("gps_lost", speed=5.0)
    log_dir = rig.start_companion(NAV_DEST_LAT=32.5, NAV_DEST_LON=152.6, NAV_PERIOD_S=PROBE_S)
    mon = rig.monitor
    mon.pump(lambda m: m.armed and m.mode == OFFBOARD, WALL_S, "armed in OFFBOARD")
    t_arm = mon.time_s
    mon.pump(lambda m: m.time_s >= t_arm + 30.0, WALL_S, "30 s after arming")
    deny_gps(mon)
    mon.pump(lambda m: m.truth and m.truth[-1].gps_fix < 3, WALL_S, "GPS lost")
    t_lost = mon.time_s
    # on the truth's clock: HIL_STATE_QUATERNION (1 Hz) lags SYSTEM_TIME, and the last truth sample is judged
    mon.pump(lambda m: (m.truth and m.truth[-1].time_s >= t_lost + 1800.0) or m.mode != OFFBOARD or not m.armed,
             8 * WALL_S, "30 minutes without GPS")
    after = [s for s in mon.truth if s.time_s >= t_lost]
    said = (rig.tmp / "companion.err").read_text(errors="replace")[-1500:]
    left = next((s for s in after if s.mode != OFFBOARD or not s.armed), None)
    assert left is None, f"left OFFBOARD {left.time_s - t_lost:.0f} s after GPS loss: {mon.texts[-6:]}\n{said}"
    assert after[-1].time_s - t_lost >= 1800.0, f"left OFFBOARD (mode {mon.mode:#x}): {mon.texts[-6:]}\n{said}"
    assert mon.texts_matching("feeding our position (HIL_GPS)", 191)
    # a command holds until the next step: a period whose fix the plausibility check excludes flies
    # the last command on (on SIH, where fixes scatter by 100-200 km, 1-4 of 11 periods are excluded)
    flown_s, commands, off_deg = commands_flown(log_dir / "steps.csv", mon.truth, t_lost, after[-1].time_s,
                                                ROVER_MIN_SPEED)
    # EKF2's yaw follows the fed track after the loss (the true track ran 14-20 deg off the course
    # before the companion steered its own measured heading, COMP_TRIM_DEG): judged on the median
    assert off_deg and off_deg[len(off_deg) // 2] < 5.0, f"true track off the course by {off_deg[len(off_deg) // 2]:.1f} deg (median)"
    # 1800 s less the command in force at the loss (up to one 160 s period) and a last one under 60 s
    assert flown_s >= 1500.0, f"only {flown_s:.0f} s flown on commanded courses without GPS"
    assert commands >= 5, f"only {commands} commands without GPS: the navigator stopped stepping"

"""The companion against real PX4 in lockstep with our world (``sitl.physics.px4_hil``): GPS lost after start-up.

Meant to replace the SIH test of the same claim (``test_px4_gps_lost.py``: GPS lost after start-up,
OFFBOARD kept, the true track on the companion's courses; 30 simulated minutes at 5x, 425 s in CI,
CI's longest): here PX4's clock advances only with our frames and our world waits for the companion,
so a loaded machine slows the run without changing what PX4 and the companion see. 20 minutes without
GPS took 118 s of wall time at load average 20 on 2 cores when it passed. Not yet in CI
(``FCMPC_PX4_HIL=1`` runs it): of six runs it passed two (one in our seaway with the compass's drawn
residuals, one in a calm sea without them) and four times PX4 failed safe 680-940 s after the loss
("High Accelerometer Bias", once "Attitude failure (pitch)"): with the seaway and no compass residuals,
and twice in a calm sea with them; so the SIH test stays until EKF2's drift without GPS on our world is
understood.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.params import write_parm_file
from fcmpc.firmware.monitor import FirmwareMonitor
from tests.firmware.conftest import REPO, Rig, _px4_root_or_skip, commands_flown
from tests.firmware.test_px4 import OFFBOARD, PROBE_S, ROVER_MIN_SPEED

WALL_S = 600.0            # per wait; a lockstep run is slower on a loaded machine, never different
LOST_S = 1200.0           # simulated seconds flown without GPS: seven commands of PROBE_S


class HilRig(Rig):
    """PX4 (simulator_mavlink) + the bridge as its physics + the monitor on its GCS link + the companion."""

    quiet = False

    def __init__(self, tmp_path: Path, seed: int = 0) -> None:
        from sitl.clock import LockstepGate
        from fcmpc.firmware.px4 import Px4Sitl, free_px4_instance
        from fcmpc.firmware.px4_rig import HIL_GATE_TIMEOUT_S, HIL_LOCKSTEP_PERIOD_S, HIL_VALUES, MONITOR_RATES_HZ
        from sitl.physics.px4_hil import Px4HilBridge, hil_params, hil_world
        from sitl.scenario import load_scenario

        self.tmp = tmp_path
        root = _px4_root_or_skip()
        instance = free_px4_instance(first=1 + os.getpid() % 9)
        scenario = load_scenario("pacific")
        world = hil_world(scenario, seed)
        self.bridge = Px4HilBridge(instance, world, scenario.start_posix,
                                   LockstepGate(HIL_LOCKSTEP_PERIOD_S, timeout_s=HIL_GATE_TIMEOUT_S))
        self.sitl = Px4Sitl(workdir=tmp_path / "px4", instance=instance, root=root, simulator="mavlink",
                            params={**HIL_VALUES, **hil_params(world.dynamics)})
        self.companion = None
        self.monitor = None
        self.bridge.listen()
        self.sitl.start()
        self.bridge.start()
        self.monitor = FirmwareMonitor(self.sitl.gcs_url, rates_hz=MONITOR_RATES_HZ)
        self.monitor.start()

    def start_companion(self, startup_s: float | None = 30.0, **values) -> Path:
        from fcmpc.firmware.px4_rig import COMPANION_VALUES

        parm = self.tmp / "companion.parm"
        write_parm_file(parm, {"NAV_START_LAT": 33.0, "NAV_START_LON": 152.0, "COMP_ARM_ENABLE": 1,
                               **COMPANION_VALUES, **values})
        log_dir = self.tmp / "companion"
        self.companion = subprocess.Popen(
            [sys.executable, "-m", "companion.app", "--connect", self.bridge.companion_url, "--params", str(parm),
             "--log-dir", str(log_dir), "--lockstep", "--startup-s", f"{startup_s:g}"],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=open(self.tmp / "companion.err", "wb"))
        return log_dir

    def close(self) -> None:
        super().close()
        self.bridge.stop()


@pytest.fixture
def hil_rig(tmp_path):
    rig = HilRig(tmp_path / "hil")
    yield rig
    rig.close()


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("FCMPC_PX4_HIL") != "1",
                    reason="PX4 lockstep GPS-lost: not yet reliable (PX4 failsafe after ~13 min without GPS); "
                           "FCMPC_PX4_HIL=1 runs it")
def test_gps_lost_after_start_up_offboard_kept_and_on_course_in_lockstep(hil_rig):
    """Our world's receiver loses its fix 30 s after arming (HIL_GPS fix_type 0): the companion feeds
    HIL_GPS, EKF2 keeps a position, PX4 stays in OFFBOARD for 20 simulated minutes, every frame was
    answered (no actuator or companion timeout) and the true track follows the companion's courses."""
    rig = hil_rig
    log_dir = rig.start_companion(NAV_DEST_LAT=32.5, NAV_DEST_LON=152.6, NAV_PERIOD_S=PROBE_S)
    mon = rig.monitor
    mon.pump(lambda m: m.armed and m.mode == OFFBOARD, WALL_S, "armed in OFFBOARD")
    t_arm = mon.time_s
    mon.pump(lambda m: m.time_s >= t_arm + 30.0, WALL_S, "30 s after arming")
    rig.bridge.deny_gps()
    mon.pump(lambda m: m.truth and m.truth[-1].gps_fix < 3, WALL_S, "GPS lost")
    t_lost = mon.time_s
    mon.pump(lambda m: (m.truth and m.truth[-1].time_s >= t_lost + LOST_S) or m.mode != OFFBOARD or not m.armed,
             WALL_S, "20 minutes without GPS")
    after = [s for s in mon.truth if s.time_s >= t_lost]
    said = (rig.tmp / "companion.err").read_text(errors="replace")[-1500:]
    left = next((s for s in after if s.mode != OFFBOARD or not s.armed), None)
    assert left is None, f"left OFFBOARD {left.time_s - t_lost:.0f} s after GPS loss: {mon.texts[-6:]}\n{said}"
    assert after[-1].time_s - t_lost >= LOST_S
    assert mon.texts_matching("feeding our position (HIL_GPS)", 191)
    stats = rig.bridge.stats()
    assert stats["hil_actuator_timeouts"] == 0 and stats["lockstep_timeouts"] == 0, stats
    flown_s, commands, off_deg = commands_flown(log_dir / "steps.csv", mon.truth, t_lost, after[-1].time_s,
                                                ROVER_MIN_SPEED)
    median = off_deg[len(off_deg) // 2] if off_deg else float("nan")
    assert median < 5.0, f"true track off the course by {median:.1f} deg (median)"
    assert flown_s >= LOST_S - 2 * PROBE_S, f"only {flown_s:.0f} s flown on commanded courses without GPS"
    assert commands >= 5, f"only {commands} commands without GPS: the navigator stopped stepping"

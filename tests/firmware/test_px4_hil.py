"""The companion against real PX4 in lockstep with our world (``sitl.physics.px4_hil``): GPS lost after start-up.

In CI in place of the SIH test of the same claim (``test_px4_gps_lost.py``: GPS lost after start-up,
OFFBOARD kept, the true track on the companion's courses for 30 simulated minutes; 419 s in CI at 5x,
wall-paced, so a loaded machine failed it): here PX4's clock advances only with our frames and our
world waits for the companion, so a loaded machine slows the run without changing what PX4 and the
companion see. Until 2026-12-06 it passed 2 of 6 runs (EKF2's "High Accelerometer Bias" and a
failsafe 680-940 s after the loss); the causes and the fixes, measured, are in
docs/notes/2026-12-06-px4-hil-lockstep.md (the feed turns as the boat does and claims 1 m, the gyro
senses the Earth's rotation, PX4's FIFO truncation rounds).
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.params import write_parm_file
from fcmpc.firmware.monitor import FirmwareMonitor
from tests.firmware.conftest import REPO, Rig, _px4_root_or_skip, claim_instance, commands_flown
from tests.firmware.test_px4 import OFFBOARD, PROBE_S, ROVER_MIN_SPEED

WALL_S = 900.0            # per wait; a lockstep run is slower on a loaded machine, never different
LOST_S = 1800.0           # simulated seconds flown without GPS, as the SIH test: eleven commands of PROBE_S


class HilRig(Rig):
    """PX4 (simulator_mavlink) + the bridge as its physics + the monitor on its GCS link + the companion."""

    quiet = False

    def __init__(self, tmp_path: Path, seed: int = 0) -> None:
        from sitl.clock import LockstepGate
        from fcmpc.firmware.px4 import MAX_INSTANCE, Px4Sitl
        from fcmpc.firmware.px4_rig import HIL_GATE_TIMEOUT_S, HIL_LOCKSTEP_PERIOD_S, HIL_VALUES, MONITOR_RATES_HZ
        from sitl.physics.px4_hil import Px4HilBridge, hil_params, hil_world
        from sitl.scenario import load_scenario

        self.tmp = tmp_path
        root = _px4_root_or_skip()
        self.claims = contextlib.ExitStack()      # the instance, held until close()
        instance = claim_instance(self.claims, "px4", 1, MAX_INSTANCE, 1 + os.getpid() % 9)
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
        from sitl.physics.px4_hil import HIL_COMPANION_VALUES

        parm = self.tmp / "companion.parm"
        write_parm_file(parm, {"NAV_START_LAT": 33.0, "NAV_START_LON": 152.0, "COMP_ARM_ENABLE": 1,
                               **COMPANION_VALUES, **HIL_COMPANION_VALUES, **values})
        log_dir = self.tmp / "companion"
        self.companion = subprocess.Popen(
            [sys.executable, "-m", "companion.app", "--connect", self.bridge.companion_url, "--params", str(parm),
             "--log-dir", str(log_dir), "--lockstep", "--startup-s", f"{startup_s:g}"],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=open(self.tmp / "companion.err", "wb"))
        return log_dir

    def close(self) -> None:
        claims, self.claims = self.claims, contextlib.ExitStack()   # the instance: released after the bridge
        super().close()
        self.bridge.stop()
        claims.close()


@pytest.fixture
def hil_rig(tmp_path):
    rig = HilRig(tmp_path / "hil")
    yield rig
    rig.close()


@pytest.mark.slow
def test_gps_lost_after_start_up_offboard_kept_and_on_course_in_lockstep(hil_rig):
    """Our world's receiver loses its fix 30 s after arming (HIL_GPS fix_type 0): the companion feeds
    HIL_GPS, EKF2 keeps a position, PX4 stays in OFFBOARD for 30 simulated minutes, PX4 and the
    companion answered (all but a few frames; every lockstep boundary) and the true track follows the
    companion's courses."""
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
             2 * WALL_S, "30 minutes without GPS")
    after = [s for s in mon.truth if s.time_s >= t_lost]
    said = (rig.tmp / "companion.err").read_text(errors="replace")[-1500:]
    left = next((s for s in after if s.mode != OFFBOARD or not s.armed), None)
    assert left is None, f"left OFFBOARD {left.time_s - t_lost:.0f} s after GPS loss: {mon.texts[-6:]}\n{said}"
    assert after[-1].time_s - t_lost >= LOST_S
    assert mon.texts_matching("feeding our position (HIL_GPS)", 191)
    stats = rig.bridge.stats()
    # PX4 answered its frames (now and then a frame gets no output: 1-2 per 30 simulated minutes, 65,000-95,000
    # frames) and the companion every lockstep boundary
    assert stats["hil_actuator_timeouts"] * 10_000 < stats["hil_frames"] and stats["lockstep_timeouts"] == 0, stats
    # PX4 ran our two MAVLink links (params/px4-hil-mavlink.rc), not its own four
    links = [line.split("mode: ")[1].split(",")[0] for line in rig.sitl.log_path.read_text(errors="replace").splitlines()
             if "[mavlink] mode: " in line]
    assert links == ["Custom", "Onboard"], links
    flown_s, commands, off_deg = commands_flown(log_dir / "steps.csv", mon.truth, t_lost, after[-1].time_s,
                                                ROVER_MIN_SPEED)
    median = off_deg[len(off_deg) // 2] if off_deg else float("nan")
    assert median < 5.0, f"true track off the course by {median:.1f} deg (median)"
    # 1800 s less the command in force at the loss (up to one 160 s period) and a last one under 60 s
    assert flown_s >= 1500.0, f"only {flown_s:.0f} s flown on commanded courses without GPS"
    assert commands >= 5, f"only {commands} commands without GPS: the navigator stopped stepping"


def test_hil_instance_sources_our_mavlink_links_and_sih_keeps_px4s(tmp_path):
    """rcS sources px4-rc.mavlink from PATH: a simulator_mavlink instance's bin/ holds the rig's
    (GCS and onboard links only), an SIH instance's none (PX4's own in etc/)."""
    from fcmpc.firmware.px4 import HIL_LINKS_RC, Px4Sitl

    root = tmp_path / "px4root"
    (root / "bin").mkdir(parents=True)
    (root / "bin" / "px4").write_text("")
    (root / "bin" / "px4-mavlink").write_text("px4")
    for simulator in ("mavlink", "sih"):
        sitl = Px4Sitl(workdir=tmp_path / simulator, simulator=simulator)
        env = sitl.environment(root)
        assert env["PATH"].startswith(str(tmp_path / simulator / "bin"))
        ours = tmp_path / simulator / "bin" / "px4-rc.mavlink"
        assert ours.exists() == (simulator == "mavlink")
    text = (tmp_path / "mavlink" / "bin" / "px4-rc.mavlink").read_text()
    assert text == (REPO / "params" / HIL_LINKS_RC).read_text()
    starts = [line for line in text.splitlines() if line.startswith("mavlink start")]
    assert len(starts) == 2 and "-m custom" in starts[0] and "-m onboard" in starts[1], starts

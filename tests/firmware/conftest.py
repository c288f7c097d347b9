"""Real ArduPilot Rover SITL for the tests: one instance number and one work folder per test.

Skips with the reason when the binary is absent (``FCMPC_ARDUPILOT`` or ``../shared/ardupilot``);
CI has it. The monitor (a ground station on SERIAL0, where SITL waits for its first client)
connects first, the companion on SERIAL1, as on a vehicle with the companion on a telemetry port.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.params import write_parm_file
from sitl.firmware import ArduPilotSitl, FirmwareMissing, ardupilot_binary
from sitl.firmware.ardupilot import free_instance
from sitl.firmware.monitor import FirmwareMonitor

REPO = Path(__file__).resolve().parents[2]
_TAKEN: set[int] = set()     # instances this test session handed out (free_instance skips busy ports too)
# Wall-time pacing: the companion must answer in wall time (a setpoint at least every 3 s and
# GPS_INPUT every 0.1 s of firmware time, or ArduPilot stops / calls the GPS unhealthy), so a loaded
# 2-core machine needs margin: at 10x a stall of the companion must stay under 300 ms of wall time
# (150 ms at 20x; measured: at 40x with a load average of 12 the feed fell behind, at 20x one loaded
# CI run saw a setpoint gap).
SPEEDUP = 10.0
CRUISE_KMH = 28.8     # 8 m/s: the SITL motorboat's top speed is 10 m/s at full throttle


def _binary_or_skip() -> Path:
    try:
        return ardupilot_binary()
    except FirmwareMissing as err:
        pytest.skip(str(err))


class Rig:
    """ArduPilot + monitor + (later) the companion process of one test."""

    def __init__(self, tmp_path: Path, params: dict | None = None, speedup: float = SPEEDUP) -> None:
        self.tmp = tmp_path
        instance = free_instance(first=11 + (os.getpid() % 8) * 10, taken=_TAKEN)
        _TAKEN.add(instance)
        self.sitl = ArduPilotSitl(workdir=tmp_path / "ardupilot", instance=instance, speedup=speedup,
                                  params=params or {}, binary=_binary_or_skip())
        self.sitl.start()
        self.sitl.wait_listening()
        self.monitor = FirmwareMonitor(self.sitl.serial0)
        self.monitor.start()
        self.companion: subprocess.Popen | None = None

    def start_companion(self, **values) -> Path:
        parm = self.tmp / "companion.parm"
        base = {"NAV_START_LAT": 33.0, "NAV_START_LON": 152.0, "COMP_ARM_ENABLE": 1, "NAV_SPEED_KMH": CRUISE_KMH}
        write_parm_file(parm, {**base, **values})
        log_dir = self.tmp / "companion"
        self.companion = subprocess.Popen(
            [sys.executable, "-m", "companion.app", "--connect", self.sitl.serial1, "--params", str(parm),
             "--log-dir", str(log_dir), "--quiet"],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(self.tmp / "companion.err", "wb"))
        return log_dir

    def said(self, needle: str):
        """A condition for :meth:`FirmwareMonitor.pump`: the companion's STATUSTEXT containing ``needle``."""
        return lambda m: bool(m.texts_matching(needle, component=191))

    def close(self) -> None:
        if self.companion is not None and self.companion.poll() is None:
            self.companion.terminate()
            try:
                self.companion.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.companion.kill()
        self.monitor.close()
        self.sitl.stop()


@pytest.fixture
def rig_factory(tmp_path):
    rigs = []

    def make(name: str, params: dict | None = None, speedup: float = SPEEDUP) -> Rig:
        rig = Rig(tmp_path / name, params, speedup)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.close()


def bearing_deg(a, b) -> float:
    """Initial bearing from truth sample a to b, degrees from north clockwise."""
    from companion.nav.geo import geodesic_inverse

    return math.degrees(geodesic_inverse(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg)[1]) % 360.0


def angle_diff_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)

"""Real ArduPilot Rover SITL and PX4 SITL (SIH) for the tests: one instance number and one work folder per test.

Skips with the reason when the binary is absent (``FCMPC_ARDUPILOT`` or ``../shared/ardupilot``);
CI has it. The monitor (a ground station on SERIAL0, where SITL waits for its first client)
connects first, the companion on SERIAL1, as on a vehicle with the companion on a telemetry port.
"""
from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.params import write_parm_file
from fcmpc.firmware import ArduPilotSitl, FirmwareMissing, ardupilot_binary
from fcmpc.firmware.instances import claimed_instance
from fcmpc.firmware.monitor import FirmwareMonitor, write_truth_csv

REPO = Path(__file__).resolve().parents[2]
# pytest-xdist runs test modules in parallel workers (gw0, gw1, ...): each worker starts its search
# for a free instance in its own range (the claim makes sharing impossible; the ranges make it rare
# that one worker's claims make another search far)
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
# Wall-time pacing: the companion must answer in wall time (a setpoint at least every 3 s and
# GPS_INPUT every 0.1 s of firmware time, or ArduPilot stops / calls the GPS unhealthy), so a loaded
# 2-core machine needs margin: at 10x a stall of the companion must stay under 300 ms of wall time
# (150 ms at 20x; measured: at 40x with a load average of 12 the feed fell behind, at 20x one loaded
# CI run saw a setpoint gap).
SPEEDUP = 10.0
CRUISE_KMH = 28.8     # 8 m/s: the SITL motorboat's top speed is 10 m/s at full throttle


def claim_instance(claims: contextlib.ExitStack, kind: str, low: int, high: int, start: int) -> int:
    """An instance of firmware ``kind`` in ``low``..``high`` (from ``start`` on, round the range) whose
    ports nobody has bound, claimed (:func:`fcmpc.firmware.instances.claimed_instance`) until ``claims``
    closes: no other test, xdist worker, checkout or Monte Carlo run on this machine takes it meanwhile."""
    return claims.enter_context(claimed_instance(kind, low, high, start))


def _binary_or_skip() -> Path:
    try:
        return ardupilot_binary()
    except FirmwareMissing as err:
        pytest.skip(str(err))


class Rig:
    """ArduPilot + monitor + (later) the companion process of one test."""

    quiet = True      # the companion's own lines on stderr (companion.err) or not
    companion_args: tuple[str, ...] = ()    # more companion options (a lockstep rig: --lockstep)

    def __init__(self, tmp_path: Path, params: dict | None = None, speedup: float = SPEEDUP) -> None:
        self.tmp = tmp_path
        binary = _binary_or_skip()
        self.claims = contextlib.ExitStack()      # the instance, held until close()
        instance = claim_instance(self.claims, "ardupilot", 11, 99, 11 + (_WORKER % 4) * 20 + (os.getpid() % 2) * 10)
        self.sitl = ArduPilotSitl(workdir=tmp_path / "ardupilot", instance=instance, speedup=speedup,
                                  params=params or {}, binary=binary)
        self.sitl.start()
        self.sitl.wait_listening()
        self.monitor = FirmwareMonitor(self.sitl.serial0)
        self.monitor.start()
        self.companion: subprocess.Popen | None = None

    @property
    def companion_url(self) -> str:
        return self.sitl.serial1

    def start_companion(self, startup_s: float | None = None, **values) -> Path:
        """The companion on its port with these parameters; ``startup_s``: its stationary start-up
        average (``--startup-s``; default one NAV_PERIOD_S)."""
        parm = self.tmp / "companion.parm"
        base = {"NAV_START_LAT": 33.0, "NAV_START_LON": 152.0, "COMP_ARM_ENABLE": 1, "NAV_SPEED_KMH": CRUISE_KMH}
        write_parm_file(parm, {**base, **values})
        log_dir = self.tmp / "companion"
        self.companion = subprocess.Popen(
            [sys.executable, "-m", "companion.app", "--connect", self.companion_url, "--params", str(parm),
             "--log-dir", str(log_dir), *(["--quiet"] if self.quiet else []),
             *(["--startup-s", f"{startup_s:g}"] if startup_s is not None else []), *self.companion_args],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(self.tmp / "companion.err", "wb"))
        return log_dir

    def said(self, needle: str):
        """A condition for :meth:`FirmwareMonitor.pump`: the companion's STATUSTEXT containing ``needle``."""
        return lambda m: bool(m.texts_matching(needle, component=191))

    def close(self) -> None:
        self.write_records()
        if self.companion is not None and self.companion.poll() is None:
            self.companion.terminate()
            try:
                self.companion.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.companion.kill()
        if self.monitor is not None:
            self.monitor.close()
        self.stop_firmware()
        self.claims.close()

    def stop_firmware(self) -> None:
        self.sitl.stop()

    def write_records(self) -> None:
        """The monitor's truth (truth.csv) and texts (texts.txt) into the test's folder: what a failed
        run is diagnosed from (pytest keeps the last runs' folders)."""
        if self.monitor is None:
            return
        self.tmp.mkdir(parents=True, exist_ok=True)
        write_truth_csv(self.tmp / "truth.csv", self.monitor.truth)
        with open(self.tmp / "texts.txt", "w") as handle:
            handle.writelines(f"{t:.3f}\t{comp}\t{text}\n" for t, comp, text in self.monitor.texts)


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


def moving_pairs(truth, t0: float, t1: float, min_speed_mps: float = 3.0):
    """Pairs of truth samples 10 s apart inside [t0, t1] while the vehicle moves."""
    from companion.nav.geo import geodesic_distance_m

    samples = [s for s in truth if t0 <= s.time_s <= t1]
    pairs = []
    for a in samples:
        b = next((s for s in samples if s.time_s >= a.time_s + 10.0), None)
        if b is None:
            break
        if geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg) / (b.time_s - a.time_s) >= min_speed_mps:
            pairs.append((a, b))
    return pairs


def assert_forward_on(truth, t0: float, t1: float, course_deg: float, min_speed_mps: float = 3.0) -> list[float]:
    """The true track between t0 and t1 follows ``course_deg`` within 15 deg, heading first; returns
    each judged pair's track error (deg)."""
    pairs = moving_pairs(truth, t0, t1, min_speed_mps)
    assert len(pairs) >= 5, f"vehicle did not move on course {course_deg} between {t0:.0f} and {t1:.0f} s"
    errors = []
    for a, b in pairs:
        track = bearing_deg(a, b)
        errors.append(angle_diff_deg(track, course_deg))
        assert errors[-1] < 15.0, f"track {track:.0f} deg, commanded {course_deg:.0f} deg"
        assert angle_diff_deg(a.yaw_deg, track) < 30.0, f"heading {a.yaw_deg:.0f} deg against track {track:.0f}: reversing"
    return errors


def commands_flown(steps_csv: Path, truth, t_lost: float, t_end: float, min_speed_mps: float):
    """The companion's commands from ``t_lost`` on, each judged on the true track (``assert_forward_on``;
    a command shorter than 60 s is skipped): (seconds flown on them, how many, sorted track errors in deg).
    A command holds until the next step: a period whose fix the plausibility check excludes flies the
    last command on."""
    from companion.io.records import read_steps_csv

    steps = [r for r in read_steps_csv(steps_csv) if r["event"] == "step"]
    ends = [following["msg_time_s"] for following in steps[1:]] + [t_end]
    flown_s, commands, off_deg = 0.0, 0, []
    for step, end in zip(steps, ends):
        start = step["msg_time_s"]
        if start < t_lost or end - start < 60.0:
            continue
        off_deg += assert_forward_on(truth, start + 20.0, end, step["course_deg"], min_speed_mps)
        flown_s, commands = flown_s + end - start, commands + 1
    return flown_s, commands, sorted(off_deg)


# --- PX4 SITL with SIH ---------------------------------------------------------------------------
# PX4's speed factor: simulated seconds per wall second. The companion must keep PX4's offboard
# link fed in wall time (COM_OF_LOSS_T of simulated time), so the tests set that timeout to
# PX4_LOSS_WALL_S of wall time at this factor, as PX4's own rcS does (factor x 1 s) but with more
# margin for a loaded 2-core machine.
PX4_SPEED = 12.0
PX4_LOSS_WALL_S = 2.0
# The companion's stationary start-up average against PX4: SIH runs at about 1x until the rover arms,
# whatever its speed factor, so the default (one NAV_PERIOD_S, 160 s) cost ~165 s of wall time per test;
# 30 s at SIH's 50 Hz (COMP_MAG_HZ in px4_flight.COMPANION_VALUES) are 1500 samples, as many as the
# 160 s at 10 Hz the fix-judging tests needed for the start's I calibration (at 10 Hz, 300 samples took
# SIH's 0.2-0.3 deg noise into it)
PX4_STARTUP_S = 30.0


def _px4_root_or_skip() -> Path:
    from fcmpc.firmware.px4 import px4_root

    try:
        return px4_root()
    except FirmwareMissing as err:
        pytest.skip(str(err))


class Px4TestRig(Rig):
    """PX4 SIH + a monitor on its ground-station link + (later) the companion on its onboard link."""

    quiet = False     # PX4 forwards the companion's texts to the monitor, but a failing test wants them all

    def __init__(self, tmp_path: Path, params: dict | None = None, speed: float = PX4_SPEED,
                 monitor: bool = True) -> None:
        from fcmpc.firmware.px4 import MAX_INSTANCE, Px4Sitl
        from fcmpc.firmware.px4_rig import MONITOR_RATES_HZ

        self.tmp = tmp_path
        root = _px4_root_or_skip()
        self.claims = contextlib.ExitStack()
        instance = claim_instance(self.claims, "px4", 1, MAX_INSTANCE, 1 + (_WORKER % 4) * 2 + os.getpid() % 2)
        self.loss_timeout_s = PX4_LOSS_WALL_S * speed
        self.sitl = Px4Sitl(workdir=tmp_path / "px4", instance=instance, speed_factor=speed, root=root,
                            params={"COM_OF_LOSS_T": self.loss_timeout_s, **(params or {})})
        self.sitl.start()
        self.monitor = None
        if monitor:   # PX4's GCS link answers its first client only: a test may want another one there
            self.monitor = FirmwareMonitor(self.sitl.gcs_url, rates_hz=MONITOR_RATES_HZ)
            self.monitor.start()
        self.companion: subprocess.Popen | None = None

    @property
    def companion_url(self) -> str:
        return self.sitl.companion_url

    def start_companion(self, startup_s: float | None = PX4_STARTUP_S, **values) -> Path:
        from fcmpc.firmware.px4_rig import COMPANION_VALUES   # the companion as fcmpc-fly --fc px4 flies it

        return super().start_companion(startup_s, **{**COMPANION_VALUES, **values})


@pytest.fixture
def px4_factory(tmp_path):
    rigs = []

    def make(name: str, params: dict | None = None, speed: float = PX4_SPEED, monitor: bool = True) -> Px4TestRig:
        rig = Px4TestRig(tmp_path / name, params, speed, monitor)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.close()


def assert_guided_and_on_course_without_gps(monitor, log_dir: Path, t_lost: float, minutes: float = 30.0,
                                            guided: int = 15) -> None:
    """After GPS was lost at ``t_lost``: GUIDED and armed throughout ``minutes``, the companion feeding its
    position, and at least 10 of its steps flown on their course (from 60 s into each step: a reversal of
    course, 132 deg after ~310 deg in one CI run, is a turn of the boat that takes tens of seconds)."""
    from companion.io.records import read_steps_csv

    after = [s for s in monitor.truth if s.time_s >= t_lost]
    assert all(s.mode == guided and s.armed for s in after), \
        f"left GUIDED at {next(s.time_s for s in after if s.mode != guided or not s.armed) - t_lost:.0f} s"
    assert after[-1].time_s - t_lost >= 60.0 * minutes
    assert monitor.texts_matching("feeding our position", 191)
    steps = [r for r in read_steps_csv(log_dir / "steps.csv") if r["event"] == "step"]
    checked = 0
    for step, following in zip(steps, steps[1:]):
        start, end = step["msg_time_s"], following["msg_time_s"]
        if start < t_lost or end - start < 60.0:
            continue
        assert_forward_on(monitor.truth, start + 60.0, end, step["course_deg"])
        checked += 1
    assert checked >= 10, f"only {checked} steps flown without GPS"

"""One mission flown by the companion against real ArduPilot Rover SITL (``fcmpc-fly --fc ardupilot``).

The world is ArduPilot's own: its simulated boat (``--model motorboat``, waves, wind 3 m/s),
its magnetic field (ArduPilot's IGRF tables, not the navigator's WMM), its compass-derived yaw,
its EKF. The companion runs as a process on SERIAL1 with the scenario's start and destination;
a ground station on SERIAL0 (:class:`~sitl.firmware.monitor.FirmwareMonitor`) records the truth
(SIMSTATE), denies GPS the moment the vehicle arms (``SIM_GPS1_ENABLE 0``: GPS for start-up
only, as in the paper's scenario), and waits for the companion to end the mission and the boat
to come to rest. Records: ``truth.csv`` (firmware time, true position, mode, armed, GPS fix),
``companion/`` (steps.csv, summary.json, tlog), ``ardupilot/`` (its log and eeprom).
"""
from __future__ import annotations

import math
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from companion.params import write_parm_file
from sitl.firmware.ardupilot import ArduPilotSitl, ardupilot_binary
from sitl.firmware.compass import ardupilot_compass_params, calibrate_fixed_yaw
from sitl.firmware.monitor import FirmwareMonitor, write_truth_csv

__all__ = ["FirmwareFlight", "FirmwareRun", "fly_ardupilot", "fly_firmware", "BOAT_CRUISE_KMH", "ArduPilotRig"]

BOAT_CRUISE_KMH = 28.8      # 8 m/s: ArduPilot's SITL motorboat makes 10 m/s at full throttle
REST_SPEED_MPS = 0.3
REPO = Path(__file__).resolve().parents[2]


@dataclass
class FirmwareFlight:
    """What to fly: start, destination, companion parameters, and the firmware's pacing."""

    start: tuple[float, float]
    destination: tuple[float, float]
    out_dir: Path
    values: dict = field(default_factory=dict)     # companion parameters beyond start/destination
    speedup: float = 50.0
    instance: int = 0
    start_unix_s: float | None = None
    timeout_s: float = 7200.0
    deny_gps_at_arming: bool = True
    quiet: bool = False
    compass: str = "real"          # the firmware's compass: sitl.firmware.compass ("real" or "ideal")
    physics: str = "builtin"       # PX4: "builtin" (SIH) or "hil" (our world in lockstep, sitl.firmware.px4_hil)
    scenario: object = None        # the world of a "hil" flight (sitl.scenario.Scenario; default pacific)
    seed: int = 0
    current_en_mps: tuple[float, float] = (0.0, 0.0)   # our world as the physics (sitl.physics): its current (E, N)


@dataclass
class FirmwareRun:
    status: str            # arrived | failed | timeout | error | interrupted
    message: str
    truth: dict            # time_s, lat_deg, lon_deg lists (firmware time)
    wall_s: float
    companion_exit: int | None
    gps_denied_at_s: float = math.nan
    notes: tuple[str, ...] = ()     # what was done to the firmware before the companion started


def _say(flight: FirmwareFlight, text: str) -> None:
    if not flight.quiet:
        print(f"fcmpc-fly: {text}", file=sys.stderr, flush=True)


class ArduPilotRig:
    """ArduPilot's side of a flight: SITL, the monitor on SERIAL0, the companion on SERIAL1."""

    name = "ArduPilot SITL"

    def __init__(self, flight: FirmwareFlight, out: Path) -> None:
        self.compass = flight.compass
        self.sitl = ArduPilotSitl(workdir=out / "ardupilot", instance=flight.instance, home=flight.start,
                                  speedup=flight.speedup, start_unix_s=flight.start_unix_s, binary=ardupilot_binary(),
                                  params=ardupilot_compass_params(flight.compass))

    def start(self) -> FirmwareMonitor:
        self.sitl.start()
        self.sitl.wait_listening()
        monitor = FirmwareMonitor(self.sitl.serial0, rates_hz={"SIMSTATE": 1.0, "VFR_HUD": 1.0, "GPS_RAW_INT": 1.0})
        monitor.start()
        return monitor

    def prepare(self, monitor: FirmwareMonitor) -> list[str]:
        """Before the companion starts: a real compass is calibrated as a boat's user does it."""
        return [calibrate_fixed_yaw(monitor)] if self.compass == "real" else []

    companion_args: tuple[str, ...] = ()

    @property
    def companion_url(self) -> str:
        return self.sitl.serial1

    def deny_gps(self, monitor: FirmwareMonitor) -> None:
        monitor.set_param("SIM_GPS1_ENABLE", 0)

    def stop(self) -> None:
        self.sitl.stop()


def fly_ardupilot(flight: FirmwareFlight) -> FirmwareRun:
    """Fly one mission to its end; see the module docstring. Raises FirmwareMissing without a binary."""
    ardupilot_binary()                 # FirmwareMissing before anything is written
    return fly_firmware(flight, ArduPilotRig)


def fly_firmware(flight: FirmwareFlight, rig_class) -> FirmwareRun:
    """Fly one mission against the firmware ``rig_class(flight, out)`` starts (ArduPilot or PX4):
    the companion as a process on its port, the monitor recording the truth, GPS denied at arming."""
    out = Path(flight.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    parm = out / "fly.parm"
    write_parm_file(parm, {"NAV_START_LAT": flight.start[0], "NAV_START_LON": flight.start[1],
                           "NAV_DEST_LAT": flight.destination[0], "NAV_DEST_LON": flight.destination[1],
                           "COMP_ARM_ENABLE": 1, "NAV_SPEED_KMH": BOAT_CRUISE_KMH, **flight.values},
                    header=f"fcmpc-fly against {rig_class.name}")
    rig = rig_class(flight, out)
    wall0 = time.monotonic()
    companion = None
    monitor = None
    denied_at = math.nan
    status, message = "error", ""
    notes: list[str] = []
    # SIGTERM (a supervisor, `kill`, `timeout`) stops the flight as Ctrl-C does: the records and the
    # result are still written (it used to end the process with nothing but the companion's steps).
    # SIGINT gets the handler explicitly too: a job started in the background by a non-interactive
    # shell inherits SIGINT ignored, and `kill -INT` then did nothing (fcmpc-fly's stand-in path,
    # fcmpc.fly.runner._Interrupts, already installs its own)
    old_handlers = {signum: signal.signal(signum, _raise_interrupt) for signum in (signal.SIGINT, signal.SIGTERM)} \
        if threading.current_thread() is threading.main_thread() else {}
    try:
        monitor = rig.start()
        notes = rig.prepare(monitor)
        for note in notes:
            _say(flight, note)
        companion = subprocess.Popen(
            [sys.executable, "-m", "companion.app", "--connect", rig.companion_url, "--params", str(parm), "--log-dir",
             str(out / "companion"), "--exit-when-done", "--quiet", *getattr(rig, "companion_args", ())],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=open(out / "companion.log", "wb"))
        pace = "in lockstep" if getattr(rig, "companion_args", ()) else f"at {flight.speedup:g}x"
        _say(flight, f"{rig.name} instance {flight.instance} {pace}, companion on "
                     f"{rig.companion_url}; records in {out}")
        deadline = wall0 + flight.timeout_s
        last_report = 0.0

        def tick(m: FirmwareMonitor) -> bool:
            nonlocal denied_at, last_report
            if flight.deny_gps_at_arming and m.armed and not math.isfinite(denied_at):
                rig.deny_gps(m)
                denied_at = m.time_s
                _say(flight, f"armed at {m.time_s:.0f} s: GPS denied from take-off")
            if time.monotonic() - last_report > 30.0 and m.truth:
                last_report = time.monotonic()
                from companion.nav.geo import geodesic_distance_m

                s = m.truth[-1]
                _say(flight, f"{s.time_s / 3600.0:5.2f} h simulated, "
                             f"{geodesic_distance_m(s.lat_deg, s.lon_deg, *flight.destination) / 1000.0:.1f} km to go")
            return companion.poll() is not None

        monitor.pump(tick, max(deadline - time.monotonic(), 1.0), "the end of the mission")
        code = companion.returncode
        status, message = ("arrived", "") if code == 0 else ("failed", f"companion exited with {code}")
        # the vehicle coasts after the last step: wait until it is at rest (at most 120 s of firmware time)
        t_done = monitor.time_s
        monitor.pump(lambda m: m.time_s > t_done + 120.0 or _at_rest(m), 120.0, "the vehicle at rest")
    except TimeoutError as err:
        status, message = "timeout", str(err)
    except KeyboardInterrupt as err:   # Ctrl-C or SIGTERM: stop both, and still write the records and the result
        status, message = "interrupted", f"stopped by {err.args[0]}" if err.args else "interrupted by the user"
    except (RuntimeError, OSError) as err:
        status, message = "error", str(err)
    finally:
        if companion is not None and companion.poll() is None:
            companion.terminate()
            try:
                companion.wait(timeout=10)
            except subprocess.TimeoutExpired:
                companion.kill()
        if monitor is not None:
            monitor.close()
        rig.stop()
        for signum, handler in old_handlers.items():
            signal.signal(signum, handler)
    truth = _write_truth(out / "truth.csv", monitor.truth if monitor is not None else [])
    return FirmwareRun(status, message, truth, time.monotonic() - wall0,
                       companion.returncode if companion is not None else None, denied_at, tuple(notes))


def _raise_interrupt(signum: int, frame) -> None:  # noqa: ARG001
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _at_rest(monitor: FirmwareMonitor) -> bool:
    truth = monitor.truth
    if len(truth) < 6:
        return False
    from companion.nav.geo import geodesic_distance_m

    a, b = truth[-6], truth[-1]
    return geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg) / max(b.time_s - a.time_s, 1e-3) \
        < REST_SPEED_MPS


def _write_truth(path: Path, samples: list) -> dict:
    write_truth_csv(path, samples)
    return {"time_s": [s.time_s for s in samples], "lat_deg": [s.lat_deg for s in samples],
            "lon_deg": [s.lon_deg for s in samples]}

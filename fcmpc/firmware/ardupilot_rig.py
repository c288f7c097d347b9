"""ArduPilot Rover SITL with its own boat, a flight controller of the one runner (``fcmpc-fly --fc ardupilot``).

The world is ArduPilot's own: its simulated boat (``--model motorboat``, waves, wind 3 m/s),
its magnetic field (ArduPilot's IGRF tables, not the navigator's WMM), its compass-derived yaw,
its EKF. :class:`ArduPilotRig` is what is ArduPilot's: SITL in its own folder and instance, a
ground station on SERIAL0 (:class:`~fcmpc.firmware.monitor.FirmwareMonitor`: the truth is SIMSTATE),
the real compass's errors and its fixed-yaw calibration before the companion starts, the companion
on SERIAL1, GPS denied by ``SIM_GPS1_ENABLE 0``. The mission itself (the companion, GPS denied at
arming, the boat at rest, the records) is the one runner's (:mod:`fcmpc.fly.mission`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fcmpc.firmware.ardupilot import ArduPilotSitl, ardupilot_binary
from fcmpc.firmware.compass import ardupilot_compass_params, calibrate_fixed_yaw
from fcmpc.firmware.monitor import STARTUP_GUARD_S, FirmwareMonitor

__all__ = ["FirmwareFlight", "BOAT_CRUISE_KMH", "ArduPilotRig"]

BOAT_CRUISE_KMH = 28.8      # 8 m/s: ArduPilot's SITL motorboat makes 10 m/s at full throttle
REPO = Path(__file__).resolve().parents[2]


@dataclass
class FirmwareFlight:
    """What a firmware rig needs to start: where, at what pace, which instance, and the world of a
    lockstep flight (our world as the physics)."""

    start: tuple[float, float]
    speedup: float = 50.0
    instance: int = 0
    start_unix_s: float | None = None
    compass: str = "real"          # the firmware's compass: fcmpc.firmware.compass ("real" or "ideal")
    physics: str = "builtin"       # PX4: "builtin" (SIH) or "hil" (our world in lockstep, sitl.physics.px4_hil)
    scenario: object = None        # the world of a "hil" flight (sitl.scenario.Scenario; default pacific)
    seed: int = 0
    current_en_mps: tuple[float, float] = (0.0, 0.0)   # our world as the physics (sitl.physics): its current (E, N)


class ArduPilotRig:
    """ArduPilot's side of a flight: SITL, the monitor on SERIAL0, the companion on SERIAL1."""

    name = "ArduPilot SITL"
    default_speedup = 50.0

    @staticmethod
    def check() -> None:
        """FirmwareMissing (before anything is written) when the binary is absent."""
        ardupilot_binary()

    @staticmethod
    def companion_values(flight: FirmwareFlight) -> dict:
        """The companion's parameters for ArduPilot's boat: a real compass is calibrated by the
        companion's circles before the mission (COMP_CAL_TURNS); ArduPilot's own fixed-yaw
        calibration learns the offsets only (fcmpc/firmware/compass.py)."""
        return {"COMP_CAL_TURNS": 1} if flight.compass == "real" else {}

    def __init__(self, flight: FirmwareFlight, out: Path) -> None:
        self.compass = flight.compass
        self.sitl = ArduPilotSitl(workdir=out / "ardupilot", instance=flight.instance, home=flight.start,
                                  speedup=flight.speedup, start_unix_s=flight.start_unix_s, binary=ardupilot_binary(),
                                  params=ardupilot_compass_params(flight.compass))

    def start(self) -> FirmwareMonitor:
        self.sitl.start()
        self.sitl.wait_listening()
        monitor = FirmwareMonitor(self.sitl.serial0, rates_hz={"SIMSTATE": 1.0, "VFR_HUD": 1.0, "GPS_RAW_INT": 1.0})
        monitor.start(timeout_s=STARTUP_GUARD_S, alive=self.alive)
        return monitor

    def alive(self) -> bool:
        """Every process of the firmware's side runs (SITL; the JSON rig adds its world)."""
        return self.sitl.alive()

    def prepare(self, monitor: FirmwareMonitor) -> list[str]:
        """Before the companion starts: a real compass is calibrated as a boat's user does it."""
        return [calibrate_fixed_yaw(monitor)] if self.compass == "real" else []

    companion_args: tuple[str, ...] = ()

    @property
    def companion_url(self) -> str:
        return self.sitl.serial1

    def deny_gps(self, monitor: FirmwareMonitor) -> None:
        monitor.set_param("SIM_GPS1_ENABLE", 0)

    def companion_ended(self) -> None:
        """Nothing to release: the motorboat runs on the wall clock, and the JSON relay never waits
        for what the companion was not given."""

    def stop(self) -> None:
        self.sitl.stop()

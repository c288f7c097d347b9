"""Real flight-controller firmware as a flight controller of the one runner (``fcmpc-fly --fc ardupilot|px4``).

Each firmware's own start-up lives with it: :class:`fcmpc.firmware.ardupilot_rig.ArduPilotRig` (ArduPilot
Rover SITL with its motorboat), :class:`fcmpc.firmware.ardupilot_json_rig.ArduPilotJsonRig` (with our world as its
JSON physics, in lockstep), :class:`fcmpc.firmware.px4_rig.Px4Rig` (PX4 with SIH) and
:class:`~fcmpc.firmware.px4_rig.Px4HilRig` (with our world over HIL, in lockstep). A rig starts
the processes and hands back a ground-station monitor (:class:`~fcmpc.firmware.monitor.FirmwareMonitor`).
:class:`FirmwareFC` is what every rig has in common for the runner: it pumps the monitor (the
truth: SIMSTATE or HIL_STATE_QUATERNION), denies GPS the moment the vehicle arms (GPS for
start-up only, as in the paper's scenario), waits after the mission until the boat is at rest,
and writes ``truth.csv``. :func:`firmware_flight` turns the scenario and the user's options into
the rig and the companion's parameters.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from fcmpc.fly.results import TruthTrack
from fcmpc.firmware.ardupilot_rig import BOAT_CRUISE_KMH, FirmwareFlight
from fcmpc.firmware.monitor import FirmwareMonitor, write_truth_csv

__all__ = ["FirmwareFC", "SETTLE_SPEED_MPS", "firmware_flight"]

SETTLE_SPEED_MPS = 0.3      # slower than this over the last five truth samples: the boat is at rest
TRUTH_EVERY_S = 30.0        # wall seconds between the truth's progress lines (steps may stop: a boat in HOLD)
_MISSION = ("NAV_START_LAT", "NAV_START_LON", "NAV_DEST_LAT", "NAV_DEST_LON", "COMP_ARM_ENABLE", "COMP_SP_RATE_HZ")


class FirmwareFC:
    """A firmware rig (``rig_class(flight, out)``: ``start() -> monitor``, ``prepare(monitor) ->
    notes``, ``companion_url``, ``companion_args``, ``deny_gps(monitor)``, ``stop()``, ``name``) as
    a :class:`fcmpc.fly.mission.FlightController` flying to ``destination``; ``say``: where its notes
    go (GPS denied, and every :data:`TRUTH_EVERY_S` of wall time the true distance to go)."""

    def __init__(self, rig_class, flight: FirmwareFlight, destination: tuple[float, float],
                 deny_gps_at_arming: bool = True, say: Callable[[str], None] = lambda text: None) -> None:
        self.rig_class, self.flight, self.deny_gps_at_arming, self.say = rig_class, flight, deny_gps_at_arming, say
        self.destination = destination
        self._said_wall_s = 0.0
        self.name = rig_class.name
        self.companion_args = tuple(getattr(rig_class, "companion_args", ()))
        self.rig = None
        self.monitor: FirmwareMonitor | None = None
        self.denied_at_s = math.nan
        self.out: Path | None = None

    @property
    def companion_url(self) -> str:
        return self.rig.companion_url

    def start(self, out: Path) -> list[str]:
        self.out = Path(out)
        self.rig = self.rig_class(self.flight, self.out)
        self.monitor = self.rig.start()
        return self.rig.prepare(self.monitor)

    def companion_ready(self, pid: int) -> None:    # noqa: ARG002 - the firmware's world waits on its own gate
        pace = "in lockstep" if self.companion_args else f"at {self.flight.speedup:g}x"
        self.say(f"{self.name} instance {self.flight.instance} {pace}, companion on {self.companion_url}")

    def _tick(self, monitor: FirmwareMonitor) -> None:
        if self.deny_gps_at_arming and monitor.armed and not math.isfinite(self.denied_at_s):
            self.rig.deny_gps(monitor)
            self.denied_at_s = monitor.time_s
            self.say(f"armed at {monitor.time_s:.0f} s: GPS denied from take-off")
        if time.monotonic() - self._said_wall_s > TRUTH_EVERY_S and monitor.truth:
            from companion.nav.geo import geodesic_distance_m

            self._said_wall_s = time.monotonic()
            s = monitor.truth[-1]
            self.say(f"{s.time_s / 3600.0:5.2f} h simulated, "
                     f"{geodesic_distance_m(s.lat_deg, s.lon_deg, *self.destination) / 1000.0:.1f} km to go (true)")

    def wait(self, timeout_s: float) -> tuple[str, str] | None:
        deadline = time.monotonic() + timeout_s
        self.monitor.pump(lambda m: self._tick(m) or time.monotonic() >= deadline, timeout_s + 5.0, "the firmware")
        error = getattr(getattr(self.rig, "bridge", None), "error", None)     # PX4 over HIL: the bridge's thread
        return ("error", f"{self.name}: {error}") if error is not None else None

    def settle(self, timeout_s: float) -> None:
        """Until the boat is at rest or ``timeout_s`` of firmware time passed (TimeoutError after as
        much wall time)."""
        self.rig.companion_ended()
        t_done = self.monitor.time_s
        self.monitor.pump(lambda m: m.time_s > t_done + timeout_s or _at_rest(m), timeout_s, "the vehicle at rest")

    def stop(self) -> None:
        try:
            if self.monitor is not None:
                self.monitor.close()
        finally:
            if self.rig is not None:
                self.rig.stop()

    def truth(self) -> TruthTrack | None:
        samples = self.monitor.truth if self.monitor is not None else []
        if self.out is not None:
            write_truth_csv(self.out / "truth.csv", samples)
        if not samples:
            return None
        return TruthTrack(np.array([s.time_s for s in samples]), np.array([s.lat_deg for s in samples]),
                          np.array([s.lon_deg for s in samples]))


def _at_rest(monitor: FirmwareMonitor) -> bool:
    truth = monitor.truth
    if len(truth) < 6:
        return False
    from companion.nav.geo import geodesic_distance_m

    a, b = truth[-6], truth[-1]
    return geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg) / max(b.time_s - a.time_s, 1e-3) \
        < SETTLE_SPEED_MPS


# (--fc, --physics) -> "module:rig class"; each rig says how its firmware starts, its pace and the
# companion's parameters for it (check(), default_speedup, companion_values(flight), companion_args)
RIGS = {("ardupilot", "builtin"): "fcmpc.firmware.ardupilot_rig:ArduPilotRig",
        ("ardupilot", "json"): "fcmpc.firmware.ardupilot_json_rig:ArduPilotJsonRig",
        ("px4", "builtin"): "fcmpc.firmware.px4_rig:Px4Rig",
        ("px4", "hil"): "fcmpc.firmware.px4_rig:Px4HilRig"}


def firmware_flight(options, scenario, dest: tuple[float, float], values: dict,
                    say: Callable[[str], None] = lambda text: None) -> tuple[FirmwareFC, dict]:
    """The flight controller of ``options.fc`` (ardupilot or px4) with ``options.physics`` (:data:`RIGS`)
    and the companion's parameters for it (the scenario's start, ``dest``, the firmware's cruise, its
    rig's values, what the user set; the scenario's ``[navigator]`` table describes its simulated world,
    not the firmware's). FirmwareMissing (nothing written) when the firmware is absent; ValueError for a
    physics it has not."""
    import importlib

    spec = RIGS.get((options.fc, options.physics))
    if spec is None:
        choices = " or ".join(physics for fc, physics in RIGS if fc == options.fc) or "no physics"
        raise ValueError(f"physics {options.physics!r}: choose {choices} with --fc {options.fc}")
    module, name = spec.split(":")
    rig_class = getattr(importlib.import_module(module), name)
    rig_class.check()
    start = (scenario.start_lat_deg, scenario.start_lon_deg)
    flight = FirmwareFlight(start=start, speedup=options.speedup or rig_class.default_speedup,
                            instance=options.fc_instance, start_unix_s=scenario.start_posix, compass=options.compass,
                            physics=options.physics, scenario=scenario, seed=options.seed,
                            current_en_mps=_current(options, scenario))
    given = {**scenario.nav_overrides(navigator=False), **options.extra_params}
    companion = {"NAV_START_LAT": start[0], "NAV_START_LON": start[1], "NAV_DEST_LAT": dest[0],
                 "NAV_DEST_LON": dest[1], "COMP_ARM_ENABLE": 1, "NAV_SPEED_KMH": BOAT_CRUISE_KMH,
                 **rig_class.companion_values(flight),
                 **{k: v for k, v in values.items() if k not in _MISSION and k in given}}
    return FirmwareFC(rig_class, flight, dest, say=say), companion


def _current(options, scenario) -> tuple[float, float]:
    """The water's current of this seed in the scenario's world (our world as ArduPilot's JSON physics):
    the in-process flight's current for the same scenario and seed (:func:`sitl.world.vehicle.seed_motion_errors`)."""
    if options.physics != "json":
        return (0.0, 0.0)
    from sitl.world.vehicle import seed_motion_errors

    return seed_motion_errors(scenario.motion, options.seed).current_en_mps

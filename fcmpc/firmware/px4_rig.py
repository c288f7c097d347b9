"""One mission flown by the companion against real PX4 SITL with SIH (``fcmpc-fly --fc px4``).

The world is PX4's own: SIH's Ackermann rover, its magnetic field (PX4's WMM tables), EKF2 with
its magnetometer-derived yaw. PX4 starts at the mission's start (``SIH_LOC_LAT0/LON0``) with
``params/px4-rover.params``; the companion listens on PX4's onboard link (``udpin`` on
14540+N); a ground station on PX4's GCS link (:class:`~fcmpc.firmware.monitor.FirmwareMonitor`)
records SIH's ground truth (HIL_STATE_QUATERNION) and denies GPS when the vehicle arms
(``SIM_GPS_USED 0``: the simulated receiver reports no fix, as a jammed one does). These rigs are
what is PX4's (its start-up, parameters and physics); the mission is the one runner's
(:mod:`fcmpc.fly.mission`, through :class:`fcmpc.fly.firmware.FirmwareFC`).
"""
from __future__ import annotations

from pathlib import Path

from fcmpc.firmware.ardupilot_rig import BOAT_CRUISE_KMH, FirmwareFlight
from fcmpc.firmware.monitor import STARTUP_GUARD_S, FirmwareMonitor
from fcmpc.firmware.px4 import Px4Sitl, px4_root

__all__ = ["COMPANION_VALUES", "HIL_GATE_TIMEOUT_S", "HIL_LOCKSTEP_PERIOD_S", "HIL_VALUES", "MONITOR_RATES_HZ",
           "Px4HilRig", "Px4Rig", "deny_gps"]

# The companion's parameters against PX4 SIH, for the main job and the tests alike:
# NAV_SPEED_KMH 10.8 (3 m/s): SIH's Ackermann rover with params/px4-rover.params (RO_SPEED_LIM 3);
# COMP_HB_TMO_S / SAFE_TMO_S 10 s: the companion also judges a silent flight controller in wall
# time, and SIH on a shared 2-core machine was starved for over 3 s of it (a companion failsafe
# 80 s into a GPS-lost run; PX4's own offboard timeout is the one that matters);
# COMP_MAG_HZ 50: SIH makes 50 distinct magnetometer samples per second with 2000-3000 nT of noise
# per axis (ten times a real sensor's), and at 10 Hz four of five were thrown away (SCALED_IMU asked
# at 100 Hz repeats half of its samples);
# COMP_TRIM_DEG 30: after GPS loss EKF2's yaw follows our fed track and the rover's true track ran
# 14-20 deg off the command (companion.nav.steering); the companion steers its own measured heading
COMPANION_VALUES = {"NAV_SPEED_KMH": 10.8, "COMP_HB_TMO_S": 10.0, "SAFE_TMO_S": 10.0, "COMP_MAG_HZ": 50.0,
                    "COMP_TRIM_DEG": 30.0}

# The GCS link streams attitude and positions at 50 Hz: the monitor needs none of them but the
# time (GLOBAL_POSITION_INT, SYSTEM_TIME) and the truth, so the rest is turned off (rate 0).
MONITOR_RATES_HZ = {"HIL_STATE_QUATERNION": 1.0, "GPS_RAW_INT": 1.0, "SYSTEM_TIME": 1.0, "GLOBAL_POSITION_INT": 2.0,
                    "ATTITUDE": 0.0, "ATTITUDE_QUATERNION": 0.0, "ATTITUDE_TARGET": 0.0,
                    "POSITION_TARGET_LOCAL_NED": 0.0, "LOCAL_POSITION_NED": 0.0, "SERVO_OUTPUT_RAW": 0.0,
                    "RC_CHANNELS": 0.0}


def deny_gps(monitor: FirmwareMonitor) -> None:
    """SIH's receiver reports no fix from now on (``SIM_GPS_USED`` below 4 satellites)."""
    monitor.set_param_int32_bytewise("SIM_GPS_USED", 0)


class Px4Rig:
    """PX4's side of a flight: SIH, the monitor on the GCS link, the companion on the onboard link."""

    name = "PX4 SITL (SIH)"
    default_speedup = 10.0
    companion_args: tuple[str, ...] = ()

    @staticmethod
    def check() -> None:
        """FirmwareMissing (before anything is written) when PX4 is absent."""
        px4_root()

    @staticmethod
    def companion_values(flight: FirmwareFlight) -> dict:   # noqa: ARG004
        """SIH's Ackermann rover at 3 m/s, its magnetometer at 50 Hz (:data:`COMPANION_VALUES`)."""
        return dict(COMPANION_VALUES)

    def __init__(self, flight: FirmwareFlight, out: Path, params: dict | None = None) -> None:
        # COM_LOW_BAT_ACT 0: PX4's SITL rcS sets 3 (land), and SIH's simulated battery called it after
        # ~2 simulated hours of the 30 km leg (the rover disarmed mid-route); a flight's own battery
        # is not what this run measures (simulator only: params/px4-rover.params leaves it alone)
        self.sitl = Px4Sitl(workdir=out / "px4", instance=flight.instance, home=flight.start,
                            speed_factor=flight.speedup,
                            params={"COM_LOW_BAT_ACT": 0, **(params or {})}, root=px4_root())

    def start(self) -> FirmwareMonitor:
        self.sitl.start()
        return self._monitor()

    def _monitor(self) -> FirmwareMonitor:
        monitor = FirmwareMonitor(self.sitl.gcs_url, rates_hz=MONITOR_RATES_HZ)
        try:
            monitor.start(timeout_s=STARTUP_GUARD_S, alive=self.sitl.alive)
        except TimeoutError as err:
            raise RuntimeError(f"{err}; PX4 {'exited' if not self.sitl.alive() else 'runs'}, "
                               f"see {self.sitl.log_path}") from None
        return monitor

    def prepare(self, monitor: FirmwareMonitor) -> list[str]:   # noqa: ARG002
        """SIH's magnetometer keeps its own noise; nothing to calibrate before the companion starts."""
        return []

    @property
    def companion_url(self) -> str:
        return self.sitl.companion_url

    def deny_gps(self, monitor: FirmwareMonitor) -> None:
        deny_gps(monitor)

    def companion_ended(self) -> None:
        """Nothing to release: SIH runs on the wall clock and never waits for the companion."""

    def stop(self) -> None:
        self.sitl.stop()


# The world waits for the companion every 0.4 s of PX4's time (the stand-in's PX4 lockstep period);
# PX4's offboard-loss timeout (COM_OF_LOSS_T, simulated time) then keeps a margin over one period of slack
HIL_LOCKSTEP_PERIOD_S = 0.4
HIL_OFFBOARD_LOSS_S = 2.0
# Wall time the world waits for the companion at a boundary before going on alone: a control step on a
# machine at load 20 took over 5 s (PX4 then lost offboard 2 s of its time later, at 7x 0.3 s of wall time)
HIL_GATE_TIMEOUT_S = 120.0
# The ground station's heartbeats (the monitor's, 1 Hz of wall time) arrive every 5-20 s of PX4's time in
# lockstep: "Connection to ground station lost" every few seconds. The data link is not what a run
# measures; neither is the simulated battery (SIM_BAT_MIN_PCT 100: it never drains to a warning)
HIL_VALUES = {"COM_LOW_BAT_ACT": 0, "COM_OF_LOSS_T": HIL_OFFBOARD_LOSS_S, "COM_DL_LOSS_T": 300.0,
              "SIM_BAT_MIN_PCT": 100.0}


class Px4HilRig(Px4Rig):
    """PX4 in lockstep with our world (:mod:`sitl.physics.px4_hil`): the bridge is PX4's physics and
    relays its onboard link to the companion, which runs with ``--lockstep``; the monitor reads the
    truth PX4 forwards from the bridge (HIL_STATE_QUATERNION)."""

    name = "PX4 SITL (lockstep, our world)"
    companion_args = ("--lockstep",)

    @staticmethod
    def companion_values(flight: FirmwareFlight) -> dict:   # noqa: ARG004
        """The boat is ours (sitl.world.actuated, 10 m/s at full throttle): it cruises as ArduPilot's does,
        the feed turning as PX4 turns it there and claiming 1 m (:func:`sitl.physics.px4_hil.hil_companion_values`)."""
        from sitl.physics.px4_hil import hil_companion_values

        return {**COMPANION_VALUES, **hil_companion_values(BOAT_CRUISE_KMH / 3.6), "NAV_SPEED_KMH": BOAT_CRUISE_KMH}

    def __init__(self, flight: FirmwareFlight, out: Path, params: dict | None = None) -> None:
        from sitl.clock import LockstepGate
        from sitl.physics.px4_hil import Px4HilBridge, hil_params, hil_world
        from sitl.scenario import load_scenario

        scenario = flight.scenario if flight.scenario is not None else load_scenario("pacific")
        world = hil_world(scenario, flight.seed)
        self.sitl = Px4Sitl(workdir=out / "px4", instance=flight.instance, home=flight.start, simulator="mavlink",
                            params={**HIL_VALUES, **hil_params(world.dynamics), **(params or {})}, root=px4_root())
        self.bridge = Px4HilBridge(flight.instance, world, scenario.start_posix,
                                   LockstepGate(HIL_LOCKSTEP_PERIOD_S, timeout_s=HIL_GATE_TIMEOUT_S))

    def start(self) -> FirmwareMonitor:
        self.bridge.listen()
        self.sitl.start()
        self.bridge.start()
        return super()._monitor()

    @property
    def companion_url(self) -> str:
        return self.bridge.companion_url

    def deny_gps(self, monitor: FirmwareMonitor) -> None:   # noqa: ARG002
        self.bridge.deny_gps()

    def companion_ended(self) -> None:
        """The world stops waiting for the companion (its gate would hold PX4's clock for
        ``HIL_GATE_TIMEOUT_S`` of wall time at every boundary while the boat comes to rest)."""
        self.bridge.release_companion()

    def stop(self) -> None:
        """Stop PX4 and the bridge; the bridge's counts (frames, timeouts, lockstep waits) go to
        ``px4/hil_stats.json``."""
        self.sitl.stop()
        self.bridge.stop()
        import json

        (Path(self.sitl.workdir) / "hil_stats.json").write_text(json.dumps(self.bridge.stats(), indent=1))

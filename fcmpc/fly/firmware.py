"""``fcmpc-fly --fc ardupilot`` / ``--fc px4``: the main job against real flight-controller firmware.

The flight itself is :func:`sitl.firmware.flight.fly_ardupilot` (ArduPilot's own boat, field,
compass-derived yaw and EKF; GPS denied the moment the vehicle arms; SIMSTATE as the truth) or
:func:`sitl.firmware.px4_flight.fly_px4` (PX4 SIH's Ackermann rover; HIL_STATE_QUATERNION as the truth).
This module turns the scenario and the user's options into that flight, and its records into the
same result, plot and summary as a flight against our stand-in (:func:`fcmpc.fly.runner.finish`).
"""
from __future__ import annotations

import time
from datetime import datetime
from pathlib import Path

import numpy as np

from fcmpc.fly.results import STATUS_EXIT, FlyResult, TruthTrack
from fcmpc.fly.runner import REPO, FlyOptions, finish, prepare

__all__ = ["fly_on_ardupilot", "fly_on_px4"]

_MISSION = ("NAV_START_LAT", "NAV_START_LON", "NAV_DEST_LAT", "NAV_DEST_LON", "COMP_ARM_ENABLE", "COMP_SP_RATE_HZ")


def fly_on_ardupilot(options: FlyOptions) -> FlyResult:
    """Fly the scenario's mission (or its ``--short`` leg) against ArduPilot SITL; FirmwareMissing
    (before anything is written) when the binary is absent."""
    from sitl.firmware.ardupilot import ardupilot_binary
    from sitl.firmware.flight import fly_ardupilot

    ardupilot_binary()
    # a real compass is calibrated by the companion's circles before the mission (COMP_CAL_TURNS):
    # ArduPilot's own fixed-yaw calibration learns the offsets only (sitl/firmware/compass.py)
    if options.physics == "json":       # our world as ArduPilot's physics, in lockstep (sitl.physics)
        from sitl.physics.rig import fly_ardupilot_json as fly_ardupilot
    elif options.physics != "builtin":
        raise ValueError(f"physics {options.physics!r}: choose builtin or json")
    return _fly_on(options, "ardupilot", fly_ardupilot, 50.0, {"COMP_CAL_TURNS": 1} if options.compass == "real" else {})


def fly_on_px4(options: FlyOptions) -> FlyResult:
    """The same against PX4 SITL with SIH (``$FCMPC_PX4`` or ``../shared/px4``): its Ackermann rover at
    :data:`sitl.firmware.px4_flight.COMPANION_VALUES` (3 m/s, SIH's magnetometer at 50 Hz) unless ``--param``
    says otherwise; PX4's pacing is its
    speed factor (``--speedup``, default 10)."""
    from sitl.firmware.px4 import px4_root
    from sitl.firmware.flight import BOAT_CRUISE_KMH
    from sitl.firmware.px4_flight import COMPANION_VALUES, fly_px4
    from sitl.firmware.px4_hil import hil_companion_values

    if options.physics not in ("builtin", "hil"):
        raise ValueError(f"physics {options.physics!r}: choose builtin or hil with --fc px4")
    px4_root()
    # in lockstep the boat is ours (sitl.world.actuated, 10 m/s at full throttle): it cruises as ArduPilot's does
    values = {**COMPANION_VALUES, **hil_companion_values(BOAT_CRUISE_KMH / 3.6), "NAV_SPEED_KMH": BOAT_CRUISE_KMH} \
        if options.physics == "hil" else COMPANION_VALUES
    return _fly_on(options, "px4", fly_px4, 10.0, values)


def _current(options: FlyOptions, scenario) -> tuple[float, float]:
    """The water's current of this seed in the scenario's world (our world as the firmware's physics)."""
    if options.physics != "json":
        return (0.0, 0.0)
    from sitl.world.vehicle import MotionErrors

    return MotionErrors.draw(scenario.motion, np.random.default_rng(options.seed)).current_en_mps


def _fly_on(options: FlyOptions, name: str, fly_firmware, default_speedup: float, defaults: dict) -> FlyResult:
    from sitl.firmware.flight import FirmwareFlight

    scenario, dest, values = prepare(options)
    wall0 = time.monotonic()
    out = Path(options.out_dir) if options.out_dir else \
        REPO / "out" / "fly" / f"{scenario.name}-{name}-{datetime.now():%Y%m%d-%H%M%S}"
    # the scenario's [navigator] table describes its simulated world, not the firmware's
    given = {**scenario.nav_overrides(navigator=False), **options.extra_params}
    companion_values = {k: v for k, v in values.items() if k not in _MISSION and k in given}
    run = fly_firmware(FirmwareFlight(
        start=(scenario.start_lat_deg, scenario.start_lon_deg), destination=dest, out_dir=out,
        values={**defaults, **companion_values}, speedup=options.speedup or default_speedup,
        instance=options.fc_instance, start_unix_s=scenario.start_posix, timeout_s=options.timeout_s,
        compass=options.compass, current_en_mps=_current(options, scenario), physics=options.physics,
        scenario=scenario, seed=options.seed,
        quiet=options.progress_s is None))
    t = run.truth
    truth = TruthTrack(np.asarray(t["time_s"]), np.asarray(t["lat_deg"]), np.asarray(t["lon_deg"])) \
        if t["time_s"] else None
    return finish(options, scenario, out, dest, run.status, STATUS_EXIT.get(run.status, 1), run.message, wall0,
                  truth=truth)

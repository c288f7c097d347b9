"""Closed loop: the simulator and the companion as separate processes on loopback (via fcmpc.fly).

Tolerance against the in-process Monte Carlo of the same seed: ``remaining <= max(1.5 * MC, 1.5 km)``.
The closed loop and the in-process run draw different noise: the in-process run draws one
averaged (D, I) error per step, the simulator draws every 10 Hz magnetometer and attitude
sample (and its INS is propagated on its own schedule). Both have the same statistics (the
averaged measurement error of the closed loop matches ``SensorModel.averaged_di_noise_deg``:
about 7" in D and 4-5" in I per 360 s step), but not the same realisation, and the final miss
of a single run is dominated by the last geomagnetic fix (1-sigma a few hundred metres) plus
the 500 m arrival threshold on the *estimated* distance. Over 40 seeds the in-process miss has
median 0.3 km, 90th percentile 0.65 km and maximum 1.04 km (Pacific, full and 80 km), so 1.5x
of a single sub-km draw is not a property of the system; the absolute floor of 1.5 km is 1.5x
the worst of those 40 in-process misses.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.io.records import read_steps_csv  # noqa: E402
from fcmpc.fly import FlyOptions, FlyResult, fly  # noqa: E402
from sitl.scenario import load_scenario  # noqa: E402

FLOOR_M = 1500.0
ISSUE_MISS_M = 1000.0    # issue 10: after each fault "the mission still arriving within 1 km afterwards"
# A guard against a hung run, not a performance requirement: a short run takes about 70 s of wall
# time on an idle 2-core machine and several times that under load, which must not turn CI red.
HANG_S = 800.0
pytestmark = pytest.mark.timeout(HANG_S + 100.0)


def assert_close_to_monte_carlo(result: FlyResult, floor_m: float = FLOOR_M) -> None:
    assert result.status == "arrived", f"{result.status}: {result.message} ({result.out_dir})"
    # both report where the vehicle came to rest (in-process: on its final command at its limits)
    assert result.came_to_rest and math.isfinite(result.rest_remaining_m) and math.isfinite(result.mc_remaining_m)
    limit = max(1.5 * result.mc_remaining_m, floor_m)
    assert result.rest_remaining_m <= limit, (
        f"closed loop {result.rest_remaining_m:.0f} m vs in-process {result.mc_remaining_m:.0f} m (limit {limit:.0f} m)")
    # ... near where the last step found it
    assert abs(result.rest_remaining_m - result.step_remaining_m) <= 1000.0
    saved = json.loads((Path(result.out_dir) / "result.json").read_text())
    assert saved["status"] == "arrived" and saved["rest_remaining_m"] == pytest.approx(result.rest_remaining_m)
    # Open (session 2026-11-30): since the estimation filter merged, the companion's Table 3 path
    # (FUS_MODEL 0 on a vehicle) takes 23 steps on the short mission where the in-process run takes
    # 17 (both arrive within 0.5 km); the bound was max(5, 15 %) before. Not a defect found: the fix-alone
    # estimate dithers around the 500 m arrival threshold, and in-process Table 3 itself takes 17-23
    # steps over seeds 0-11 (docs/notes/estimation-notes.md, "Table 3's 23 steps closed loop").
    assert abs(result.iterations - result.mc_iterations) <= max(8, 0.15 * result.mc_iterations)
    assert result.plot_path and Path(result.plot_path).stat().st_size > 10_000


def test_short_pacific_mission_closed_loop(tmp_path):
    result = fly(FlyOptions(scenario="paper_pacific", short=True,
                            compare=True, out_dir=str(tmp_path / "run"), timeout_s=HANG_S))
    assert_close_to_monte_carlo(result)
    comp = result.companion
    assert comp["setpoints_refused"] == 0 and comp["setpoints_sent"] > 1000 and comp["bad_frames"] == 0
    assert comp["fc"]["autopilot"] == "ArduPilot" and comp["restarts"] == 0
    steps = [r for r in read_steps_csv(tmp_path / "run" / "companion" / "steps.csv") if r["event"] == "step"]
    assert [r["phase"] for r in steps[:3]] == ["probe1", "probe2", "cruise"] and steps[-1]["phase"] == "arrived"
    assert all(r["samples"] >= 3500 for r in steps[1:])               # 10 Hz over 360 s
    assert all(r["ins_source"] == "fc" for r in steps)                 # GLOBAL_POSITION_INT, never GPS
    # FUS_MODEL 0 (auto) with the stand-in's independent INS: the error-state filter, said at start
    events = json.loads((tmp_path / "run" / "companion" / "summary.json").read_text())["events"]
    assert any("position filter: INS error model" in e for e in events), [e for e in events if "filter" in e]
    sitl = json.loads((tmp_path / "run" / "sitl" / "summary.json").read_text())
    # the world waited on the companion's process (fcmpc-fly gives its PID): no wall timeout, no hang
    assert sitl["lockstep_timeouts"] == 0 and sitl["lockstep_hangs"] == 0
    # the stand-in's GPS is denied from take-off: the companion feeds GPS_INPUT (COMP_POS_PUB 3);
    # the stand-in's navigation-grade INS ignores it (no GPS2_RAW), so its position stayed independent
    assert comp["fc"]["positions_fed"] > 1000
    assert (tmp_path / "run" / "companion" / "companion.tlog").stat().st_size > 1_000_000


def test_short_mission_px4_offboard(tmp_path):
    result = fly(FlyOptions(scenario="paper_pacific", short=True,
                            short_km=40.0, autopilot="px4", compare=True,
                            out_dir=str(tmp_path / "run"), timeout_s=HANG_S, tlog=False))
    assert_close_to_monte_carlo(result)
    assert result.companion["fc"]["autopilot"] == "PX4"
    # it flew in OFFBOARD: the simulator's truth log says so
    modes = {line.split(",")[11] for line in (tmp_path / "run" / "sitl" / "truth.csv").read_text().splitlines()[1:]}
    assert "OFFBOARD" in modes


# --- failsafes: one mission, three faults in turn -----------------------------------------------
FAULTS = {"mag_off": (600.0, 30.0), "heartbeat_off": (1500.0, 20.0), "mag_nan": (2400.0, 20.0)}
# the companion reads the ArduPilot stand-in's HIGHRES_IMU (float: NaN arrives as NaN, not saturated)
REASON = {"mag_off": ("mag:", "zero"), "heartbeat_off": ("heartbeat:", "message time"),
          "mag_nan": ("mag:", "non-finite")}
TIMEOUT_S = {"mag_off": 2.0, "heartbeat_off": 3.0, "mag_nan": 2.0}      # COMP_MAG_TMO_S, COMP_HB_TMO_S
LATENCY_S = 1.0 + 0.4 + 0.1     # one lockstep period (1 s) + one setpoint tick (2.5 Hz) + margin


@pytest.fixture(scope="module")
def faulted_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("failsafe")
    faults = tuple(f"{kind}:{at:g}:{dur:g}" for kind, (at, dur) in FAULTS.items())
    result = fly(FlyOptions(scenario="paper_pacific", short=True,
                            short_km=60.0, faults=faults, out_dir=str(out / "run"), timeout_s=HANG_S,
                            tlog=False, sitl_extra=("--tlog",)))
    start = load_scenario("paper_pacific").start_posix
    log = mavutil.mavlink_connection(str(out / "run" / "sitl" / "sitl.tlog"))
    setpoints, modes, texts = [], [], []
    while True:
        msg = log.recv_match(type=["SET_POSITION_TARGET_GLOBAL_INT", "HEARTBEAT", "STATUSTEXT"])
        if msg is None:
            break
        t = msg._timestamp - start                              # the simulator stamps simulated time
        if msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT":
            setpoints.append(t)
        elif msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
            modes.append((t, msg.custom_mode))
        elif msg.get_type() == "STATUSTEXT" and msg.get_srcComponent() == 191:
            texts.append((t, msg.text))
    events = [r for r in read_steps_csv(out / "run" / "companion" / "steps.csv") if r["event"] == "failsafe"]
    log.close()
    return result, setpoints, modes, texts, events


@pytest.mark.parametrize("kind", list(FAULTS))
def test_failsafe_stops_streaming_holds_and_says_why(faulted_run, kind):
    result, setpoints, modes, texts, events = faulted_run
    at, duration = FAULTS[kind]
    timeout = TIMEOUT_S[kind]
    # the companion noticed within its timeout (message time), with the right reason
    [event] = [e for e in events if at <= e["msg_time_s"] <= at + duration]
    assert e_reason_ok(event["reason"], kind), event["reason"]
    assert event["msg_time_s"] - at <= timeout + 0.5
    # ... streamed nothing from then until the fault cleared
    assert not [t for t in setpoints if at + timeout + LATENCY_S <= t < at + duration], "setpoints during the fault"
    assert [t for t in setpoints if at - 5.0 <= t < at], "it was streaming before"
    assert [t for t in setpoints if at + duration <= t <= at + duration + 5.0], "it resumed after"
    # ... said so (STATUSTEXT received by the flight controller)
    said = "".join(text for t, text in texts if at <= t <= at + timeout + LATENCY_S + 1.0)
    assert "FAILSAFE" in said and REASON[kind][0] in said
    # ... and put the vehicle in HOLD (ArduPilot Rover mode 4) while the flight controller still talked
    if kind != "heartbeat_off":
        held = [mode for t, mode in modes if at + timeout + 2 * LATENCY_S <= t < at + duration]
        assert held and all(mode == 4 for mode in held)


def e_reason_ok(reason: str, kind: str) -> bool:
    prefix, detail = REASON[kind]
    return reason.startswith(prefix) and detail in reason


def test_mission_completes_after_the_faults(faulted_run):
    result = faulted_run[0]
    assert result.status == "arrived", result.message
    # measured with the error-state filter (the default since 2026-11-30): 0.11 km at the last step,
    # 0.19 km at rest (seed 0); Table 3's fix alone arrived 1.03 km off, over the issue's 1 km
    assert max(result.step_remaining_m, result.rest_remaining_m) <= ISSUE_MISS_M, \
        f"missed by {result.step_remaining_m:.0f} m (last step), {result.rest_remaining_m:.0f} m (at rest)"
    # each fault's failsafe counted once (the "not ready" before engaging is not a failsafe)
    assert result.companion["failsafes"] == len(faulted_run[4]) >= len(FAULTS)


def test_realistic_short_mission_navigates_on_every_period(tmp_path):
    """The realistic world (the default `pacific`: IGRF-14 and crust against WMM, INS heading,
    calibration residuals that turn with the vehicle, currents, a drawn start), closed loop: the
    companion's plausibility judge takes each period as the filter will see it, its heading states at
    the window's heading, so no period is excluded when the vehicle turns (before, every period after
    take-off was: "fix would jump 146-349 km", and the vehicle flew its last command on for good),
    and the mission arrives."""
    result = fly(FlyOptions(scenario="pacific", short=True, short_km=60.0, compare=True,
                            out_dir=str(tmp_path / "run"), timeout_s=HANG_S))
    assert result.status == "arrived", f"{result.status}: {result.message} ({result.out_dir})"
    events = json.loads((tmp_path / "run" / "companion" / "summary.json").read_text())["events"]
    assert not [e for e in events if "implausible" in e or "sustained" in e], events
    assert math.isfinite(result.rest_remaining_m) and math.isfinite(result.mc_remaining_m)

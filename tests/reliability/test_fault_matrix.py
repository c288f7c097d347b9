"""The fault matrix of issue 10 ("hardened link and failsafes"), closed loop against the stand-in.

Every fault the issue names, what the companion is expected to do about it, and where that is
tested. All closed-loop rows run the companion and ``fcmpc-sitl`` as real processes over loopback
in lockstep (``fcmpc.fly``); "here" is the one short mission below.

=================================  ==========================================================  ===========================================
fault (stand-in ``--fault``)       expected outcome                                            where tested
=================================  ==========================================================  ===========================================
mag_off                            failsafe: HOLD within COMP_MAG_TMO_S, "mag: ... zero";      tests/companion/test_closed_loop.py
                                   resumes when it clears; arrives                             (faulted_run)
mag_stuck                          failsafe once stuck is judged (20 identical readings while  here
                                   the boat turned 1 deg), within COMP_MAG_TMO_S + 1 s of the
                                   freeze: HOLD, "mag: ... stuck", ONE
                                   failsafe for the whole fault; resumes; arrives
mag_nan                            failsafe: HOLD, "mag: ... saturated"; resumes; arrives      tests/companion/test_closed_loop.py
mag_spike 20000 nT, 5 s            no failsafe; the period it spoils is excluded by the        here
                                   plausibility check ("implausible magnetometer step"), so
                                   no step steers on it; arrives
sustained mag offset (3000 nT)     each period excluded, "sustained magnetometer offset",      tests/companion/process/
                                   recovery said; arrives                                      test_plausibility_closed_loop.py
heartbeat_off                      failsafe within COMP_HB_TMO_S (message time), setpoints     tests/companion/test_closed_loop.py
                                   stop; resumes; arrives
gps_off (GPS lost in flight)       no failsafe: the companion never steers on GPS; the FC's    here
                                   position becomes an independent INS it fuses, GPS_INPUT
                                   switches from echo to our estimate; arrives
link_loss 30 % for 300 s           heartbeat failsafes that all recover, no HOLD of ours       tests/companion/process/
                                   taken for a pilot's; arrives                                test_recovery_closed_loop.py
link_delay 2 s                     no failsafe (all stamps late alike: message time lags);     here
                                   the setpoints keep the FC in GUIDED; arrives
link_duplicate 30 %                no failsafe, no duplicate taken for a stuck sensor; arrives  here
FC reboot (``fc_reboot``)          noticed on evidence (its clock went back), said; the same   here
                                   mission re-armed and resumed at its next step from its
                                   last estimate (not from NAV_START, no new start-up, no
                                   navigation restart); arrives
companion SIGKILL and restart      the saved state resumes the mission at its next step        tests/companion/process/
                                                                                               test_resume_closed_loop.py
=================================  ==========================================================  ===========================================

The mission: the first 40 km of the Pacific route with GPS until the ``gps_off`` fault (the
bundled scenario denies it from take-off, so losing it would change nothing), the faults
staggered so each meets a running mission, seed 0, lockstep (bit-reproducible: two runs gave the
same metre). Measured: failsafe said 3.0 s and HOLD seen 4.0 s (one lockstep period later) after
the magnetometer froze (one failsafe, "magnetometer stuck"; 6.0 s when stuck needed a 2 deg turn
and the age counted from the judgement), GUIDED again 4 s after it thawed; the spike's period excluded (its fix would have jumped
81 km); GPS_INPUT switched to our estimate 2 s after the GPS went; the reboot said 2 s after it,
re-armed in GUIDED 7 s after it, mission 1 resumed at its step 4 with 17.5 km to go; the last step
and the resting point 0.14 km from the destination (the issue asks for 1 km; the in-process worst of
40 seeds is 1.04 km, see tests/companion/test_closed_loop.py). 0.84 km until 2026-12-06, when the
end of the link_delay fault left the world waiting for answers the companion could not give until
2 s wall timeouts let it go on alone: now the stand-in waits on the companion's process and only
for what reached it, and the run beside 6 busy loops (load 9-12, 734 s of wall time) gave every
step and every truth row of the one alone (load 7, 29 s). Wall time 29-41 s on this 2-core machine
at load 7.
"""
from __future__ import annotations

import json
import math
import os
import re
from itertools import pairwise
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.io.records import read_steps_csv
from companion.nav.geo import geodesic_inverse
from fcmpc.fly import FlyOptions, fly
from fcmpc.fly.standin import LOCKSTEP_PERIOD_S
from sitl.scenario import SCENARIO_DIR, load_scenario
from tests.companion.test_closed_loop import ISSUE_MISS_M

HANG_S = 800.0           # a hung-run guard (see tests/companion/test_closed_loop.py), not a pace
SHORT_KM = 40.0
MAG_TMO_S = 2.0          # COMP_MAG_TMO_S
LOCKSTEP_S = LOCKSTEP_PERIOD_S["ardupilot"]   # 1 s
LATENCY_S = LOCKSTEP_S + 0.4 + 0.1  # one lockstep period + one setpoint tick (2.5 Hz) + margin
OFF_ROUTE_DEG = 45.0
HOLD, GUIDED = 4, 15     # ArduPilot Rover custom modes

STUCK_AT, STUCK_S = 500.0, 30.0
SPIKE_AT, SPIKE_S, SPIKE_NT = 1200.0, 5.0, 20000.0
GPS_OFF_AT = 1350.0
DELAY_AT, DELAY_S, DELAY_VALUE_S = 1600.0, 60.0, 2.0
DUP_AT, DUP_S, DUP_P = 1900.0, 120.0, 0.3
REBOOT_AT = 2300.0
FAULTS = (f"mag_stuck:{STUCK_AT:g}:{STUCK_S:g}", f"mag_spike:{SPIKE_AT:g}:{SPIKE_S:g}:{SPIKE_NT:g}",
          f"gps_off:{GPS_OFF_AT:g}", f"link_delay:{DELAY_AT:g}:{DELAY_S:g}:{DELAY_VALUE_S:g}",
          f"link_duplicate:{DUP_AT:g}:{DUP_S:g}:{DUP_P:g}", f"fc_reboot:{REBOOT_AT:g}")
pytestmark = [pytest.mark.slow, pytest.mark.timeout(HANG_S + 100.0)]


def _scenario_with_gps(path: Path) -> Path:
    """The bundled Pacific scenario with GPS until a gps_off fault takes it."""
    text = (SCENARIO_DIR / "paper_pacific.toml").read_text(encoding="utf-8")
    text, count = re.subn(r"(?m)^gps_denied_after_s\s*=.*$", "gps_denied_after_s = 1.0e9", text)
    assert count == 1
    path.write_text(re.sub(r'(?m)^name\s*=\s*"paper_pacific"', 'name = "pacific_gps"', text), encoding="utf-8")
    return path


class Run:
    """What one faulted mission left behind: the stand-in's tlog (both directions, simulated time),
    its truth log, and the companion's steps and summary."""

    def __init__(self, out: Path, result) -> None:
        self.result = result
        self.start = load_scenario("paper_pacific").start_posix
        self.modes: list[tuple[float, int, bool]] = []          # (t, custom_mode, armed) of the FC
        self.texts: list[tuple[float, str]] = []                # STATUSTEXT of the companion (joined chunks)
        self.fc_texts: list[tuple[float, str]] = []
        self.setpoints: list[float] = []
        self.feeds: list[float] = []                            # GPS_INPUT
        log = mavutil.mavlink_connection(str(out / "sitl" / "sitl.tlog"))
        try:
            while (msg := log.recv_match(type=["HEARTBEAT", "STATUSTEXT", "SET_POSITION_TARGET_GLOBAL_INT",
                                               "GPS_INPUT"])) is not None:
                self._add(msg, msg._timestamp - self.start)   # the stand-in stamps simulated time
        finally:
            log.close()
        rows = read_steps_csv(out / "companion" / "steps.csv")
        self.rows = rows
        self.steps = [r for r in rows if r["event"] == "step"]
        # the companion's message time is the FC's boot time: it starts again at the reboot
        self.reboot_row = next(i for i, r in enumerate(rows) if r["event"] == "restart" and "rebooted" in r["reason"])
        self.before_reboot, self.after_reboot = rows[:self.reboot_row], rows[self.reboot_row:]
        self.summary = json.loads((out / "companion" / "summary.json").read_text())

    def _add(self, msg, t: float) -> None:
        kind, comp = msg.get_type(), msg.get_srcComponent()
        if kind == "HEARTBEAT" and comp == 1:
            self.modes.append((t, msg.custom_mode, bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)))
        elif kind == "STATUSTEXT":
            texts = self.texts if comp == 191 else self.fc_texts
            if comp == 191 and msg.chunk_seq > 0 and texts:
                texts[-1] = (texts[-1][0], texts[-1][1] + msg.text)
            else:
                texts.append((t, msg.text))
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
            self.setpoints.append(t)
        elif kind == "GPS_INPUT":
            self.feeds.append(t)

    def said(self, t0: float, t1: float) -> str:
        return " | ".join(text for t, text in self.texts if t0 <= t <= t1)

    def first_mode(self, mode: int, after: float, armed: bool | None = None) -> float:
        """Simulated time of the first FC heartbeat in ``mode`` at or after ``after`` (inf if none)."""
        return next((t for t, m, a in self.modes if t >= after and m == mode and (armed is None or a == armed)),
                    math.inf)

    def failsafes_said(self, t0: float, t1: float) -> list[tuple[float, str]]:
        return [(t, text) for t, text in self.texts if t0 <= t <= t1 and "FAILSAFE" in text]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Run:
    out = tmp_path_factory.mktemp("matrix")
    scenario = _scenario_with_gps(out / "pacific_gps.toml")
    result = fly(FlyOptions(scenario=str(scenario), short=True, short_km=SHORT_KM, faults=FAULTS,
                            out_dir=str(out / "run"), timeout_s=HANG_S, tlog=False, plot=False,
                            sitl_extra=("--tlog",), quiet=True, progress_s=None))
    return Run(out / "run", result)


def test_mag_stuck_holds_within_the_timeout_once_says_why_and_resumes(run):
    [(said, text)] = run.failsafes_said(STUCK_AT, STUCK_AT + STUCK_S)   # one failsafe: it never looked fresh again
    # judged in 2-3 s; the age counts from the freeze, so the failsafe is due within the timeout + 1 s
    assert said - STUCK_AT <= MAG_TMO_S + 1.0, f"failsafe said {said - STUCK_AT:.1f} s after the freeze"
    hold = run.first_mode(HOLD, STUCK_AT)
    assert hold - STUCK_AT <= MAG_TMO_S + 1.0 + LATENCY_S, f"HOLD {hold - STUCK_AT:.1f} s after the freeze"
    assert "mag:" in text and "stuck" in text
    assert all(m == HOLD for t, m, _ in run.modes if hold <= t < STUCK_AT + STUCK_S)
    assert not [t for t in run.setpoints if hold + LATENCY_S <= t < STUCK_AT + STUCK_S], "steered while stuck"
    assert run.first_mode(GUIDED, STUCK_AT + STUCK_S, armed=True) <= STUCK_AT + STUCK_S + 5.0, "not resumed"


def test_mag_spike_no_failsafe_and_its_period_never_steers(run):
    assert not run.failsafes_said(SPIKE_AT - 1.0, SPIKE_AT + 400.0)
    assert all(m == GUIDED for t, m, _ in run.modes if SPIKE_AT <= t <= SPIKE_AT + 400.0)
    excluded = [r for r in run.before_reboot if r["event"] == "excluded"]
    assert excluded and all(SPIKE_AT < r["msg_time_s"] <= SPIKE_AT + 360.0 + 1.0 for r in excluded)
    assert "implausible magnetometer step" in run.said(SPIKE_AT, SPIKE_AT + 400.0)


def test_gps_off_no_failsafe_the_fc_position_becomes_an_ins_and_the_feed_our_estimate(run):
    steps = [r for r in run.before_reboot if r["event"] == "step"]
    before = [r for r in steps if r["msg_time_s"] < GPS_OFF_AT]
    after = [r for r in steps if r["msg_time_s"] > GPS_OFF_AT] + [r for r in run.after_reboot if r["event"] == "step"]
    assert before and all(r["ins_source"].startswith("none: FC position GPS-aided") for r in before)
    assert after and all(r["ins_source"] == "fc" for r in after)
    said = run.said(GPS_OFF_AT, GPS_OFF_AT + 5.0)
    assert "FC has no GPS: feeding our position" in said and "FAILSAFE" not in said
    assert not run.failsafes_said(GPS_OFF_AT - 1.0, GPS_OFF_AT + 60.0)
    gaps = [b - a for a, b in pairwise(run.feeds) if GPS_OFF_AT - 5.0 <= a <= GPS_OFF_AT + 60.0]
    assert gaps and max(gaps) <= 1.0, "the GPS_INPUT feed paused when the GPS went"


@pytest.mark.parametrize("at, duration", [(DELAY_AT, DELAY_S), (DUP_AT, DUP_S)], ids=["link_delay", "link_duplicate"])
def test_delay_and_duplicates_no_failsafe_the_fc_stays_guided(run, at, duration):
    assert not run.failsafes_said(at, at + duration + 5.0)
    assert all(m == GUIDED and armed for t, m, armed in run.modes if at <= t <= at + duration + 5.0)
    # at the delay's onset nothing reaches the companion for 2 s, so it sends nothing (it runs on message
    # time): the FC sees one gap of the delay plus a lockstep period, within its GUID_TIMEOUT of 3 s
    arrivals = [t for t in run.setpoints if at - 5.0 <= t <= at + duration + 5.0]
    assert arrivals and max(b - a for a, b in pairwise(arrivals)) <= DELAY_VALUE_S + LOCKSTEP_S
    assert not [text for t, text in run.fc_texts if at <= t <= at + duration + 5.0 and "setpoint timeout" in text]


def test_fc_reboot_noticed_said_rearmed_and_the_same_mission_goes_on(run):
    said = run.said(REBOOT_AT, REBOOT_AT + 5.0)
    assert "flight controller rebooted" in said and "goes on from its last estimate" in said
    rearmed = run.first_mode(GUIDED, REBOOT_AT + 0.5, armed=True)
    assert rearmed - REBOOT_AT <= 15.0, f"re-armed {rearmed - REBOOT_AT:.1f} s after the reboot"
    assert "resumed at step" in run.said(REBOOT_AT, rearmed + 5.0)
    feeds = [t for t in run.feeds if REBOOT_AT - 1.0 <= t <= REBOOT_AT + 120.0]   # GPS_INPUT goes on at 10 Hz
    assert feeds[-1] > REBOOT_AT + 119.0 and max(b - a for a, b in pairwise(feeds)) <= 3.0, "the feed stopped"
    last = [r for r in run.before_reboot if r["event"] == "step"][-1]
    first = next(r for r in run.after_reboot if r["event"] == "step")
    assert first["mission"] == last["mission"] == 1 and first["step"] == last["step"] + 1   # not probe1 again
    assert first["phase"] == "cruise" and first["remaining_m"] < last["remaining_m"]
    s = run.summary
    assert s["missions"] == 1 and s["restarts"] == 0 and s["link"]["fc_reboots"] == 1
    assert not any("NAV_START" in e or "start-up average" in e for e in s["events"][-12:]), "started afresh"


def test_no_step_steers_off_the_route_and_the_mission_arrives(run):
    result = run.result
    _, route = geodesic_inverse(33.0, 152.0, result.dest_lat_deg, result.dest_lon_deg)
    cruise = [r for r in run.steps if r["phase"] == "cruise" and r["remaining_m"] >= 5000.0]
    off = [abs((r["course_deg"] - math.degrees(route) + 180.0) % 360.0 - 180.0) for r in cruise]
    assert len(cruise) >= 5 and max(off) <= OFF_ROUTE_DEG, [round(o) for o in off]
    assert result.status == "arrived", f"{result.status}: {result.message} ({result.out_dir})"
    # measured 0.14 km at the last step and at rest (0.84 km with the 2 s timeouts): the issue's 1 km is asserted
    # (tighter than the closed-loop floor of 1.5 km, test_closed_loop.FLOOR_M; see the module docstring)
    miss = (result.step_remaining_m, result.rest_remaining_m)
    assert max(miss) <= ISSUE_MISS_M, f"missed by {miss[0]:.0f} m (last step), {miss[1]:.0f} m (at rest)"

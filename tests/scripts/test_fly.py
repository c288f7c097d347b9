"""fcmpc-fly: Ctrl-C gives a result and exit 130; the three distances; the track plot says how
the run ended. The interrupt tests run the real command (simulator and companion as processes)
and send the signal once its progress line shows the mission running, never after a sleep."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from geographiclib.geodesic import Geodesic

from fcmpc.fly.plots import plot_track, title_for
from fcmpc.fly.results import REST_TOL_M, REST_WINDOW_S, FlyResult, TruthTrack, distances, summary_lines

from tests.processes import Lines  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DEST = (32.5, 152.6)


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(p) for p in path.read_text().split()] if path.exists() else []


@pytest.mark.parametrize("target", ["terminal", "parent", "simulator"])
def test_interrupt_gives_a_summary_result_and_plot(tmp_path, target):
    """``terminal``: SIGINT to the whole process group, as Ctrl-C in a shell; ``parent``: to
    fcmpc-fly alone; ``simulator``: only the simulator child dies from it (not a miss either)."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "fcmpc.fly.cli", "--short", "--no-tlog", "--out-dir", str(out)],
                            cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        lines = Lines(proc.stderr)
        started = lines.wait_for("fcmpc-fly: step ", 120.0)
        assert started is not None, lines.seen
        children = _children(proc.pid)
        assert len(children) == 2, children
        if target == "terminal":
            os.killpg(proc.pid, signal.SIGINT)
        elif target == "parent":
            os.kill(proc.pid, signal.SIGINT)
        else:
            sitl = [c for c in children if "sitl.fc" in Path(f"/proc/{c}/cmdline").read_text()]
            os.kill(sitl[0], signal.SIGINT)
        stdout, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, (stdout, lines.seen)
    assert stdout.startswith("fcmpc-fly: interrupted before arriving") and " km from the destination" in stdout
    assert "arrived" not in stdout
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "interrupted" and result["exit_code"] == 130
    assert result["iterations"] >= 0 and result["rest_remaining_m"] > 1000.0      # it was far from there
    assert (out / "track.png").stat().st_size > 10_000
    assert all(not Path(f"/proc/{c}").exists() or "zombie" in Path(f"/proc/{c}/status").read_text()
               for c in children), "a child outlived fcmpc-fly"


# --- the three distances, on tracks built here ------------------------------------------------
def _track(points: list[tuple[float, float, float]]) -> TruthTrack:
    t, lat, lon = (np.array(v, dtype=float) for v in zip(*points))
    return TruthTrack(t, lat, lon)


def _dist(a: tuple[float, float], b: tuple[float, float]) -> float:
    return Geodesic.WGS84.Inverse(a[0], a[1], b[0], b[1])["s12"]


def _along(distance_m: float) -> tuple[float, float]:
    """A point ``distance_m`` north of the destination."""
    g = Geodesic.WGS84.Direct(DEST[0], DEST[1], 0.0, distance_m)
    return g["lat2"], g["lon2"]


def test_distances_separate_last_step_rest_and_belief():
    at_step, at_rest = _along(400.0), _along(150.0)
    points = [(float(t), *_along(400.0 - 10.0 * max(0.0, t - 100.0))) for t in range(90, 126)]   # slows to a stop
    points += [(float(t), *at_rest) for t in range(126, 126 + int(REST_WINDOW_S) + 5)]
    steps = [{"step": 7, "msg_time_s": 100.0, "remaining_m": 320.0}]
    d = distances(_track(points), steps, DEST)
    assert d["step_remaining_m"] == pytest.approx(_dist(at_step, DEST), abs=0.01)
    assert d["rest_remaining_m"] == pytest.approx(_dist(at_rest, DEST), abs=0.01)
    assert d["believed_remaining_m"] == 320.0 and d["iterations"] == 7 and d["came_to_rest"]


def test_a_boat_stopped_in_a_current_is_at_rest_where_it_stopped_not_where_it_drifted():
    """Speed through the water 0 from 126 s, drifting north-away at 0.8 m/s with the current: at rest
    (where it stopped); without the water speed logged the same track is still moving at its end."""
    stop = 150.0
    t = np.arange(90.0, 400.0)
    north = np.where(t < 126.0, 400.0 - 10.0 * np.clip(t - 100.0, 0.0, None), stop + 0.8 * (t - 126.0))
    water = np.where(t < 126.0, 10.0, 0.0)
    lat, lon = (np.array(v) for v in zip(*(_along(n) for n in north)))
    steps = [{"step": 7, "msg_time_s": 100.0, "remaining_m": 320.0}]
    d = distances(TruthTrack(t, lat, lon, water_speed_mps=water), steps, DEST)
    assert d["came_to_rest"] and d["rest_remaining_m"] == pytest.approx(stop, abs=0.5)
    drifting = distances(TruthTrack(t, lat, lon), steps, DEST)
    assert not drifting["came_to_rest"] and drifting["rest_remaining_m"] == pytest.approx(stop + 0.8 * 273, abs=1.0)
    still_propelled = distances(TruthTrack(t, lat, lon, water_speed_mps=np.where(t < 395.0, 0.0, 1.0)), steps, DEST)
    assert not still_propelled["came_to_rest"]


def test_the_last_step_after_an_fc_reboot_is_found_on_the_new_boot_clock():
    """Message time is the FC's boot time: after a reboot at 1000 s the last step at message time
    200 s happened 1200 s into the run, not 200 s in."""
    t = np.arange(0.0, 1400.0)
    north = 5000.0 - 5.0 * t                                       # 5 m/s towards the destination
    lat, lon = (np.array(v) for v in zip(*(_along(n) for n in north)))
    boot = np.where(t < 1000.0, t, t - 1000.0)
    steps = [{"step": 9, "msg_time_s": 200.0, "remaining_m": 100.0}]
    d = distances(TruthTrack(t, lat, lon, boot_s=boot), steps, DEST)
    assert d["step_remaining_m"] == pytest.approx(abs(5000.0 - 5.0 * 1200.0), abs=1.0)
    assert distances(_track(list(zip(t, lat, lon))), steps, DEST)["step_remaining_m"] == pytest.approx(4000.0, abs=1.0)


def test_a_track_that_ends_moving_is_not_at_rest():
    points = [(float(t), *_along(1000.0 - 3.0 * REST_TOL_M * t / REST_WINDOW_S)) for t in range(0, 30)]
    d = distances(_track(points), [], DEST)
    assert not d["came_to_rest"] and math.isnan(d["step_remaining_m"]) and d["iterations"] == 0
    assert d["rest_remaining_m"] == pytest.approx(_dist((points[-1][1], points[-1][2]), DEST), abs=0.01)


def _result(status: str, rest_m: float, **kw) -> FlyResult:
    base = dict(status=status, exit_code=0, scenario="paper_pacific", seed=0, iterations=5, rest_remaining_m=rest_m,
                step_remaining_m=rest_m + 50.0, believed_remaining_m=rest_m - 70.0, came_to_rest=status == "arrived",
                wall_s=3.0, sim_s=1800.0, out_dir="x", plot_path=None, dest_lat_deg=DEST[0], dest_lon_deg=DEST[1])
    return FlyResult(**{**base, **kw})


def test_summary_puts_the_resting_point_first_and_never_calls_an_interruption_a_miss():
    lines = summary_lines(_result("arrived", 128.0))
    assert lines[0].startswith("arrived: the vehicle came to rest 128 m from the destination")
    assert "at the last control step: 178 m" in lines[1] and "believed:   58 m" in lines[2]
    head = summary_lines(_result("interrupted", 747_201.0))[0]
    assert head.startswith("interrupted before arriving") and "747.2 km" in head


def test_plot_of_an_interrupted_run_says_so_in_km(tmp_path):
    start = _along(60_000.0)
    points = [(float(t), *_along(60_000.0 - 13.9 * t)) for t in range(0, 2000, 10)]
    steps = [{"step": k, "msg_time_s": 360.0 * k, "remaining_m": 60_000.0 - 5000.0 * k,
              "est_lat_deg": _along(60_000.0 - 5000.0 * k + 300.0)[0], "est_lon_deg": DEST[1]} for k in range(5)]
    result = _result("interrupted", _dist((points[-1][1], points[-1][2]), DEST))
    title = title_for(result, "paper_pacific")
    assert "INTERRUPTED" in title and f"{result.rest_remaining_m / 1000.0:.2f} km" in title
    path = plot_track(tmp_path / "track.png", start, DEST, _track(points), steps, result, "paper_pacific")
    assert path.stat().st_size > 20_000


def test_nice_lowers_the_childrens_priority_by_the_increment_and_zero_keeps_it():
    """``FlyOptions.nice``: the children's ``preexec_fn`` adds the increment to their niceness."""
    from fcmpc.fly.mission import niceness as _niceness

    probe = [sys.executable, "-c", "import os; print(os.nice(0))"]
    own = os.nice(0)
    assert _niceness(0) is None
    lowered = subprocess.run(probe, preexec_fn=_niceness(3), capture_output=True, text=True, check=True)
    assert int(lowered.stdout) == min(own + 3, 19)


@pytest.mark.parametrize("scenario, gifted", [("paper_pacific", True), ("pacific", False)])
def test_a_paper_world_says_its_gifts_before_and_after_the_flight(monkeypatch, capsys, scenario, gifted):
    """The flight itself stands in (the closed loop is tests/companion's): what fcmpc-fly prints around it."""
    import fcmpc.fly.cli

    monkeypatch.setattr(fcmpc.fly.cli, "fly", lambda options: _result("arrived", 128.0, scenario=options.scenario))
    assert fcmpc.fly.cli.main(["--scenario", scenario, "--no-plot"]) == 0
    printed = capsys.readouterr()
    said = [line for line in (printed.err + printed.out).splitlines() if "hands the navigator" in line]
    assert len(said) == (2 if gifted else 0)
    assert all(line.startswith(f"fcmpc-fly: {scenario} hands") and "the true heading" in line for line in said)


def test_a_storm_world_flies_storm_parameters_fitted_without_its_storm(monkeypatch, capsys):
    """fcmpc-fly scores a storm world as fcmpc-montecarlo does: its storm-time parameters fitted on
    the library's other storms (the committed .parm of that fit by the miss is the reference), a --param wins,
    and parameters fitted on the world's own storm are refused before anything flies."""
    import fcmpc.fly.cli
    from companion.params import read_parm_file

    flown = []
    monkeypatch.setattr(fcmpc.fly.cli, "fly", lambda options: flown.append(options) or _result("arrived", 128.0))
    assert fcmpc.fly.cli.main(["--scenario", "short_storm", "--no-plot", "--param", "FUS_BQA_N=12"]) == 0
    said = capsys.readouterr().err
    assert "fitted on halloween2003,march2011,stpatrick2015, not on may2024" in said
    committed = read_parm_file(REPO / "params" / "storms-halloween2003+march2011+stpatrick2015-by-miss.parm")
    given = flown[0].extra_params
    assert given["FUS_BQA_N"] == 12
    assert {k: v for k, v in committed.items() if k != "FUS_BQA_N"} == {
        k: pytest.approx(given[k], abs=0.051) for k in committed if k != "FUS_BQA_N"}
    assert fcmpc.fly.cli.main(["--scenario", "short_storm", "--no-plot", "--storm-params", "may2024"]) == 2
    assert "fitted on may2024" in capsys.readouterr().err and len(flown) == 1


def test_the_runner_reports_a_flight_controller_that_ends_on_its_own_and_stops_the_companion(tmp_path):
    """The one runner against a stand-in that exits at once (an option it refuses): an error naming
    its log, the companion stopped by PID, no truth."""
    from companion.params import write_parm_file
    from fcmpc.fly.mission import CompanionRun, run_mission
    from fcmpc.fly.standin import StandIn

    parm = tmp_path / "fly.parm"
    write_parm_file(parm, {"COMP_ARM_ENABLE": 1})
    fc = StandIn(("--no-such-option",))
    outcome, truth = run_mission(fc, CompanionRun(parm, tmp_path / "companion", ("--quiet",)), tmp_path, 120.0)
    assert outcome.status == "error" and outcome.code == 1, outcome
    assert "the simulator exited with 2" in outcome.message and str(tmp_path / "sitl.log") in outcome.message
    assert "--no-such-option" in (tmp_path / "sitl.log").read_text()
    assert truth is None and fc.process.returncode == 2
    assert (tmp_path / "companion" / "steps.csv").exists()      # it had opened its link ...
    alive = [c for c in _children(os.getpid()) if "companion.app" in Path(f"/proc/{c}/cmdline").read_text()
             and "zombie" not in Path(f"/proc/{c}/status").read_text()]
    assert not alive, "the companion outlived the run"           # ... and was stopped


def test_the_stand_in_in_lockstep_waits_on_the_companions_process_not_a_wall_timeout(tmp_path):
    """``fcmpc-fly``'s stand-in in lockstep is told the companion's PID (``--lockstep-peer-pid``), so a
    busy machine that delays the companion's answers beyond the 2 s lockstep timeout slows the run
    instead of letting the world run ahead of it (a closed-loop test failed so at load 20-25)."""
    import subprocess
    import sys

    from fcmpc.fly.standin import StandIn

    peer = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    fc = StandIn(("--lockstep", "--scenario", "pacific", "--quiet", "--duration", "5"))
    try:
        fc.start(tmp_path)
        fc.companion_ready(peer.pid)
        # the command line it was started with (its /proc entry is empty once it has exited: a CI run read
        # it after the stand-in had ended, and found no flag)
        argv = list(fc.process.args)
        assert argv[argv.index("--lockstep-peer-pid") + 1] == str(peer.pid), argv
        assert "--lockstep-successor" in argv       # a companion restarted after a crash is waited on too
    finally:
        fc.stop()
        peer.stdin.close()
        peer.wait(10)

"""The magnetometer's calibration circles before the mission (COMP_CAL_TURNS), closed loop against the
stand-in whose magnetometer carries a real installation's hard and soft iron, uncalibrated."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from companion.params import read_parm_file
from tests.companion.test_app import _run

REPO = Path(__file__).resolve().parents[2]
PARM = "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\n"


def _installation(tmp_path: Path) -> Path:
    """The paper's Pacific world with an uncalibrated magnetometer: 3000 nT of hard iron and 2 % of
    soft iron per element (log171's external compass: 213 mG offsets, 1.8 % cross-axis), and GPS
    until 70 s, just past arming (the start must be GPS-known to calibrate against the model)."""
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text()
    text, count = re.subn(r"(?m)^gps_denied_after_s = .*$", "gps_denied_after_s = 70.0", text)
    assert count == 1
    text = re.sub(r"(?m)^\[sensors\]\n", "[sensors]\nmag_hard_iron_resid_nt = 3000.0\nmag_soft_iron_resid = 0.02\n",
                  text, count=1)
    path = tmp_path / "installation.toml"
    path.write_text(text)
    return path


def _said(companion: dict, needle: str) -> list[str]:
    return [e for e in companion["events"] if needle in e]


def test_circles_fit_the_installation_and_the_probes_are_not_excluded(tmp_path):
    world = _installation(tmp_path)
    # GPS ends at 70 s of simulated time, just past arming: the world must wait for the companion at
    # every boundary however loaded the machine (a 0.5 s wall timeout once let it run on without the
    # companion, so arming came after the GPS cut and no circle was flown): _run's world waits as long
    # as the companion's process lives
    args = ("--scenario", str(world))
    (tmp_path / "circles").mkdir(), (tmp_path / "none").mkdir()
    sitl_none, none = _run(tmp_path / "none", PARM, sim_s=600.0, sitl_args=args, wall_s=600.0)
    assert _said(none, "implausible magnetometer"), "the uncalibrated installation should be noticed"
    sitl_circles, circles = _run(tmp_path / "circles", PARM + "COMP_CAL_TURNS 1\n", sim_s=1300.0, sitl_args=args,
                                 wall_s=600.0)
    assert sitl_none["lockstep_timeouts"] == 0 and sitl_circles["lockstep_timeouts"] == 0
    said = _said(circles, "magnetometer calibrated")
    assert len(said) == 1, circles["events"][-10:]
    residual = float(re.search(r"residual (\d+) nT", said[0]).group(1))
    assert residual < 300.0, said
    started = [i for i, e in enumerate(circles["events"]) if "phase probe1" in e]
    assert started, circles["events"][-10:]
    after = circles["events"][started[0]:]
    assert not [e for e in after if "implausible magnetometer" in e], after
    stored = read_parm_file(tmp_path / "circles" / "companion.parm")
    assert abs(stored["MAG_OFS_X"]) + abs(stored["MAG_OFS_Y"]) > 5.0, "the fit was not written to MAG_*"


def _gps_until(tmp_path: Path, seconds: float, ins_at_rest: bool) -> Path:
    """The paper's Pacific world with GPS only until ``seconds`` of simulated time; ``ins_at_rest``:
    the FC's free-inertial solution starts without the paper's initial errors (5 km, 10 m/s), as a
    flight controller's EKF holds a vehicle at rest, so its position says the vehicle has not moved."""
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text()
    text, count = re.subn(r"(?m)^gps_denied_after_s = .*$", f"gps_denied_after_s = {seconds}", text)
    assert count == 1
    if ins_at_rest:
        for name in ("vel_err_mps", "pos_err_east_m", "pos_err_north_m"):
            text, count = re.subn(rf"(?m)^{name} = .*$", f"{name} = 0.0", text)
            assert count == 1, name
    path = tmp_path / "world.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("ins_at_rest", [True, False], ids=["FC holds the vehicle", "FC drifts"])
def test_a_fix_older_than_the_start_allows_places_the_circle_or_is_said(tmp_path, ins_at_rest):
    """The GPS cut 17 s before arming (ArduPilot in lockstep, seed 1007, refused arming four times
    and the circle was dropped without a word). While the flight controller's own position stays
    by the last fix, the circle is flown there. Where it runs away (the paper's free INS: 7.7 km
    at 14 m/s after 18 s at rest), a WARNING says the circle is skipped and why before the mission's
    start, summary.json keeps it, and the mission flies on. 30 s: the decision comes at arming, ~22 s."""
    parm = "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 20\nCOMP_CAL_TURNS 1\nCOMP_POS_PUB 2\n"   # POS_PUB 2: the FC's own position
    _, run = _run(tmp_path, parm, sim_s=30.0, wall_s=300.0,
                  sitl_args=("--scenario", str(_gps_until(tmp_path, 5.0, ins_at_rest))))
    events = run["events"]
    if ins_at_rest:
        assert _said(run, "calibrating the magnetometer"), events[-10:]
        assert not _said(run, "skipped"), events[-10:]
        assert re.fullmatch(r"circling at 33\.0000,152\.0000: the GPS fix of 1\d s ago, at rest since "
                            r"\(the FC position \d m from it at 0\.\d m/s\)", run["calibration"]), run["calibration"]
        return
    said = [i for i, e in enumerate(events) if "calibration circle skipped, MAG_* unchanged: the last GPS "
            "fix is 1" in e and "s old and the vehicle moved since (the FC position" in e]
    started = [i for i, e in enumerate(events) if "mission 1 start" in e]
    assert said and started and said[0] < started[0], events[:10]
    assert not _said(run, "calibrating the magnetometer"), events[-10:]
    assert run["calibration"].startswith("skipped: the last GPS fix is 1"), run["calibration"]
    assert run["state"] == "running", events[-10:]   # flies on, having said so

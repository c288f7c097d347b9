"""The magnetometer's calibration circles before the mission (COMP_CAL_TURNS), closed loop against the
stand-in whose magnetometer carries a real installation's hard and soft iron, uncalibrated."""
from __future__ import annotations

import re
from pathlib import Path

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


def _gps_until(tmp_path: Path, seconds: float) -> Path:
    """The paper's Pacific world with GPS only until ``seconds`` of simulated time."""
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text()
    text, count = re.subn(r"(?m)^gps_denied_after_s = .*$", f"gps_denied_after_s = {seconds}", text)
    assert count == 1
    path = tmp_path / "world.toml"
    path.write_text(text)
    return path


def test_a_circle_that_cannot_be_placed_is_said_before_the_mission(tmp_path):
    """The GPS cut 30 s before arming (ArduPilot in lockstep, seed 1007, refused arming four times
    and the circle was dropped without a word). The stand-in's free-inertial position runs away
    from the last fix (8 km at 14 m/s after 33 s at rest), so the rest that would let the old fix
    place the field model is not shown: a WARNING says the circle is skipped and why before the
    mission's start, summary.json keeps it, and the mission flies on. 150 s: arming at ~62 s."""
    parm = PARM + "COMP_CAL_TURNS 1\nCOMP_POS_PUB 2\n"   # the FC's own position, not our feed echoed
    _, stale = _run(tmp_path, parm, sim_s=150.0, wall_s=300.0,
                    sitl_args=("--scenario", str(_gps_until(tmp_path, 30.0))))
    said = [i for i, e in enumerate(stale["events"]) if "calibration circle skipped, MAG_* unchanged: the last GPS "
            "fix is 3" in e and "s old and the vehicle moved since (the FC position" in e]
    started = [i for i, e in enumerate(stale["events"]) if "mission 1 start" in e]
    assert said and started and said[0] < started[0], stale["events"][:10]
    assert not _said(stale, "calibrating the magnetometer"), stale["events"][-10:]
    assert stale["calibration"].startswith("skipped: the last GPS fix is 3"), stale["calibration"]
    assert stale["state"] == "running", stale["events"][-10:]   # flies on, having said so

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

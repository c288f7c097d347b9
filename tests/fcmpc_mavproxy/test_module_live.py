"""``module load fcmpc`` in MAVProxy against the running companion and the simulator, real processes
on loopback, MAVProxy headless through its console on a pipe (as tests/companion/test_link_mavproxy.py):
the module loads, ``fcmpc start`` starts the mission, ``fcmpc status`` shows the phase and a
finite 1-sigma from the live companion, ``fcmpc help`` the registry's unit and range, and hold /
resume are acknowledged by the companion and change what it does. With OpenCV, a map module
(tests/fcmpc_mavproxy/headless_map.py: MAVProxy's map without its wxPython window) is loaded too:
the module's slip objects, drawn by MAVProxy's own code, show the running companion's estimate,
its 95 % ellipse and the destination where its messages put them, move with the estimate and go
with the module (test_map_drawing.py's pixel checks)."""
from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.registry import SPEC_BY_NAME
from tests.companion.test_ground_station import Console, running_vehicle
from tests.companion.test_link_mavproxy import _quit
from tests.lockstep import HANG_S

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None,
                                reason="MAVProxy not installed (pip install --no-deps MAVProxy next to pymavlink)")

# a short control period: the start-up average is one period (2 s of wall time at running_vehicle's
# 5x cap). The world is in lockstep with the companion; MAVProxy, on the wall clock, waits on its
# console's lines with HANG_S guards (a MAVProxy loading a module took more than 30 s under load)
PARMS = "NAV_PERIOD_S 10\n"


def _mavproxy(port: int, workdir: Path) -> Console:
    """MAVProxy as an operator runs it (its target component is the autopilot's: not 191), on the vehicle's TCP port."""
    workdir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(
        [sys.executable, "-m", "MAVProxy.mavproxy", "--master", f"tcp:127.0.0.1:{port}", "--target-system", "1",
         "--default-modules", "link", "--state-basedir", str(workdir), "--nowait"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1, cwd=workdir,
        env=dict(os.environ, MAVLINK20="1", PYTHONPATH=str(REPO)))
    return Console(proc)


def _said(console: Console, since: int, text: str, timeout_s: float) -> bool:
    """``text`` in a line read since line ``since`` (what follows a command comes in no fixed order: the
    companion's STATUSTEXT, its COMMAND_ACK, the FC's mode change), or in one within ``timeout_s``."""
    return any(text in line for line in console.seen[since:]) or console.wait_for(text, timeout_s) is not None


def _status(console: Console) -> tuple[str, float]:
    """``fcmpc status``: (phase, 1-sigma in m, NaN when unknown)."""
    console.send("fcmpc status")
    phase_line = console.wait_for("fcmpc: phase", HANG_S)
    sigma_line = console.wait_for("estimate 1-sigma", HANG_S)
    assert phase_line is not None and sigma_line is not None, console.seen[-20:]
    phase = phase_line.split("fcmpc: phase ", 1)[1].split()[0].rstrip(",")
    found = re.search(r"1-sigma (\d+(?:\.\d+)?) m", sigma_line)
    return phase, float(found.group(1)) if found else math.nan


MAP = importlib.util.find_spec("cv2") is not None        # MAVProxy's map drawing needs OpenCV
if MAP:
    from MAVProxy.modules.lib import mp_util
    from MAVProxy.modules.mavproxy_map import mp_tile

    from tests.fcmpc_mavproxy.headless_map import View
    from tests.fcmpc_mavproxy.test_map_drawing import ICONS


def _save(console: Console, path: Path) -> tuple[np.ndarray, dict]:
    """The headless map's drawing of its current view, and what it holds (headless_map.py)."""
    console.send(f"hmap save {path}")
    assert console.wait_for(f"hmap: saved {path}", HANG_S) is not None, console.seen[-20:]
    return np.load(f"{path}.npy"), json.loads(Path(f"{path}.json").read_text())


def _drawn_estimate(record: dict) -> tuple[tuple[float, float], tuple[float, float, float]]:
    """The estimate icon's position and the GLOBAL_POSITION_INT_COV the companion sent it from:
    (lat, lon) and its (north-north, north-east, east-east) covariance."""
    lat, lon = record["objects"]["fcmpc:estimate"]["latlon"]
    sent = [m for m in record["heard"] if (m["lat"], m["lon"]) == (round(lat * 1e7), round(lon * 1e7))]
    assert sent, f"the estimate drawn at {lat}, {lon} is none the companion sent"
    cov = sent[-1]["covariance"]
    return (sent[-1]["lat"] * 1e-7, sent[-1]["lon"] * 1e-7), (cov[0], cov[1], cov[7])


def _map_while_held(console: Console, since: int, workdir: Path) -> dict:
    """The mission held: the estimate, its ellipse and the destination drawn where the companion's
    messages put them. What was measured, for :func:`_map_after_resume`."""
    from tests.fcmpc_mavproxy.test_map_drawing import assert_ellipse_drawn, assert_icon_drawn

    tiles = mp_tile.MPTile(cache_path=str(workdir / "tiles"), download=False)   # the map's Web Mercator
    for key in ("fcmpc:ellipse", "fcmpc:estimate", "fcmpc:destination"):
        assert _said(console, since, f"hmap: added {key}", HANG_S), (key, console.seen[since:])
    console.send("hmap fit fcmpc:estimate fcmpc:ellipse")         # the ellipse across a quarter of the view
    img, record = _save(console, workdir / "estimate")
    view = View(**record["view"])
    latlon, cov = _drawn_estimate(record)
    assert_icon_drawn(img, view.pixmapper(tiles)(latlon), ICONS["estimate"])
    measured = assert_ellipse_drawn(img, view, view.pixmapper(tiles)(latlon), latlon[0], cov)

    destination = tuple(SPEC_BY_NAME[name].default for name in ("NAV_DEST_LAT", "NAV_DEST_LON"))
    assert record["objects"]["fcmpc:destination"]["latlon"] == pytest.approx(destination, abs=1e-5)  # float32
    console.send(f"hmap view {destination[0]} {destination[1]} 2000")
    img, record = _save(console, workdir / "destination")
    far = View(**record["view"])
    assert_icon_drawn(img, far.pixmapper(tiles)(destination), ICONS["destination"])
    return {"estimate": latlon, "cov": cov, "pixels": measured, "tiles": tiles}


def _map_after_resume(console: Console, held: dict, workdir: Path) -> dict:
    """The mission resumed: the companion's next status (1 Hz of wall time) has its estimate flown
    on; the module moves the objects there (that nothing is left where they were is
    test_map_drawing.py's, on a view that holds both places)."""
    from tests.fcmpc_mavproxy.test_map_drawing import assert_ellipse_drawn, assert_icon_drawn

    deadline = time.monotonic() + HANG_S      # not a count of statuses: those are paced by the wall
    while True:
        line = console.wait_for("hmap: added fcmpc:estimate at", deadline - time.monotonic())
        assert line is not None, console.seen[-20:]
        if tuple(float(v) for v in line.rsplit(" ", 1)[1].split(",")) != pytest.approx(held["estimate"], abs=2e-7):
            break
    console.send("hmap fit fcmpc:estimate fcmpc:ellipse")
    img, record = _save(console, workdir / "moved")
    latlon, cov = _drawn_estimate(record)
    view = View(**record["view"])
    pixmapper = view.pixmapper(held["tiles"])
    old, new = pixmapper(held["estimate"]), pixmapper(latlon)
    assert new != old, (held["estimate"], latlon)
    assert_icon_drawn(img, new, ICONS["estimate"])
    return {"moved_m": mp_util.gps_distance(*held["estimate"], *latlon), "cov": cov,
            "pixels": assert_ellipse_drawn(img, view, new, latlon[0], cov)}


def test_fcmpc_module_against_the_running_companion(tmp_path):
    with running_vehicle(tmp_path, PARMS) as (port, _parm):
        console = _mavproxy(port, tmp_path / "mavproxy")
        try:
            console.send("module load fcmpc")
            assert console.wait_for("Loaded module fcmpc", HANG_S) is not None, console.seen[-20:]
            spec = SPEC_BY_NAME["NAV_SPEED_KMH"]
            console.send("fcmpc help NAV_SPEED_KMH")
            assert console.wait_for(f"unit: {spec.unit}; range [{spec.minimum:g}, {spec.maximum:g}]", HANG_S), \
                console.seen[-20:]
            console.send("fcmpc start")
            assert console.wait_for("fcmpc: start: ACCEPTED by the companion", HANG_S), console.seen[-20:]
            if MAP:    # loaded after the module (which draws in full on a map that comes later)
                console.send("module load tests.fcmpc_mavproxy.headless_map")
                assert console.wait_for("Loaded module tests.fcmpc_mavproxy.headless_map", HANG_S), console.seen[-20:]
            console.send("set moddebug 2")     # from now on an exception in a module prints its traceback
            loaded = len(console.seen)
            # the companion selects GUIDED, arms, starts the mission and steps: its STATUSTEXT says so
            assert console.wait_for("FcMPC: step 1 phase", HANG_S), console.seen[-30:]
            phase, sigma = _status(console)
            assert phase == "running" and math.isfinite(sigma) and sigma > 0.0, console.seen[-20:]
            for word, said, mode in (("hold", "held by the operator", "Mode HOLD"),   # the FC told to hold
                                     ("resume", "resumed by the operator", "Mode GUIDED")):  # back under guidance
                since = len(console.seen)
                console.send(f"fcmpc {word}")
                for text in (f"fcmpc: {word}: ACCEPTED by the companion", f"FcMPC: {said}", mode):
                    assert _said(console, since, text, HANG_S), (text, console.seen[since:])
                if MAP and word == "hold":
                    held = _map_while_held(console, loaded, tmp_path / "mavproxy")
            if MAP:
                moved = _map_after_resume(console, held, tmp_path / "mavproxy")
                print("map:", held["estimate"], held["pixels"], moved)
            console.send("module unload fcmpc")
            assert console.wait_for("Unloaded module fcmpc", HANG_S), console.seen[-20:]
            if MAP:      # the module's objects taken off the map: nothing left to draw
                img, record = _save(console, tmp_path / "mavproxy" / "unloaded")
                assert record["objects"] == {} and not img.any(), record["objects"]
            assert not [line for line in console.seen if "Traceback" in line or "fcmpc" in line and "rror" in line]
        finally:
            _quit(console)
    summary = json.loads((tmp_path / "companion" / "summary.json").read_text())
    assert summary["operator"]["commands"] == 3 and not summary["operator"]["held"]
    assert summary["missions"] == 1

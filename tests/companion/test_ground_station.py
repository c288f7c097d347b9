"""Real ground-station clients list and set the companion's parameters (component 191).

Topology as on a vehicle: the companion talks to the flight controller (the simulator), the
ground station talks to the flight controller too, and the flight controller routes between
its links (ArduPilot's MAVLink routing, which the simulator implements). The ground station
therefore sees system 1 with an ArduPilot autopilot (component 1) and the companion (191).
The ground station connects over TCP, as to ArduPilot SITL's 5760: a ground station the machine's
load starves of CPU reads late and loses nothing (over UDP, MAVProxy's socket overflowed at load
14 with 3 busy loops, 1,169-1,358 datagrams dropped per run, and with them the companion's
COMMAND_ACK or a STATUSTEXT the test waits for, in 9 of 11 loaded runs).

* MAVSDK 4.x (a dependency): ``ParamAsync.select_component(191, V1)`` then get/set. MAVSDK 4.1's
  binding reports ``select_component`` as UNKNOWN although the selection takes effect (checked:
  the parameters then listed are the companion's, not the simulator's), so that result is not
  trusted; everything after it is.
* MAVProxy (optional: ``pip install --no-deps MAVProxy``; skipped when absent) with
  ``--target-component 191``: it fetches the parameters at start-up ("Received N parameters"),
  then ``param set`` through its console on a pipe.
"""
from __future__ import annotations

import asyncio
import importlib.util
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from companion.params import REGISTRY, read_parm_file
from tests.lockstep import COMPANION_ID, HANG_S, lockstep_pair
from tests.ports import free_port
from tests.processes import Lines, wait_for_listening


def wait_for_companion(port: int, procs: list, timeout_s: float) -> None:
    """Connect where the ground station will (the stand-in's TCP server, once it listens) until the
    companion's HEARTBEAT (system 1, component 191) has arrived through the simulator's routing;
    then disconnect (the ground station connects next)."""
    from pymavlink import mavutil

    wait_for_listening(port, procs, timeout_s)
    conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255)
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == COMPANION_ID:
                return
        raise AssertionError(f"no heartbeat from the companion (1/191) on tcp port {port} within {timeout_s:g} s")
    finally:
        conn.close()


@contextmanager
def running_vehicle(tmp_path: Path, parm_text: str, speedup: float = 5.0) -> Iterator[tuple[int, Path]]:
    """Companion (``parm_text`` its parameter file) + stand-in in lockstep with it (:mod:`tests.lockstep`:
    a busy machine slows the pair, never changes what they do), simulated time capped at ``speedup``
    times the wall's so that a ground station's operator, on the wall clock, still meets the mission;
    yields (port, parm_path): the stand-in's TCP server for the ground station, once the companion is
    heard there. The flight controller answers the companion's own parameter reads on the companion's
    link only, as ArduPilot does (:mod:`sitl.fc.params`), so a client's first parameter download finds
    component 191's and nothing else. The ground station is a client: it does not hold the clock."""
    port = free_port()
    with lockstep_pair(tmp_path, parm_text, companion_args=("--params-create",), wall_s=600.0,
                       sitl_args=("--master", f"tcp:127.0.0.1:{port}", "--speedup", f"{speedup:g}",
                                  "--duration", "86400")) as pair:
        wait_for_companion(port, [pair.companion, pair.sitl], HANG_S)
        yield port, pair.parm


@pytest.fixture
def vehicle(tmp_path):
    """:func:`running_vehicle` with MAVSDK's ground-station id allowed (MAVProxy's is 255)."""
    with running_vehicle(tmp_path, "LINK_GCS_ID2 245\n") as ports:
        yield ports


async def _mavsdk_session(port: int) -> dict:
    from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.plugins.param import ParamError, ProtocolVersion

    out: dict = {}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"tcpout://127.0.0.1:{port}")
        system = await sdk.first_autopilot(timeout_s=HANG_S)
        assert system is not None, "MAVSDK saw no autopilot"
        # MAVSDK decodes an INT32 parameter as ArduPilot does (a C cast) only once it has seen the
        # autopilot's HEARTBEAT (first_autopilot may return on another of its messages): wait for both
        deadline = time.monotonic() + HANG_S
        while (191 not in await system.component_ids() or await system.autopilot_type() != Autopilot.ARDUPILOT) \
                and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        out["components"] = await system.component_ids()
        param = ParamAsync(system)
        try:
            await param.select_component(191, ProtocolVersion.V1)
        except ParamError:
            pass   # MAVSDK 4.1 reports UNKNOWN here although the selection is made (see module docstring)
        everything = await param.get_all_params()
        out["ints"] = {p.name: p.value for p in everything.int_params}
        out["floats"] = {p.name: p.value for p in everything.float_params}
        await param.set_param_float("NAV_SPEED_KMH", 42.0)
        await param.set_param_int("NAV_MAX_STEPS", 500)
        out["speed"] = await param.get_param_float("NAV_SPEED_KMH")
        out["steps"] = await param.get_param_int("NAV_MAX_STEPS")
        try:
            await param.set_param_float("MPC_HORIZON_X", 1.0)
            out["unknown_refused"] = False
        except ParamError:
            out["unknown_refused"] = True
        try:
            await param.set_param_float("NAV_SPEED_KMH", 1000.0)   # out of range: the value stays
            out["range_refused"] = False
        except ParamError:
            out["range_refused"] = True
        out["speed_after"] = await param.get_param_float("NAV_SPEED_KMH")
    return out


def test_mavsdk_lists_and_sets_companion_parameters(vehicle):
    pytest.importorskip("mavsdk")
    port, parm = vehicle
    result = asyncio.run(asyncio.wait_for(_mavsdk_session(port), HANG_S))
    assert 1 in result["components"] and 191 in result["components"]
    names = set(result["ints"]) | set(result["floats"])
    assert names == {spec.name for spec in REGISTRY}                       # ours, not the simulator's
    assert set(result["ints"]) == {spec.name for spec in REGISTRY if spec.kind is int}
    assert result["ints"]["NAV_MAX_STEPS"] == 1000 and result["ints"]["MPC_HORIZON"] == 2   # C cast, read right
    assert result["floats"]["NAV_SPEED_KMH"] == pytest.approx(50.0)
    assert result["speed"] == pytest.approx(42.0) and result["steps"] == 500
    assert result["range_refused"] and result["speed_after"] == pytest.approx(42.0)
    assert result["unknown_refused"]
    saved = read_parm_file(parm)
    assert saved["NAV_SPEED_KMH"] == pytest.approx(42.0) and saved["NAV_MAX_STEPS"] == 500


class Console:
    """MAVProxy's console through a pipe: lines read by a thread, commands written to stdin."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self._lines = Lines(proc.stdout)
        self.seen = self._lines.seen

    def send(self, command: str) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def wait_for(self, text: str, timeout_s: float) -> str | None:
        return self._lines.wait_for(text, timeout_s)


@pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None,
                    reason="MAVProxy not installed (pip install --no-deps MAVProxy next to pymavlink)")
def test_mavproxy_lists_and_sets_companion_parameters(vehicle, tmp_path):
    port, parm = vehicle
    proc = subprocess.Popen(
        [sys.executable, "-m", "MAVProxy.mavproxy", "--master", f"tcp:127.0.0.1:{port}", "--target-system", "1",
         "--target-component", "191", "--default-modules", "param", "--state-basedir", str(tmp_path / "mavproxy"),
         "--nowait"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
        cwd=tmp_path, env=dict(os.environ, MAVLINK20="1"))
    console = Console(proc)
    try:
        received = console.wait_for("Received", HANG_S)
        assert received is not None, console.seen[-20:]
        assert f"Received {len(REGISTRY)} parameters" in received          # the whole registry, from 191
        console.send("param set NAV_SPEED_KMH 33")
        console.send("param set NAV_MAX_STEPS 444")
        deadline = time.monotonic() + HANG_S
        while time.monotonic() < deadline:
            values = read_parm_file(parm) if parm.exists() else {}
            if values.get("NAV_SPEED_KMH") == 33.0 and values.get("NAV_MAX_STEPS") == 444:
                break
            time.sleep(0.2)
        assert values.get("NAV_SPEED_KMH") == 33.0 and values.get("NAV_MAX_STEPS") == 444, values
        console.send("param set NAV_SPEED_KMH 1000")
        assert console.wait_for("refused", HANG_S) is not None, console.seen[-20:]
        console.send("param show NAV_SPEED_KMH")
        assert console.wait_for("33.0", HANG_S) is not None                    # unchanged
        assert read_parm_file(parm)["NAV_SPEED_KMH"] == 33.0
    finally:
        proc.stdin.close()          # closing stdin quits MAVProxy
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)

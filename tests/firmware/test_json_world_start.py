"""The JSON rig's world starts on every route and every seed's current: a southern home and a westward
or southward current are negative numbers, which argparse took for options ("expected one argument"),
so the world exited at once and ArduPilot never got a frame (seeds 1000, 1003, 1005 of the firmware
Monte Carlo; the Tasman route on every seed).
"""
from __future__ import annotations

import errno
import socket
import time

from fcmpc.firmware.ardupilot_json_rig import start_world
from fcmpc.firmware.processes import stop_process
from sitl.physics.ardupilot_json import json_port
from fcmpc.firmware.instances import claimed_instance
from tests.firmware.conftest import _WORKER

HANG_S = 120.0


def _bound(port: int) -> bool:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("127.0.0.1", port))
        return False
    except OSError as err:
        return err.errno == errno.EADDRINUSE
    finally:
        probe.close()


def test_the_world_starts_south_of_the_equator_in_a_south_westward_current(tmp_path):
    with claimed_instance("ardupilot", 71, 79, 71 + _WORKER % 4) as instance:
        world = start_world(instance, (-40.0, 160.0), (-0.04, -0.03), tmp_path, relay=False)
        try:
            deadline = time.monotonic() + HANG_S      # a hang guard: the event is the world's socket or its exit
            while world.poll() is None and not _bound(json_port(instance)) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert world.poll() is None, (tmp_path / "physics.log").read_text()
            assert _bound(json_port(instance))
        finally:
            stop_process(world, 10.0)

"""The monitor waits for a booting firmware's first heartbeat as long as the firmware runs, not a wall minute.

A real listener that never speaks (a firmware still booting) and a real process standing for the
firmware: while the process runs the wait goes on to the hang guard; once it has exited the wait
ends at the next second with the reason.
"""
from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from fcmpc.firmware.monitor import FirmwareMonitor
from tests.ports import free_port


@pytest.fixture
def silent_port():
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    port = free_port()
    server.bind(("127.0.0.1", port))
    server.listen(1)
    yield port
    server.close()


def test_a_firmware_that_has_exited_is_not_waited_for(silent_port):
    firmware = subprocess.Popen([sys.executable, "-c", "pass"])
    firmware.wait()
    monitor = FirmwareMonitor(f"tcp:127.0.0.1:{silent_port}")
    started = time.monotonic()
    with pytest.raises(RuntimeError, match="exited before its first heartbeat"):
        monitor.start(timeout_s=600.0, alive=lambda: firmware.poll() is None)
    assert time.monotonic() - started < 300.0       # far inside the hang guard: it did not wait for it


def test_a_running_silent_firmware_is_waited_for_to_the_hang_guard(silent_port):
    firmware = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        monitor = FirmwareMonitor(f"tcp:127.0.0.1:{silent_port}")
        with pytest.raises(TimeoutError, match="within 2 s"):
            monitor.start(timeout_s=2.0, alive=lambda: firmware.poll() is None)
        assert firmware.poll() is None
    finally:
        firmware.kill()
        firmware.wait()

"""Helpers for tests that start real processes: wait on events (a file, a message), never on sleeps."""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

__all__ = ["wait_for_file"]


def wait_for_file(path: Path, procs: list[subprocess.Popen], timeout_s: float) -> None:
    """Wait until ``path`` exists (an event a process writes), failing early if a process died.
    The companion creates ``<log-dir>/steps.csv`` right after its MAVLink port is bound."""
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        dead = [p.args[:3] for p in procs if p.poll() is not None]
        assert not dead, f"{dead} exited before writing {path}"
        assert time.monotonic() < deadline, f"{path} not written within {timeout_s:g} s"
        time.sleep(0.05)   # the polling interval of the wait, not a guess at how long a start takes

"""Helpers for tests that start real processes: wait on events (a file, a message), never on sleeps."""
from __future__ import annotations

import queue
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["wait_for_file", "wait_for_listening", "Lines", "reaped"]


class Lines:
    """A process's output read line by line on a thread, so a test can wait for one (an event)."""

    def __init__(self, stream) -> None:
        self.queue: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=lambda: [self.queue.put(line.rstrip()) for line in stream], daemon=True).start()

    def wait_for(self, text: str, timeout_s: float) -> str | None:
        """The first line containing ``text`` within ``timeout_s`` of wall time (a hang guard), else None."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.queue.get(timeout=0.2)
            except queue.Empty:
                continue
            self.seen.append(line)
            if text in line:
                return line
        return None


def wait_for_file(path: Path, procs: list[subprocess.Popen], timeout_s: float) -> None:
    """Wait until ``path`` exists (an event a process writes), failing early if a process died.
    The companion creates ``<log-dir>/steps.csv`` right after its MAVLink port is bound."""
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        dead = [p.args[:3] for p in procs if p.poll() is not None]
        assert not dead, f"{dead} exited before writing {path}"
        assert time.monotonic() < deadline, f"{path} not written within {timeout_s:g} s"
        time.sleep(0.05)   # the polling interval of the wait, not a guess at how long a start takes


def wait_for_listening(port: int, procs: list[subprocess.Popen], timeout_s: float) -> None:
    """Wait until a server accepts TCP connections on 127.0.0.1:``port`` (an event, probed by
    connecting), failing early if a process died."""
    deadline = time.monotonic() + timeout_s
    while True:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        dead = [p.args[:3] for p in procs if p.poll() is not None]
        assert not dead, f"{dead} exited before listening on tcp port {port}"
        assert time.monotonic() < deadline, f"nothing listened on tcp port {port} within {timeout_s:g} s"
        time.sleep(0.05)   # the polling interval of the wait, not a guess at how long a start takes


@contextmanager
def reaped(proc: subprocess.Popen) -> Iterator[subprocess.Popen]:
    """``proc`` for the block; killed and waited for after it if still running (a failed wait)."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()

"""Loopback ports for the tests' real sockets: never shared by two xdist workers, never handed out twice.

The old pattern (bind port 0, read the number, close, let a process bind it later) draws from the
kernel's ephemeral range, where every other port-0 bind and every first ``sendto`` of an unbound
socket also draws. On Linux a UDP socket with SO_REUSEADDR (pymavlink's ``udpin`` sets it) binding
port 0 may even be given a port another SO_REUSEADDR socket holds, and the newer socket then takes
the unicast datagrams. A test could so receive what another test's simulator sent (one CI run: a
stray PARAM_VALUE in ``tests/sitl/fc/test_params.py``).

:func:`free_port` hands out ports *below* the ephemeral range (``ip_local_port_range``), which
port-0 binds never get, from a block of its own per xdist worker (``PYTEST_XDIST_WORKER`` gwN of
``PYTEST_XDIST_WORKER_COUNT``), in turn, so a port is not given again in this process until the
block wraps (a simulator of an earlier test still sending to its old port reaches nobody). Each
port is checked free for UDP and TCP by binding it without SO_REUSEADDR (another program, or a
second pytest session in the same block, may hold it). The start within the block depends on the
process id, so two sessions on one machine rarely walk the same ports.
"""
from __future__ import annotations

import errno
import os
import socket
import threading

__all__ = ["free_port", "port_block"]

LOWEST = 20000          # below: well-known services and MAVLink's 14550/14540/5760 defaults
_lock = threading.Lock()
_next: dict[tuple[int, int], int] = {}


def _ephemeral_range() -> tuple[int, int]:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range", encoding="ascii") as f:
            low, high = (int(v) for v in f.read().split())
        return low, high
    except (OSError, ValueError):
        return 32768, 60999     # Linux's default (macOS: 49152-65535, also above)


def port_block(worker: str | None = None, workers: str | None = None) -> range:
    """This worker's ports: its share of the ports between ``LOWEST`` and the ephemeral range
    (or above it, where that gap is larger).

    >>> a, b = port_block("gw0", "2"), port_block("gw1", "2")
    >>> len(a) > 1000 and not set(a) & set(b)
    True
    """
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0") if worker is None else worker
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") if workers is None else workers
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    count = max(1, int(workers) if workers.isdigit() else 1, index + 1)
    low, high = _ephemeral_range()
    below, above = range(LOWEST, max(LOWEST, low)), range(min(high + 1, 65536), 65536)
    pool = below if len(below) >= len(above) else above
    size = len(pool) // count
    if size < 16:
        raise RuntimeError(f"no room for test ports outside the ephemeral range {low}-{high}")
    return pool[index * size:(index + 1) * size]


def _is_free(port: int) -> bool:
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        with socket.socket(socket.AF_INET, kind) as probe:   # no SO_REUSEADDR: fails on any holder
            try:
                probe.bind(("127.0.0.1", port))
            except OSError as err:
                if err.errno in (errno.EADDRINUSE, errno.EACCES):
                    return False
                raise
    return True


def free_port() -> int:
    """A loopback port nobody holds now (UDP and TCP), not handed out before by this process."""
    block = port_block()
    key = (block.start, block.stop)
    with _lock:
        for _ in range(len(block)):
            k = _next.get(key, os.getpid() * 7919 % len(block))
            _next[key] = (k + 1) % len(block)
            if _is_free(block[k]):
                return block[k]
    raise RuntimeError(f"every port of {block} is in use")

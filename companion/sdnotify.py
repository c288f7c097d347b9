"""systemd's notify protocol, for ``Type=notify`` and ``WatchdogSec=`` (``deploy/fcmpc-companion.service``).

The datagram is written to ``$NOTIFY_SOCKET`` directly (a few lines; ``sd_notify(3)`` documents
the protocol: ``READY=1``, ``WATCHDOG=1``, ``STOPPING=1``, ``STATUS=...``), so no extra package is
needed. Without ``$NOTIFY_SOCKET`` (not started by systemd) every call does nothing. The control
loop calls :meth:`Notifier.watchdog` every iteration; it sends at most every ``WATCHDOG_USEC / 2``
(systemd's advice), so a loop that stalls for longer than ``WatchdogSec`` gets the process
killed and restarted (``Restart=on-failure``).
"""
from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable

__all__ = ["Notifier"]


class Notifier:
    """Writes sd_notify datagrams; a no-op outside systemd."""

    def __init__(self, environ: dict | None = None, wall: Callable[[], float] = time.monotonic) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        if address.startswith("@"):
            address = "\0" + address[1:]          # abstract namespace socket
        self.address = address or None
        usec = env.get("WATCHDOG_USEC", "")
        self.period_s = int(usec) * 1e-6 / 2.0 if usec.isdigit() and int(usec) > 0 else None
        self.wall = wall
        self.sent = 0
        self._next = -float("inf")

    def notify(self, state: str) -> bool:
        """Send one state line; False outside systemd or when the socket refuses."""
        if self.address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                sock.sendto(state.encode("utf-8"), self.address)
        except OSError:
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        """Feed the watchdog if half its period has passed since the last feed."""
        if self.period_s is None:
            return False
        now = self.wall()
        if now < self._next:
            return False
        self._next = now + self.period_s
        return self.notify("WATCHDOG=1")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

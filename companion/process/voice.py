"""What the companion says: STATUSTEXT to the vehicle, a line on stderr, an event in the summary."""
from __future__ import annotations

import math
import sys

from companion.io.link import MavlinkLink, mavlink

__all__ = ["Voice"]


class Voice:
    """Every word the companion says goes through :meth:`say`; ``events`` keeps them with their
    message time (summary.json, the status page)."""

    def __init__(self, link: MavlinkLink, quiet: bool) -> None:
        self.link = link
        self.quiet = quiet
        self.events: list[str] = []

    def stamp(self) -> str:
        """``[message time]``, or ``[no FC time]`` before the first time-stamped message."""
        now = self.link.clock.now_s
        return f"[{now:10.1f}]" if math.isfinite(now) else "[no FC time]"

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT to the vehicle, a line on stderr (unless quiet), an event in the summary."""
        self.events.append(f"{self.stamp()} {text}")
        if not self.quiet:
            print(f"fcmpc-companion {self.stamp()} {text}", file=sys.stderr, flush=True)
        if self.link.conn is not None:
            self.link.send_statustext(text, severity)

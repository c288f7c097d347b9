"""Mode commands the companion sent and the flight controller has not confirmed yet.

A mode change the companion did not command is a pilot's (or a ground station's, or the
autopilot's own failsafe) and is respected; one it did command (HOLD in a failsafe) is its own,
and the mission takes the vehicle back once healthy. Telling the two apart by a flag cleared when
the companion resumes is wrong on a lossy link: a HOLD sent in a failsafe may reach the flight
controller after the companion was healthy again and resumed, and its late HOLD then looked like
a pilot's and paused the mission for good (issue 10, item 1 of the probe).

So each mode command is remembered with the mode it asks for and a deadline (message time
``MODE_CONFIRM_S`` after it was last sent, retries refresh it). It leaves the table only when the
flight controller's HEARTBEAT reports that mode (:meth:`confirm`, :meth:`observe`) or when a
heartbeat received after the deadline still shows another mode (the command was lost; a later
change to that mode is somebody else's). Expiry runs on the message time of the newest
*heartbeat*, not of any message: while heartbeats are lost (the FC streams on, or the link drops
them), the mode the FC is in cannot be seen, and a HOLD it took meanwhile must still be ours when
its heartbeat comes back.

>>> cmds = ModeCommands()
>>> cmds.sent(4, 100.0, "HOLD")
>>> cmds.observe(15, 101.0)               # still GUIDED: the HOLD is on its way
>>> cmds.confirm(4, 103.0)                # the FC reports HOLD: ours
True
>>> cmds.confirm(4, 104.0)                # confirmed once; a later HOLD is somebody else's
False
>>> cmds.sent(4, 200.0, "HOLD"); cmds.observe(15, 200.0 + MODE_CONFIRM_S + 0.1); cmds.pending
{}
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MODE_CONFIRM_S", "ModeCommands", "PendingMode"]

MODE_CONFIRM_S = 10.0   # message time a sent mode command may take to show in the FC's heartbeat


@dataclass(frozen=True)
class PendingMode:
    custom_mode: int        # the HEARTBEAT custom_mode the command asks for
    name: str               # for the words ("HOLD", "GUIDED")
    sent_s: float           # message time of the last (re)send
    deadline_s: float


class ModeCommands:
    """The table: expected custom_mode -> :class:`PendingMode`."""

    def __init__(self, confirm_s: float = MODE_CONFIRM_S) -> None:
        self.confirm_s = confirm_s
        self.pending: dict[int, PendingMode] = {}
        self.confirmed = 0
        self.expired = 0

    def sent(self, custom_mode: int, now_s: float, name: str = "") -> None:
        """A mode command left now (a retry moves the deadline)."""
        self.pending[custom_mode] = PendingMode(custom_mode, name, now_s, now_s + self.confirm_s)

    def confirm(self, custom_mode: int, now_s: float) -> bool:
        """The FC reports ``custom_mode`` in a heartbeat received at message time ``now_s``: True if it
        is a pending command of ours (then it is done)."""
        shown = self.pending.pop(custom_mode, None)   # before expiring: the first heartbeat after a
        self._expire(now_s)                           # silence may be the one that shows it
        if shown is None:
            return False
        self.confirmed += 1
        return True

    def observe(self, custom_mode: int, now_s: float) -> None:
        """The FC's current mode, every tick: a command it shows is done, a late one expires."""
        self.confirm(custom_mode, now_s)

    def clear(self) -> None:
        """Void every pending command (the flight controller rebooted)."""
        self.pending.clear()

    def _expire(self, now_s: float) -> None:
        if not math.isfinite(now_s):
            return
        for mode, cmd in list(self.pending.items()):
            if now_s > cmd.deadline_s:
                del self.pending[mode]
                self.expired += 1

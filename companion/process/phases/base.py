"""What every phase is: ``enter`` / ``run`` / ``exit``, as ArduPilot's modes (``Rover/mode.h``:
``_enter()``, ``update()``, ``_exit()``), and what they return to the driver."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Phase", "Tick", "Transition"]


@dataclass(frozen=True)
class Transition:
    """An event of :mod:`companion.process.machine` to take, and why (the records' words)."""

    event: str
    why: str = ""


@dataclass(frozen=True)
class Tick:
    """A phase's tick: whether it sent a setpoint (None: it says nothing about that), and the
    transition it asks for (None: it stays)."""

    sent: bool | None = None
    transition: Transition | None = None


class Phase:
    """One phase of the machine. The driver (:class:`companion.process.phases.Phases`) calls
    :meth:`exit` of the phase left and :meth:`enter` of the phase entered on each transition,
    and :meth:`run` of the current phase on each control tick. A phase never fires an event
    itself: it returns the transition it wants."""

    state = ""

    def enter(self, now: float, transition: Transition) -> Transition | None:
        """Entered on ``transition`` at message time ``now``; a transition to take at once, if any."""
        return None

    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        """One control tick (``reasons``: the failsafe's, ``dt``: seconds since the last tick)."""
        return Tick()

    def exit(self, now: float) -> None:
        """Left at message time ``now``."""

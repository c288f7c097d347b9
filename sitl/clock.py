"""Simulated time of the SITL: integer microseconds, paced against wall time, optionally in lockstep.

Two clocks, never mixed (see ``ARCHITECTURE.md``): every message carries *simulated* time;
wall time only decides how fast simulated time may advance.

:class:`Pacer` (``--speedup N``)
    simulated time may run at most N times faster than wall time. After a stall (a slow
    client, a lockstep wait) it does not burst to catch up: when more than
    ``rebase_after_s`` of wall time behind schedule it re-bases.
:class:`LockstepGate` (``--lockstep``)
    at every boundary ``B = k * period`` of simulated time the simulator, having sent every
    message stamped up to and including ``B`` (the last one a SYSTEM_TIME with
    ``time_boot_ms = B``), waits until the companion has answered. An answer is

    * a message from a peer whose ``time_boot_ms`` field is at least ``B - slack * period``
      (``slack`` = 1 by default: the companion may be one period behind, so both run in
      parallel; 0 = strict) and not later than ``B + period`` (a larger stamp is not
      simulated time and is treated as untimed), or
    * as long as the peer has never sent a stamped message: any message without a usable
      time stamp (no ``time_boot_ms`` field, or 0), such as HEARTBEAT, COMMAND_LONG or
      TIMESYNC, read while waiting at ``B``.

    The boundary awaited is the newest one whose stamps reached the peer (a link fault may lose or
    hold back what was sent; :mod:`sitl.fc.lockstep`). If no answer arrives within ``timeout_s`` of
    wall time the simulator goes on alone and counts a lockstep timeout: it never deadlocks (given
    the peer's process id it waits while that lives, with a hang guard instead). Before the first message from any peer it
    waits up to ``start_timeout_s`` at ``B = 0`` (0 = for ever).

    Once a peer has sent one stamped message, only stamped messages answer (an untimed
    COMMAND_LONG or HEARTBEAT then no longer does), so a companion must answer every boundary
    with a stamped message, also when it has nothing to command (SET_POSITION_TARGET_*,
    NAMED_VALUE_FLOAT, or an echo of SYSTEM_TIME with ``time_boot_ms`` of the boundary).

    Determinism: the server reads its links only while waiting at a boundary and handles the
    messages in arrival order up to and including the answer; what follows waits for the next
    boundary. Which boundary a message takes effect at is then fixed by the companion's
    message sequence, not by how fast the two processes run, and a deterministic companion
    gives a bit-reproducible closed loop (short of a lockstep timeout, which is wall-clock by
    nature).

    Stamps are compared on the autopilot's boot clock (:attr:`SimClock.boot_us`): after an
    ``fc_reboot`` fault the boundaries' SYSTEM_TIME starts again at 0, and the companion's stamps
    follow once it has confirmed the new boot (:meth:`LockstepGate.rebooted`).
"""
from __future__ import annotations

import time

__all__ = ["US_PER_S", "SimClock", "Pacer", "LockstepGate"]

US_PER_S = 1_000_000


class SimClock:
    """Simulated time in integer microseconds, shared by the simulator's parts.

    Only the simulation loop advances it; everyone else reads ``t_us`` or ``time_s``. ``t_us``
    runs from the simulator's start (faults, truth log, lockstep boundaries, physics); the
    autopilot's *boot* time that its messages carry (``time_boot_ms``, boot-based ``time_usec``)
    is ``boot_us``, the same until an ``fc_reboot`` fault restarts it at 0 (:meth:`reboot`).

    >>> c = SimClock(5_000_000); c.reboot(); c.t_us += 250_000; (c.time_s, c.boot_us, c.boot_ms)
    (5.25, 250000, 250)
    """

    __slots__ = ("boot0_us", "t_us")

    def __init__(self, t_us: int = 0) -> None:
        self.t_us = t_us
        self.boot0_us = 0               # simulated time of the last boot

    @property
    def time_s(self) -> float:
        """Simulated seconds since the simulator started."""
        return self.t_us / US_PER_S

    @property
    def boot_us(self) -> int:
        """Microseconds since the autopilot last booted (the stamps of its messages)."""
        return self.t_us - self.boot0_us

    @property
    def boot_ms(self) -> int:
        """Milliseconds since the autopilot last booted (``time_boot_ms``)."""
        return (self.t_us - self.boot0_us) // 1000

    def reboot(self) -> None:
        """The autopilot boots again now: its boot time restarts at 0 (simulated time goes on)."""
        self.boot0_us = self.t_us


class Pacer:
    """Wall-clock deadline of each simulated instant for a speed-up (None or <= 0: no pacing)."""

    def __init__(self, speedup: float | None, rebase_after_s: float = 0.5, clock=time.perf_counter) -> None:
        self.speedup = speedup if speedup and speedup > 0.0 else None
        self.rebase_after_s = rebase_after_s
        self._clock = clock
        self._wall0 = clock()
        self._sim0_us = 0
        self.rebases = 0

    def deadline(self, sim_us: int) -> float | None:
        """Wall time (``clock`` units) before which ``sim_us`` must not be emitted; None = now."""
        if self.speedup is None:
            return None
        target = self._wall0 + (sim_us - self._sim0_us) / (US_PER_S * self.speedup)
        now = self._clock()
        if now - target > self.rebase_after_s:
            self._wall0, self._sim0_us = now, sim_us
            self.rebases += 1
            return None
        return target

    def restart(self, sim_us: int) -> None:
        """Take ``sim_us`` as happening now (after a wait that should not be made up)."""
        self._wall0, self._sim0_us = self._clock(), sim_us


class LockstepGate:
    """Bookkeeping of the lockstep protocol (the waiting itself is the server's)."""

    def __init__(self, period_s: float, timeout_s: float = 2.0, start_timeout_s: float = 60.0,
                 peer: tuple[int, int] | None = None, slack_periods: int = 1) -> None:
        if not period_s > 0.0:
            raise ValueError(f"lockstep period must be > 0 s, got {period_s}")
        if slack_periods not in (0, 1):
            raise ValueError(f"lockstep slack must be 0 or 1 period, got {slack_periods}")
        self.period_us = int(round(period_s * US_PER_S))
        self.slack_us = slack_periods * self.period_us
        self.timeout_s = timeout_s
        self.start_timeout_s = start_timeout_s
        self.peer = peer
        self.peer_heard = False
        self.peer_time_ms = -1
        self._stamped = False            # the peer has sent a stamped message: only stamps answer now
        self._untimed = False
        self.boundaries = 0
        self.timeouts = 0
        self.consecutive_timeouts = 0
        self.future_stamps = 0
        self.wait_wall_s = 0.0
        self.max_wait_wall_s = 0.0

    def eligible(self, sysid: int, compid: int) -> bool:
        return self.peer is None or (sysid, compid) == self.peer

    def observe(self, time_boot_ms: int | None, now_us: int) -> None:
        """A message from an eligible peer was read at the autopilot's boot time ``now_us`` (us)."""
        self.peer_heard = True
        timed_only = self._stamped
        if time_boot_ms is None or time_boot_ms <= 0:
            self._untimed = self._untimed or not timed_only
            return
        if time_boot_ms * 1000 > now_us + self.period_us:
            self.future_stamps += 1
            self._untimed = self._untimed or not timed_only
            return
        self._stamped = True
        if time_boot_ms > self.peer_time_ms:
            self.peer_time_ms = time_boot_ms

    def rebooted(self) -> None:
        """The autopilot rebooted: the peer's stamps start again with the boot clock. Its stamps of
        the old boot now lie in the future and answer nothing; with one period of slack the first
        boundary after the reboot is free, the next needs the peer on the new boot time."""
        self.peer_time_ms = 0

    @property
    def answered_untimed(self) -> bool:
        """This boundary was answered by an unstamped message (the peer has sent no stamp yet)."""
        return self._untimed

    def satisfied(self, boundary_us: int) -> bool:
        """The peer answered the boundary ``boundary_us`` (boot time, us)."""
        return self._untimed or self.peer_time_ms * 1000 >= boundary_us - self.slack_us

    def finish(self, waited_s: float, timed_out: bool) -> None:
        """End of the wait at one boundary."""
        self.boundaries += 1
        self.wait_wall_s += waited_s
        self.max_wait_wall_s = max(self.max_wait_wall_s, waited_s)
        if timed_out:
            self.timeouts += 1
            self.consecutive_timeouts += 1
        else:
            self.consecutive_timeouts = 0
        self._untimed = False

    def stats(self) -> dict:
        return {"lockstep_boundaries": self.boundaries, "lockstep_timeouts": self.timeouts,
                "lockstep_wait_wall_s": round(self.wait_wall_s, 3),
                "lockstep_max_wait_wall_s": round(self.max_wait_wall_s, 3),
                "lockstep_future_stamps": self.future_stamps}

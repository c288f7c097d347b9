"""How simulated time advances against wall time: pacing by a speed-up, or lockstep with the companion.

:class:`Stepper` runs the waiting half of :mod:`sitl.clock` (whose :class:`~sitl.clock.Pacer`
and :class:`~sitl.clock.LockstepGate` keep the books). Without lockstep it reads the links
while it waits for the next instant's wall deadline. In lockstep, at each boundary
``B = k * period`` it sends everything stamped up to B, ending with SYSTEM_TIME(B), then
handles queued input in arrival order up to and including the message that answers B; the
rest waits for the next boundary, so a deterministic companion gives a bit-reproducible run.
With no answer within ``timeout_s`` of wall time it goes on alone and counts a timeout.
Given the companion's process id (``--lockstep-peer-pid``) it waits as long as that process
lives, however long a loaded machine makes it take, and goes on at once when it has ended: a
test then cannot fail because the machine is busy, and still ends when the companion does.
"""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path

from sitl.clock import LockstepGate, Pacer, SimClock
from sitl.guidance import SEVERITY_WARNING

__all__ = ["Stepper", "process_alive"]

NEVER_US = 1 << 62


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs: False once it has exited, also while it is a zombie that its
    parent (a test, the runner) has not yet reaped. Linux's /proc, else a signal 0.

    >>> process_alive(os.getpid()), process_alive(2 ** 22 + 1)
    (True, False)
    """
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    except OSError:      # no /proc: not Linux
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


class Stepper:
    """Wall-clock pacing of the simulation loop and the lockstep wait at each boundary."""

    def __init__(self, pacer: Pacer, gate: LockstepGate | None, router, out, telemetry, faults, clock: SimClock,
                 stop: threading.Event, peer_pid: int | None = None) -> None:
        self.pacer = pacer
        self.gate = gate
        self.router = router
        self.out = out
        self.telemetry = telemetry
        self.faults = faults            # a link_delay fault holds our frames back
        self.clock = clock
        self.stop = stop
        self.next_us = 0 if gate else NEVER_US   # the next lockstep boundary
        self.peer_pid = peer_pid        # wait while this process lives, not for a wall timeout
        self.peer_gone_s: float | None = None     # simulated time at which it was seen ended

    def pace(self, t_next_us: int) -> None:
        """Wait until ``t_next_us`` may be simulated (reading the links meanwhile unless in lockstep)."""
        lockstep = self.gate is not None
        poll = self.router.poll
        deadline = self.pacer.deadline(t_next_us)
        if deadline is None:
            if not lockstep:
                poll(0.0)
            return
        while not self.stop.is_set():
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                break
            if lockstep:
                time.sleep(min(remaining, 0.05))
            else:
                poll(min(remaining, 0.05))
                self.out.flush()
        if not lockstep:
            poll(0.0)

    def wait_at_boundary(self) -> None:
        """At a boundary: send its marker, then handle queued input in order until the gate opens.

        Messages are handled in arrival order and only up to (and including) the one that
        answers this boundary; the rest waits for the next boundary. Where the simulation
        stops reading therefore depends on the companion's message sequence, not on how fast
        either process runs, and a deterministic companion gives a bit-reproducible run.
        """
        gate, out, poll = self.gate, self.out, self.router.poll
        now_us = self.clock.t_us
        self.next_us = now_us + gate.period_us
        if self.telemetry.last_system_time_us != now_us:
            self.telemetry.send_system_time()
        out.flush()
        start = time.perf_counter()
        if not gate.peer_heard and not self._peer_gone():
            limit = gate.start_timeout_s
            beat = start
            while not gate.peer_heard and not self.router.pending and not self.stop.is_set():
                now = time.perf_counter()
                if limit > 0 and now - start > limit or self._peer_gone():
                    break
                if now - beat >= 1.0:
                    beat = now
                    self.telemetry.send_heartbeat()
                poll(0.1)
                out.flush()
        # a link_delay fault holds our frames back: the companion can only have answered older ones;
        # the companion stamps on our boot clock (an fc_reboot fault restarts it)
        threshold = self.clock.boot_us - self.faults.delay_us
        deadline = time.perf_counter() + gate.timeout_s
        timed_out = False
        while not self.stop.is_set():
            answered = self._handle_pending(threshold)
            out.flush()
            if answered:
                break
            if self.peer_pid is not None:     # no wall timeout: wait while the companion lives
                if self._peer_gone():
                    break
                poll(0.1)
                continue
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                timed_out = True
                break
            poll(min(remaining, 0.1))
        waited = time.perf_counter() - start
        gate.finish(waited, timed_out)
        if timed_out:
            out.say("lockstep_timeout", SEVERITY_WARNING, f"Lockstep: no answer in {gate.timeout_s:g}s, going on")
            out.flush()
        self.pacer.restart(now_us)

    def _peer_gone(self) -> bool:
        """The companion's process (``peer_pid``) has ended: the world no longer waits for it."""
        if self.peer_pid is None:
            return False
        if self.peer_gone_s is None and not process_alive(self.peer_pid):
            self.peer_gone_s = self.clock.time_s
            self.out.say("lockstep_peer_gone", SEVERITY_WARNING,
                         "Lockstep: companion ended, going on alone")
        return self.peer_gone_s is not None

    def stats(self) -> dict:
        """What the summary adds to the gate's books: when the companion's process was seen ended."""
        return {} if self.peer_pid is None else {"lockstep_peer_gone_s": self.peer_gone_s}

    def _handle_pending(self, threshold_us: int) -> bool:
        """Handle queued messages in order until the gate is satisfied (True) or none is left (False).

        Before the companion's clock has started it answers with unstamped messages (its stream
        requests, parameter reads, arming, all in the datagram of one pass): the first of them
        satisfies the gate, and the rest of its datagram is the same answer, handled with it. Taking
        each as the answer to a boundary of its own left the companion's 20-odd start-up requests
        waiting one 0.2 s boundary each (4 s of simulated time, so its parameter reads were retried
        twice and each answered three times)."""
        gate, pending, handle = self.gate, self.router.pending, self.router.handle_frame
        read = None
        while not gate.satisfied(threshold_us):
            if not pending:
                return False
            link, peer, msg, frame, read = pending.popleft()
            handle(link, peer, msg, frame)
        if read is not None and gate.answered_untimed:
            while pending and pending[0][4] == read:
                handle(*pending.popleft()[:4])
        return True

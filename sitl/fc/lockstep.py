"""How simulated time advances against wall time: pacing by a speed-up, or lockstep with the companion.

:class:`Stepper` runs the waiting half of :mod:`sitl.clock` (whose :class:`~sitl.clock.Pacer`
and :class:`~sitl.clock.LockstepGate` keep the books). Without lockstep it reads the links
while it waits for the next instant's wall deadline. In lockstep, at each boundary
``B = k * period`` it sends everything stamped up to B, ending with SYSTEM_TIME(B), then
handles queued input in arrival order up to and including the message that answers B; the
rest waits for the next boundary, so a deterministic companion gives a bit-reproducible run.
The answer awaited is to the newest instant whose stamps reached the companion
(:attr:`sitl.fc.outbox.Outbox.delivered_us`), never to one a link fault lost or still holds:
an answer to what the companion never received cannot come.
With no answer within ``timeout_s`` of wall time it goes on alone and counts a timeout.

Given the companion's process id (``--lockstep-peer-pid``) it waits as long as that process
lives, however long a loaded machine makes it take, and goes on at once when it has ended: a
test then cannot fail because the machine is busy, and still ends when the companion does.
With ``successor`` (``--lockstep-successor``, what ``fcmpc-fly`` runs) a companion restarted
after a crash takes its place: once the process has ended the world waits (up to ``hang_s``)
for a process to bind the UDP port the companion answered from, and then waits on that one
(:func:`udp_port_bound`) instead of running on alone while it starts. A companion that lives
but answers nothing for ``hang_s`` of wall time (a hang guard, 120 s by default, never reached
by a slow machine: a boundary's answer costs milliseconds) ends the run with an error
(``lockstep_hangs`` in the summary, exit code 4), rather than letting the world go on and
silently change the run.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

from sitl.clock import LockstepGate, Pacer, SimClock
from sitl.guidance import SEVERITY_WARNING
from sitl.links import bound_udp_ports

__all__ = ["HANG_S", "Stepper", "process_alive", "udp_port_bound"]

NEVER_US = 1 << 62
HANG_S = 120.0      # wall seconds a live companion may leave a boundary unanswered before it is a hang


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


def udp_port_bound(port: int) -> bool:
    """Whether a UDP socket of this machine is bound to local ``port`` (:func:`sitl.links.bound_udp_ports`):
    a restarted companion binding the same port shows here."""
    return port in bound_udp_ports()


class Stepper:
    """Wall-clock pacing of the simulation loop and the lockstep wait at each boundary."""

    def __init__(self, pacer: Pacer, gate: LockstepGate | None, router, out, telemetry, clock: SimClock,
                 stop: threading.Event, peer_pid: int | None = None, successor: bool = False,
                 hang_s: float = HANG_S) -> None:
        self.pacer = pacer
        self.gate = gate
        self.router = router
        self.out = out                  # .delivered_us: the newest instant the companion can answer (link faults)
        self.telemetry = telemetry
        self.clock = clock
        self.stop = stop
        self.next_us = 0 if gate else NEVER_US   # the next lockstep boundary
        self.peer_pid = peer_pid        # wait while this process lives, not for a wall timeout
        self.successor = successor      # once it has ended, wait on a process holding its port
        self.hang_s = hang_s
        self.peer_port: int | None = None         # the loopback UDP port the companion answers from
        self.peer_gone_s: float | None = None     # simulated time at which it was first seen ended
        self.peer_returns = 0                     # companions that took the port of an ended one
        self.hangs = 0
        self._present = True
        self._alone = False             # no restarted companion came within the guard: not waited for again

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
        gate, out = self.gate, self.out
        now_us = self.clock.t_us
        self.next_us = now_us + gate.period_us
        if self.telemetry.last_system_time_us != now_us:
            self.telemetry.send_system_time()
        out.flush()
        start = time.perf_counter()
        if not gate.peer_heard:
            self._await_first_word(start)
        # the newest instant whose stamps reached the companion (a lost or delayed boundary cannot be
        # answered), on the boot clock the companion stamps with (an fc_reboot fault restarts it)
        threshold = out.delivered_us - self.clock.boot0_us
        timed_out = self._await_answer(threshold, start)
        waited = time.perf_counter() - start
        gate.finish(waited, timed_out)
        if timed_out:
            out.say("lockstep_timeout", SEVERITY_WARNING, f"Lockstep: no answer in {gate.timeout_s:g}s, going on")
            out.flush()
        self.pacer.restart(now_us)

    def _await_first_word(self, start: float) -> None:
        """Before anything from the companion: heartbeats each second of wall time (a companion that
        listens speaks only once it has heard us), up to ``start_timeout_s``, or while its process lives.
        On a companion's PID they are repeated only where the boundary's burst was lost (a loopback
        port nobody had bound): one that got it and is still busy starting would otherwise read an
        extra heartbeat or not depending on the machine's load (3 m apart at the end of the fault
        matrix's mission)."""
        gate, limit, beat = self.gate, self.gate.start_timeout_s, start
        repeat = self.peer_pid is None or self._burst_lost()
        while not gate.peer_heard and not self.router.pending and not self.stop.is_set():
            now = time.perf_counter()
            if self.peer_pid is None:
                if limit > 0 and now - start > limit:
                    return
            elif not self._companion_there(start):
                return
            if now - beat >= 1.0:
                beat = now
                repeat = repeat or self._burst_lost()
                if repeat:
                    self.telemetry.send_heartbeat()
            self.router.poll(0.1)
            self.out.flush()

    def _burst_lost(self) -> bool:
        """A loopback UDP destination of ours that nobody has bound: what we sent there was lost."""
        return any(dest[0] == "127.0.0.1" and not udp_port_bound(dest[1])
                   for dest in (getattr(link, "destination", None) for link in self.out.links) if dest)

    def _await_answer(self, threshold_us: int, start: float) -> bool:
        """Handle queued input until the boundary is answered; True if the wall timeout passed first
        (only without a companion's process to wait on)."""
        out, poll = self.out, self.router.poll
        deadline = time.perf_counter() + self.gate.timeout_s
        while not self.stop.is_set():
            answered = self._handle_pending(threshold_us)
            out.flush()
            if answered:
                return False
            if self.peer_pid is not None:     # no wall timeout: wait while the companion is there
                if not self._companion_there(start):
                    return False
                poll(0.1)
                continue
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                return True
            poll(min(remaining, 0.1))
        return False

    def _companion_there(self, start: float) -> bool:
        """Whether to go on waiting at this boundary (entered at wall time ``start``): the companion's
        process lives or, with ``successor``, a process holds its port (or may still take it, within
        ``hang_s``); a live companion silent for ``hang_s`` is a hang and stops the run."""
        present = process_alive(self.peer_pid) or (
            self.successor and self.peer_port is not None and udp_port_bound(self.peer_port))
        if present != self._present:
            self._present, self._alone = present, False
            if not present:
                self.peer_gone_s = self.peer_gone_s if self.peer_gone_s is not None else self.clock.time_s
                self.out.say("lockstep_peer_gone", SEVERITY_WARNING, "Lockstep: companion ended, going on alone"
                             if not self.successor else "Lockstep: companion ended, waiting for its restart")
            else:   # a restarted companion took the port: it hears the FC and this boundary's time
                self.peer_returns += 1
                self.out.say(None, SEVERITY_WARNING, f"Lockstep: a companion took port {self.peer_port}, waiting on it")
                self.telemetry.send_heartbeat()
                self.telemetry.send_system_time()
            self.out.flush()
        waited = time.perf_counter() - start
        if present and waited > self.hang_s:
            self.hangs += 1
            self.out.say(None, SEVERITY_WARNING, f"Lockstep: companion alive but silent for {self.hang_s:g}s: a hang, stopping")
            self.out.flush()
            print(f"fcmpc-sitl: lockstep: the companion (process {self.peer_pid}, port {self.peer_port}) lives but "
                  f"answered nothing for {self.hang_s:g} s of wall time at {self.clock.time_s:.1f} s: stopping",
                  file=sys.stderr, flush=True)
            self.stop.set()
            return False
        if present or not self.successor or self.peer_port is None or self._alone:
            return present
        if waited <= self.hang_s:
            return True     # a restart takes the port within the guard
        self._alone = True
        self.out.say(None, SEVERITY_WARNING, f"Lockstep: no companion took port {self.peer_port} in {self.hang_s:g}s, "
                                             "going on alone")
        return False

    def stats(self) -> dict:
        """What the summary adds to the gate's books: when the companion's process was seen ended,
        companions that took its port after it, hangs."""
        if self.peer_pid is None:
            return {}
        return {"lockstep_peer_gone_s": self.peer_gone_s, "lockstep_peer_returns": self.peer_returns,
                "lockstep_hangs": self.hangs}

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
        if read is not None and isinstance(peer, tuple) and peer[0] == "127.0.0.1":
            self.peer_port = peer[1]    # the answer's: where a restarted companion binds again
        if read is not None and gate.answered_untimed:
            while pending and pending[0][4] == read:
                handle(*pending.popleft()[:4])
        return True

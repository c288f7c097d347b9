"""The one mission runner: any flight controller, the companion as a process, one outcome.

A flight controller is a small object (:class:`FlightController`): our stand-in
(:class:`fcmpc.fly.standin.StandIn`), or real firmware through
:class:`fcmpc.fly.firmware.FirmwareFC` (ArduPilot with its own boat or with our world as its JSON
physics, PX4 with SIH or with our world over HIL). The runner does the rest, the same way for
every one of them:

1. start the flight controller's processes (:meth:`FlightController.start`);
2. start the companion (``python -m companion.app --connect <the FC's URL>``) and wait until it
   has opened its link (its ``steps.csv`` appears: an event, polled, while the FC is serviced);
3. tell the flight controller (:meth:`FlightController.companion_ready`: the stand-in starts now);
4. watch: progress from the companion's ``steps.csv``, the companion's exit (its code and
   ``summary.json`` say arrived, failed or gave up), the flight controller's own end, the wall
   deadline, SIGINT/SIGTERM;
5. let the vehicle come to rest (:meth:`FlightController.settle`), stop everything by PID, and
   hand back the outcome and the truth track (:meth:`FlightController.truth`).

:class:`MissionProcesses` is steps 1-3 and the stop as a context manager: ``fcmpc-soak`` runs its
attack inside one; :func:`run_mission` adds the watch (``fcmpc-fly``, ``fcmpc-montecarlo --fc``).

Interrupts: the first SIGINT or SIGTERM raises ``KeyboardInterrupt`` wherever the runner waits
(a firmware's start-up too), the children are stopped and the outcome is "interrupted" with exit
code 128 + signal; later ones while the records are written are only noted (SIGINT raises again,
as Ctrl-C does). A child stopped on its own before the mission ended is reported as such, never
as a miss.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

from fcmpc.fly.results import STATUS_EXIT, TruthTrack
from fcmpc.firmware.processes import stop_process

__all__ = ["BIND_TIMEOUT_S", "POLL_S", "REPO", "CompanionRun", "FlightController", "MissionProcesses", "Outcome",
           "child_env", "run_mission", "stopped_by_signal"]

REPO = Path(__file__).resolve().parents[2]
BIND_TIMEOUT_S = 300.0        # a hang guard for the companion to open its link (60 s was short at load 10 beside busy loops)
POLL_S = 0.1


class FlightController(Protocol):
    """What the runner needs of a flight controller; each keeps only what is its own (how to start
    it, its parameters, its physics, where its truth comes from)."""

    name: str                           # said in the progress lines
    companion_args: tuple[str, ...]     # the companion's options this FC needs (``--lockstep`` ...)

    @property
    def companion_url(self) -> str:
        """Where the companion connects (``--connect``), valid once :meth:`start` returned."""

    def start(self, out: Path) -> list[str]:
        """Start the FC's processes before the companion (records under ``out``); what was done to
        it first, in words (a compass calibrated ...)."""

    def companion_ready(self, pid: int) -> None:
        """The companion (process ``pid``) has opened its link."""

    def wait(self, timeout_s: float) -> tuple[str, str] | None:
        """Service the FC for up to ``timeout_s`` of wall time (read its messages, deny GPS at
        arming ...); ``(status, message)`` once it has ended on its own."""

    def settle(self, timeout_s: float) -> None:
        """After the companion's end: until the vehicle is at rest (or nothing to wait for)."""

    def stop(self) -> None:
        """Stop every process of the FC by its PID."""

    def truth(self) -> TruthTrack | None:
        """The true track, once stopped (written to the run's folder too); None if none was recorded."""


@dataclass(frozen=True)
class CompanionRun:
    """How the companion runs: its parameter file, records folder and options beyond ``--connect``,
    ``--params`` and ``--log-dir``; ``nice``: niceness added to it and the FC's children of the
    runner; ``grace_s``: how long it may take to stop after SIGTERM."""

    parm: Path
    log_dir: Path
    args: tuple[str, ...] = ()
    nice: int = 0
    grace_s: float = 10.0

    def argv(self, connect: str, more: tuple[str, ...] = ()) -> list[str]:
        """The companion's command line, connecting to ``connect``, with ``more`` options (the FC's)."""
        return [sys.executable, "-m", "companion.app", "--connect", connect, "--params", str(self.parm),
                "--log-dir", str(self.log_dir), *self.args, *more]


@dataclass(frozen=True)
class Outcome:
    """How a mission ended: status (arrived | failed | timeout | error | interrupted), exit code, words."""

    status: str
    code: int
    message: str = ""


def child_env() -> dict:
    """The environment of the runner's Python children: this checkout first on the path, MAVLink 2,
    one BLAS thread, no display."""
    env = dict(os.environ, MAVLINK20="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def niceness(increment: int) -> Callable[[], None] | None:
    """A ``preexec_fn`` that lowers a child's scheduling priority by ``increment`` (None: keep it)."""
    if increment <= 0:
        return None
    return lambda: os.nice(increment)


def stopped_by_signal(returncode: int) -> bool:
    """A child's exit code after SIGINT/SIGTERM: killed (negative) or 128 + signal."""
    return returncode < 0 or returncode in (128 + signal.SIGINT, 128 + signal.SIGTERM)


class _Interrupts:
    """The first SIGINT/SIGTERM raises KeyboardInterrupt (main thread only) while ``armed``; later
    ones are noted (SIGINT raises again, as Ctrl-C does)."""

    def __init__(self) -> None:
        self.signum = 0
        self.armed = True
        self._old: dict[int, object] = {}

    def __enter__(self) -> _Interrupts:
        if threading.current_thread() is threading.main_thread():
            # SIGINT explicitly too: a background job of a non-interactive shell inherits it ignored
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._old[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum, frame) -> None:  # noqa: ARG002
        first = not self.signum
        self.signum = self.signum or signum
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if first and self.armed:
            raise KeyboardInterrupt(signal.Signals(signum).name)

    def __exit__(self, *exc) -> None:
        for signum, old in self._old.items():
            signal.signal(signum, old)


class MissionProcesses:
    """The flight controller and the companion running (a context manager): entered, both run and
    the companion has opened its link (RuntimeError if it did not); left, both are stopped by PID
    and :attr:`companion_exit` holds the companion's exit code."""

    def __init__(self, fc: FlightController, companion: CompanionRun, out: Path,
                 say: Callable[[str], None] = lambda text: None) -> None:
        self.fc, self.run, self.out, self.say = fc, companion, Path(out), say
        self.companion: subprocess.Popen | None = None
        self.companion_exit: int | None = None
        self._log = None

    def __enter__(self) -> MissionProcesses:
        self.out.mkdir(parents=True, exist_ok=True)
        try:
            for note in self.fc.start(self.out):
                self.say(note)
            self._log = open(self.out / "companion.log", "wb")
            self.companion = subprocess.Popen(
                self.run.argv(self.fc.companion_url, self.fc.companion_args), env=child_env(), cwd=REPO,
                stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT,
                preexec_fn=niceness(self.run.nice))
            self._await_link()
            self.fc.companion_ready(self.companion.pid)
        except BaseException:
            self.stop()
            raise
        return self

    def _await_link(self) -> None:
        bound = self.run.log_dir / "steps.csv"      # created right after the link is open
        deadline = time.monotonic() + BIND_TIMEOUT_S
        while not bound.exists():
            rc = self.companion.poll()
            if rc is not None:
                raise RuntimeError(f"the companion exited with {rc} before opening its link; "
                                   f"see {self.out / 'companion.log'}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the companion did not open its link within {BIND_TIMEOUT_S:g} s")
            ended = self.fc.wait(POLL_S)
            if ended is not None:
                raise RuntimeError(ended[1])

    def stop(self) -> None:
        """Stop the companion, then the flight controller, each by PID (idempotent)."""
        try:
            if self.companion is not None:
                self.companion_exit = stop_process(self.companion, self.run.grace_s)
                if self.companion_exit is None:
                    self.companion_exit = self.companion.returncode
        finally:
            self.fc.stop()
            if self._log is not None:
                self._log.close()
                self._log = None

    def __exit__(self, *exc) -> None:
        self.stop()


def run_mission(fc: FlightController, companion: CompanionRun, out: Path, timeout_s: float,
                progress: Callable[[], None] = lambda: None, say: Callable[[str], None] = lambda text: None,
                settle_s: float = 120.0) -> tuple[Outcome, TruthTrack | None]:
    """Fly one mission to its end (the module docstring): its outcome and the true track.
    ``progress`` is called about every :data:`POLL_S` while the mission runs."""
    wall0 = time.monotonic()
    processes = MissionProcesses(fc, companion, out, say)
    with _Interrupts() as interrupts:
        try:
            with processes:
                outcome = _watch(processes, wall0, timeout_s, progress)
                if outcome.status in ("arrived", "failed"):
                    fc.settle(settle_s)     # the vehicle coasts after the last step
                interrupts.armed = False    # from here on a signal no longer cuts the stop short
        except KeyboardInterrupt:
            outcome = Outcome("interrupted", 130)
        except TimeoutError as err:
            outcome = Outcome("timeout", STATUS_EXIT["timeout"], str(err))
        except (RuntimeError, OSError) as err:
            outcome = Outcome("error", 1, str(err))
        if interrupts.signum:
            message = f"stopped by {signal.Signals(interrupts.signum).name}"
            outcome = Outcome("interrupted", 128 + interrupts.signum,
                              message + (f"; {outcome.message}" if outcome.message else ""))
    return outcome, fc.truth()


def _watch(processes: MissionProcesses, wall0: float, timeout_s: float, progress: Callable[[], None]) -> Outcome:
    """Until the companion exits, the flight controller ends on its own, or ``timeout_s`` (the
    companion's own ``--max-wall-s`` gets 30 s to say it first)."""
    companion, fc, out = processes.companion, processes.fc, processes.out
    deadline = wall0 + timeout_s + 30.0
    while True:
        progress()
        rc = companion.poll()
        if rc is not None:
            return companion_outcome(rc, processes.run.log_dir / "summary.json", out)
        ended = fc.wait(POLL_S)
        if ended is not None:
            status, message = ended
            return Outcome(status, STATUS_EXIT.get(status, 1), message)
        if time.monotonic() > deadline:
            return Outcome("timeout", STATUS_EXIT["timeout"], f"no result within {timeout_s:g} s")


def companion_outcome(rc: int, summary_path: Path, out: Path) -> Outcome:
    """The outcome from the companion's exit code and its ``summary.json``."""
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    if rc == 0 and summary.get("arrived"):
        return Outcome("arrived", 0)
    if rc == 1:
        return Outcome("failed", 1, f"the mission failed: {summary.get('phase', '')}".rstrip(": "))
    if rc == 3:
        return Outcome("timeout", 3, "the companion gave up (--max-wall-s)")
    if stopped_by_signal(rc) or rc == 0:
        return Outcome("interrupted", 130, f"the companion was stopped (exit code {rc}) before the mission ended")
    return Outcome("error", 1, f"the companion exited with {rc}; see {out / 'companion.log'}")

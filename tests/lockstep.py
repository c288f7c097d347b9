"""The stand-in and the companion in lockstep for a test, so that its outcome cannot depend on the
machine's load (docs/developer.md, "Tests and load").

The companion (``--lockstep``) answers every boundary of the stand-in's clock; the stand-in
(``--lockstep --lockstep-peer 1:191 --lockstep-peer-pid PID``) waits for those answers as long as
the companion's process lives, with no wall timeout, and goes on at once when it has ended (a
companion that exits, a test that stops it). A busy machine makes such a run slower, never
different. A ground station or MAVProxy on another ``--out`` is a client: it does not hold the
clock (only 1/191 answers a boundary). Wall time is left to hang guards (``wall_s``,
``--max-wall-s``), which fail only when something truly hangs.

>>> stand_in_lockstep_args(4242)
('--lockstep', '--lockstep-peer', '1:191', '--lockstep-peer-pid', '4242')
"""
from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fcmpc.firmware.processes import stop_process
from tests.ports import free_port
from tests.processes import wait_for_file

__all__ = ["COMPANION_ID", "HANG_S", "LockstepPair", "lockstep_pair", "stand_in_lockstep_args", "stop"]

REPO = Path(__file__).resolve().parents[1]
COMPANION_ID = (1, 191)          # the companion's system and component: the only one to answer
HANG_S = 300.0                   # a hang guard for a wait on an event (a line, a message): only a hang reaches it


def stand_in_lockstep_args(companion_pid: int) -> tuple[str, ...]:
    """The stand-in's options to wait for the companion process ``companion_pid`` alone."""
    return ("--lockstep", "--lockstep-peer", "{}:{}".format(*COMPANION_ID), "--lockstep-peer-pid", str(companion_pid))


def stop(proc: subprocess.Popen | None) -> None:
    """Terminate ``proc`` by PID if it still runs and reap it (killed if it does not end within 10 s)."""
    stop_process(proc, 10.0)


class LockstepPair:
    """The running pair: the processes, the companion's parameter file and records, the ground station's
    port (None without one)."""

    def __init__(self, base: Path, parm: Path, companion: subprocess.Popen, gcs_port: int | None) -> None:
        self.base, self.parm, self.companion, self.gcs_port = base, parm, companion, gcs_port
        self.sitl: subprocess.Popen | None = None

    @property
    def companion_dir(self) -> Path:
        return self.base / "companion"

    @property
    def sitl_dir(self) -> Path:
        return self.base / "sitl"


@contextmanager
def lockstep_pair(base: Path, parm_text: str, companion_args: tuple[str, ...] = (),
                  sitl_args: tuple[str, ...] = (), gcs_port: int | None = None, wall_s: float = 120.0,
                  companion_stderr=subprocess.DEVNULL) -> Iterator[LockstepPair]:
    """The companion (parameter file ``parm_text``, ``companion_args`` more; ``--max-wall-s wall_s`` its
    hang guard), then, once its port is bound, the stand-in in lockstep with it (``sitl_args`` more:
    ``--duration``, a ``--speedup`` cap for a test that talks to it on the wall clock, a scenario), with
    a second ``--out`` to a ground station's ``gcs_port``. Both are stopped after the block."""
    base.mkdir(parents=True, exist_ok=True)
    port = free_port()
    parm = base / "companion.parm"
    parm.write_text(parm_text, encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1")
    companion = subprocess.Popen(
        [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}", "--params", str(parm),
         "--log-dir", str(base / "companion"), "--lockstep", "--max-wall-s", f"{wall_s:g}", "--quiet",
         *companion_args],
        env=env, stdout=subprocess.DEVNULL, stderr=companion_stderr)
    pair = LockstepPair(base, parm, companion, gcs_port)
    try:
        # its port is bound once steps.csv is written (a 60 s guard was short for its start at load 40)
        wait_for_file(base / "companion" / "steps.csv", [companion], HANG_S)
        outs = ["--out", f"udp:127.0.0.1:{port}"]
        if gcs_port is not None:
            outs += ["--out", f"udp:127.0.0.1:{gcs_port}"]
        pair.sitl = subprocess.Popen(
            [sys.executable, "-m", "sitl.fc", *outs, *stand_in_lockstep_args(companion.pid),
             "--log-dir", str(base / "sitl"), "--quiet", *sitl_args],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        yield pair
    finally:
        stop(pair.sitl)
        stop(companion)

"""ArduPilot Rover SITL (``ardurover``) as a process: start, wait until it listens, stop by PID.

The binary is ``$FCMPC_ARDUPILOT`` or ``<project>/../shared/ardupilot/ardurover``; its default
parameter files (``rover.parm``, ``motorboat.parm``) sit in ``default_params/`` beside it.
ArduPilot SITL writes ``eeprom.bin``, ``logs/`` and ``terrain/`` into its working directory,
so each instance gets its own; ``-I N`` shifts every TCP port by ``10 N`` (SERIAL0 5760: the
first client, for which SITL waits before it runs; SERIAL1 5762; SERIAL2 5763).

>>> ArduPilotSitl.ports_for(2)
(5780, 5782)
"""
from __future__ import annotations

import os
import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from companion.params import format_value
from fcmpc.firmware.processes import stop_process

__all__ = ["ArduPilotSitl", "FirmwareMissing", "ardupilot_binary", "instance_free", "project_parm", "read_ardupilot_parm"]

BASE_PORT = 5760


class FirmwareMissing(RuntimeError):
    """The firmware binary is not where it should be (the message says where it looked)."""


def ardupilot_binary() -> Path:
    """``$FCMPC_ARDUPILOT`` or ``<project>/../shared/ardupilot/ardurover``; FirmwareMissing if absent."""
    env = os.environ.get("FCMPC_ARDUPILOT")
    path = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared" / "ardupilot" / "ardurover"
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise FirmwareMissing(f"ArduPilot SITL binary not found or not executable: {path} "
                              f"(set FCMPC_ARDUPILOT to an ardurover built with ./waf configure --board sitl)")
    return path


def project_parm(name: str) -> Path:
    """A parameter file shipped in the project's ``params/`` folder."""
    return Path(__file__).resolve().parents[2] / "params" / name


def read_ardupilot_parm(path: Path) -> dict[str, float]:
    """``NAME VALUE`` (or ``NAME,VALUE``) lines of an ArduPilot parameter file; ``#`` comments."""
    values: dict[str, float] = {}
    for number, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 2:
            raise ValueError(f"{path}:{number}: expected 'NAME VALUE', got {raw.strip()!r}")
        values[parts[0]] = float(parts[1])
    return values


@dataclass
class ArduPilotSitl:
    """One ArduPilot Rover SITL instance; a context manager that stops it on exit.

    ``params``: extra parameters written to a defaults file after the vehicle's own
    (``rover.parm``, ``motorboat.parm`` for the boat) and ``params/ardupilot-rover.parm``
    when ``project_params`` is set. ``home``: (lat, lon) in degrees; heading 0.
    """

    workdir: Path
    instance: int = 0
    home: tuple[float, float] = (33.0, 152.0)
    speedup: float = 50.0
    model: str = "motorboat"
    params: dict[str, float] = field(default_factory=dict)
    project_params: bool = True
    start_unix_s: float | None = None
    binary: Path | None = None
    process: subprocess.Popen | None = None

    @staticmethod
    def ports_for(instance: int) -> tuple[int, int]:
        """(SERIAL0, SERIAL1) TCP ports of an instance."""
        return BASE_PORT + 10 * instance, BASE_PORT + 2 + 10 * instance

    @property
    def serial0(self) -> str:
        return f"tcp:127.0.0.1:{self.ports_for(self.instance)[0]}"

    @property
    def serial1(self) -> str:
        return f"tcp:127.0.0.1:{self.ports_for(self.instance)[1]}"

    @property
    def log_path(self) -> Path:
        return Path(self.workdir) / "ardupilot.log"

    def defaults_files(self, binary: Path) -> list[Path]:
        shipped = binary.parent / "default_params"
        files = [shipped / "rover.parm"]
        if self.model in ("motorboat", "JSON"):     # JSON: our world's boat (sitl.physics), a boat's frame
            files.append(shipped / "motorboat.parm")
        if self.project_params:
            files.append(project_parm("ardupilot-rover.parm"))
        if self.params:
            extra = Path(self.workdir).resolve() / "extra.parm"   # ArduPilot runs in workdir: an absolute path
            extra.write_text("".join(f"{k} {format_value(float(v))}\n" for k, v in self.params.items()))
            files.append(extra)
        return files

    def start(self) -> "ArduPilotSitl":
        binary = self.binary or ardupilot_binary()
        workdir = Path(self.workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        args = [str(binary), "--model", self.model, "--home", f"{self.home[0]},{self.home[1]},0,0",
                "--defaults", ",".join(str(p) for p in self.defaults_files(binary)),
                "--speedup", f"{self.speedup:g}", "-I", str(self.instance), "--wipe"]
        if self.start_unix_s is not None:
            args += ["--start-time", str(int(self.start_unix_s))]
        log = open(self.log_path, "wb")
        try:
            self.process = subprocess.Popen(args, cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True)
        finally:
            log.close()
        return self

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def wait_listening(self, timeout_s: float = 60.0) -> None:
        """Until SERIAL0 accepts TCP connections (an event, polled), or RuntimeError."""
        port = self.ports_for(self.instance)[0]
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process is not None and self.process.poll() is not None:
                raise RuntimeError(f"ardurover exited with {self.process.returncode}; see {self.log_path}")
            if _port_open(port):
                return
            time.sleep(0.05)
        raise RuntimeError(f"ardurover did not listen on {port} within {timeout_s:g} s; see {self.log_path}")

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM by PID, SIGKILL if it does not exit in time; returns the exit code."""
        return stop_process(self.process, timeout_s)

    def __enter__(self) -> "ArduPilotSitl":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _port_open(port: int) -> bool:
    """Whether something listens on 127.0.0.1:port (probed without sending a byte).

    ArduPilot SITL accepts only one client on SERIAL0 and starts running when the first one
    connects, so the probe must not be that client: it checks the listening socket table.
    """
    try:
        with open("/proc/net/tcp") as table:
            rows = table.read().splitlines()[1:]
    except OSError:   # not Linux: fall back to a connect, which SITL then sees as a client
        with socket.socket() as s:
            s.settimeout(0.2)
            return s.connect_ex(("127.0.0.1", port)) == 0
    hex_port = f"{port:04X}"
    return any(r.split()[1].endswith(":" + hex_port) and r.split()[3] == "0A" for r in rows)


def _listening_ports() -> set[int]:
    try:
        with open("/proc/net/tcp") as table:
            rows = table.read().splitlines()[1:]
    except OSError:
        return set()
    return {int(r.split()[1].rsplit(":", 1)[1], 16) for r in rows if r.split()[3] == "0A"}


def instance_free(instance: int, busy: set[int] | None = None) -> bool:
    """Whether nobody listens on instance ``instance``'s SITL ports (``busy``: the listening ports,
    read now when not given)."""
    busy = _listening_ports() if busy is None else busy
    return not busy.intersection(range(BASE_PORT + 10 * instance, BASE_PORT + 10 * instance + 4))

"""PX4 SITL with its built-in SIH simulator as a process: start, wait for its heartbeat, stop by PID.

The firmware is ``$FCMPC_PX4`` (the ``px4`` binary, or the folder holding ``run_sih.sh``) or
``<project>/../shared/px4/``: ``bin/px4`` beside ``etc/`` (PX4's start-up scripts). PX4 SITL
writes its parameters, dataman and logs into its working folder (``-w``), so each instance gets
its own temporary one; ``-i N`` shifts its UDP ports (``px4-rc.mavlink``):

* onboard/offboard link: PX4 sends from 14580+N to 14540+N, where the companion listens
  (``udpin:127.0.0.1:14540+N``); only N <= 9 have their own port (PX4 sends every higher
  instance to 14549), so instances are 0..9;
* ground-station link: PX4 on 18570+N answers whoever talked to it last (and forwards the
  companion's messages there);
* SIH display link: PX4 on 19450+N streams HIL_STATE_QUATERNION, SIH's ground truth, to 19410+N.

``simulator="mavlink"`` starts PX4's MAVLink simulator interface instead of SIH (``PX4_SIMULATOR``
other than ``sihsim`` with the same airframe: ``px4-rc.simulator`` then runs ``px4-rc.mavlinksim``,
``simulator_mavlink start -c 4560+N``): our world is the physics (:mod:`sitl.physics.px4_hil`), and
PX4 runs in lockstep with it (its sensor simulators ``sensor_*_sim`` start only with SIH).

Parameters are applied at start through PX4's own ``PX4_PARAM_<NAME>=<value>`` environment
variables (``rcS`` sets them after the airframe's defaults), from ``params/px4-rover.params``
(QGroundControl's format) and ``params``. Home is ``SIH_LOC_LAT0/LON0`` (``PX4_HOME_LAT/LON``).

PX4's MAVLink links come from ``px4-rc.mavlink``, which ``rcS`` finds on ``PATH``: with
``simulator="mavlink"`` the instance's ``bin/`` holds ``params/px4-hil-mavlink.rc`` under that name
(:data:`HIL_LINKS_RC`: the GCS and onboard links only, without PX4's camera and gimbal links and the
onboard streams nobody reads); SIH keeps PX4's own.

The shipped ``bin/`` holds PX4's module aliases (``px4-param`` ...) as text files naming
``px4`` where a checkout lost its symbolic links; the start-up script runs them through
``PATH``, so each instance gets a ``bin/`` of real links in its working folder first on ``PATH``.

>>> Px4Sitl.ports_for(3)
(14543, 18573, 19413)
"""
from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from fcmpc.firmware.ardupilot import FirmwareMissing, project_parm
from fcmpc.firmware.processes import stop_process
from sitl.links import bound_udp_ports

__all__ = ["HIL_LINKS_RC", "MAX_INSTANCE", "PX4_MODEL", "Px4Sitl", "px4_instance_free", "px4_root", "read_qgc_params"]

MAX_INSTANCE = 9          # px4-rc.mavlink: instances above 9 share the offboard port 14549
PX4_MODEL = "sihsim_rover_ackermann"
# Set on every simulated PX4 before the caller's parameters. SDLOG_BACKEND 0: no ULog (rc.logging
# starts the logger unless it is 0; SDLOG_MODE -1 did not stop it, ~78 MB per few armed minutes);
# the companion's steps.csv and the monitor's truth are the record
SIMULATOR_PARAMS = {"SDLOG_BACKEND": 0}
PARAM_TYPE_INT32, PARAM_TYPE_REAL32 = 6, 9    # MAV_PARAM_TYPE in QGroundControl's .params
HIL_LINKS_RC = "px4-hil-mavlink.rc"     # params/: PX4's px4-rc.mavlink in lockstep with our world


def px4_root() -> Path:
    """The folder with ``bin/px4`` and ``etc/``: ``$FCMPC_PX4`` (the binary or its folder's parent)
    or ``<project>/../shared/px4``; FirmwareMissing if absent."""
    env = os.environ.get("FCMPC_PX4")
    path = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared" / "px4"
    root = path.parent.parent if path.is_file() else path
    binary = root / "bin" / "px4"
    if not (binary.is_file() and os.access(binary, os.X_OK) and (root / "etc" / "init.d-posix").is_dir()):
        raise FirmwareMissing(f"PX4 SITL not found or not executable: {binary} (with etc/ beside bin/; "
                              f"set FCMPC_PX4 to a px4 built with make px4_sitl_sih)")
    return root


def read_qgc_params(path: Path) -> dict[str, float]:
    """QGroundControl's ``.params``: ``vehicle component NAME value type`` per line (tabs), ``#`` comments.

    Raises ValueError naming the file and line for a malformed line.
    """
    values: dict[str, float] = {}
    for number, raw in enumerate(Path(path).read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 5 or int(parts[4]) not in (PARAM_TYPE_INT32, PARAM_TYPE_REAL32):
            raise ValueError(f"{path}:{number}: expected 'SYSID COMPID NAME VALUE TYPE' with type 6 or 9, "
                             f"got {raw.strip()!r}")
        value = float(parts[3])
        values[parts[2]] = float(int(value)) if int(parts[4]) == PARAM_TYPE_INT32 else value
    return values


def _format(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


@dataclass
class Px4Sitl:
    """One PX4 SIH instance; a context manager that stops it on exit.

    ``home``: (lat, lon) degrees, altitude 0 m (the field is the route's, at sea level).
    ``speed_factor``: PX4_SIM_SPEED_FACTOR (simulated seconds per wall second). ``params``:
    parameters after ``params/px4-rover.params`` (when ``project_params``) and :data:`SIMULATOR_PARAMS`.
    """

    workdir: Path
    instance: int = 1
    home: tuple[float, float] = (33.0, 152.0)
    speed_factor: float = 5.0
    model: str = PX4_MODEL
    params: dict[str, float] = field(default_factory=dict)
    project_params: bool = True
    root: Path | None = None
    simulator: str = "sih"          # "sih": PX4's own physics; "mavlink": simulator_mavlink (lockstep, ours)
    process: subprocess.Popen | None = None

    @staticmethod
    def ports_for(instance: int) -> tuple[int, int, int]:
        """(companion's listening port, PX4's ground-station port, SIH truth listening port)."""
        return 14540 + instance, 18570 + instance, 19410 + instance

    @property
    def companion_url(self) -> str:
        return f"udpin:127.0.0.1:{self.ports_for(self.instance)[0]}"

    @property
    def gcs_url(self) -> str:
        return f"udpout:127.0.0.1:{self.ports_for(self.instance)[1]}"

    @property
    def truth_url(self) -> str:
        return f"udpin:127.0.0.1:{self.ports_for(self.instance)[2]}"

    @property
    def system_id(self) -> int:
        return self.instance + 1          # rcS: MAV_SYS_ID = instance + 1

    @property
    def log_path(self) -> Path:
        return Path(self.workdir) / "px4.log"

    def all_params(self) -> dict[str, float]:
        values = read_qgc_params(project_parm("px4-rover.params")) if self.project_params else {}
        return {**values, **SIMULATOR_PARAMS, **self.params}

    def environment(self, root: Path) -> dict[str, str]:
        bin_dir = Path(self.workdir) / "bin"
        bin_dir.mkdir(parents=True, exist_ok=True)
        real = (root / "bin" / "px4").resolve()
        for alias in (root / "bin").glob("px4-*"):
            link = bin_dir / alias.name
            if alias.suffix != ".sh" and not link.exists():
                link.symlink_to(real)
        if self.simulator == "mavlink":
            shutil.copyfile(project_parm(HIL_LINKS_RC), bin_dir / "px4-rc.mavlink")
        env = {k: v for k, v in os.environ.items() if not k.startswith("PX4_")}
        env.update({"PATH": f"{bin_dir}{os.pathsep}{env.get('PATH', '')}", "PX4_WORKDIR": str(self.workdir),
                    "PX4_INSTANCE": str(self.instance), "PX4_SIM_MODEL": self.model, "PX4_CLEAN": "1",
                    "PX4_HOME_LAT": repr(float(self.home[0])),
                    "PX4_HOME_LON": repr(float(self.home[1])), "PX4_HOME_ALT": "0"})
        if self.simulator == "mavlink":
            env["PX4_SIMULATOR"] = "mavlink"        # anything but sihsim/gz: px4-rc.mavlinksim
        else:
            env["PX4_SIM_SPEED_FACTOR"] = f"{self.speed_factor:g}"
        env.update({f"PX4_PARAM_{name}": _format(value) for name, value in self.all_params().items()})
        return env

    def start(self) -> Px4Sitl:
        if self.simulator not in ("sih", "mavlink"):
            raise ValueError(f"PX4 simulator must be 'sih' or 'mavlink', got {self.simulator!r}")
        if not 0 <= self.instance <= MAX_INSTANCE:
            raise ValueError(f"PX4 instance must be 0..{MAX_INSTANCE}, got {self.instance}")
        root = self.root or px4_root()
        self.workdir = Path(self.workdir).resolve()   # PX4 changes into it; PATH and -w must not be relative
        Path(self.workdir).mkdir(parents=True, exist_ok=True)
        log = open(self.log_path, "wb")
        try:
            # run_sih.sh forces SIH; simulator_mavlink runs the binary as that script does (-d: no shell)
            command = ["/bin/sh", str(root / "run_sih.sh")] if self.simulator == "sih" else \
                [str(root / "bin" / "px4"), "-d", "-i", str(self.instance), "-w", str(self.workdir), str(root / "etc")]
            self.process = subprocess.Popen(command, cwd=self.workdir,
                                            env=self.environment(root), stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True)
        finally:
            log.close()
        return self

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM by PID (run_sih.sh execs px4, so the PID is PX4's), SIGKILL if it does not exit."""
        return stop_process(self.process, timeout_s)

    def __enter__(self) -> Px4Sitl:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def px4_instance_free(instance: int, busy: set[int] | None = None) -> bool:
    """Whether PX4 instance ``instance`` has no lock file (``/tmp/px4_lock-N``) and nobody has bound
    its UDP ports (``busy``: the bound ports, read now when not given)."""
    busy = bound_udp_ports() if busy is None else busy
    ports = {14540 + instance, 14580 + instance, 18570 + instance, 19410 + instance, 19450 + instance}
    return not busy & ports and not Path(f"/tmp/px4_lock-{instance}").exists()

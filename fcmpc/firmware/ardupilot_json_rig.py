"""``fcmpc-fly --fc ardupilot --physics json``: ArduPilot SITL with our world as its physics, in lockstep.

The rig starts the world's process (``python -m sitl.physics.ardupilot_json``: the boat, the
current, the waves, the companion's relay), then ArduPilot with ``--model JSON`` in its own folder
and ``-I`` instance, the monitor on SERIAL0 as with the built-in motorboat, and gives the companion
the relay's port and ``--lockstep`` (a stamped message every setpoint period). Everything the
built-in path does on top (the real compass's errors and its fixed-yaw calibration, GPS denied at
arming, SIMSTATE as the truth: ArduPilot's copy of our state) is the same
(:class:`fcmpc.firmware.ardupilot_rig.ArduPilotRig`). Each process is stopped by its PID. On a machine
with room the world and ArduPilot share one CPU (:func:`share_core`: they take turns, and a wake-up across
cores is the dearest part of a frame on a VM), the monitor and the companion the others.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

from fcmpc.firmware.ardupilot_rig import REPO, ArduPilotRig, FirmwareFlight
from fcmpc.firmware.processes import stop_process
from sitl.physics.relay import relay_port

__all__ = ["ArduPilotJsonRig", "JSON_PARAMS", "start_world", "stop_world", "motor_field", "share_core"]

# The physics rate is ours (one frame per 20 ms timestamp); SIM_RATE_HZ only seeds the packet's frame_rate.
# SITL's IMU samples once per physics frame, and arming checks that the gyro runs at >= 1.8 x the loop rate
# ("Arm: Gyro 0 rate 50Hz < loop ratex1.8 90Hz", measured): at 50 Hz physics the INS bit (16) of the arming
# checks is left out (every other check stays); 100 Hz physics would pass it at twice the frames.
ARMING_CHECKS_BUT_INS = (1 << 20) - 2 - 16
# CRUISE_THROTTLE: the throttle of our boat at the companion's 8 m/s (BoatDynamics: 10 m/s at full
# throttle), tuned as a boat's user tunes it (params/ardupilot-rover.parm's 63 % is SITL's motorboat's)
CRUISE_THROTTLE_PCT = 80
# SIM_DRIFT_SPEED 0: SITL adds its own gyro drift to the IMU we send (AP_InertialSensor_SITL::gyro_drift: a
# triangle ramp of 0.05 deg/s per minute for SIM_DRIFT_TIME 5 minutes, the same on all three axes, 0.25 deg/s
# at its peak); measured on a 20 km leg, 0.10-0.15 deg/s on every axis while the boat ran straight, and
# ArduPilot's pitch 3-4 deg off our world's once GPS was gone. Our world's IMU is the IMU here.
# Each MAVLink port carries what its reader asks for (SET_MESSAGE_INTERVAL) and not ArduPilot's default stream
# groups (MAVn_*, SRn_* before 4.7; n = 1 is SERIAL0, 2 SERIAL1), which sent about 25 messages at 1 Hz to each
# (measured in the companion's tlog) that neither reads: ArduPilot spent CPU packing them, the world relaying
# them and the companion and the monitor parsing them. The companion's port (SERIAL1, at SITL's default 57600
# baud modelled as 1,920 bytes/s of firmware time) ran full, its output trailing the firmware's clock by a queue
# the relay's latency has to cover: 921600 baud, as a companion's link is wired on a boat. The monitor (SERIAL0)
# keeps EXTRA1 (ATTITUDE just before SIMSTATE: the truth's firmware time) and EXTRA2 (VFR_HUD); the companion's
# port keeps POSITION (GLOBAL_POSITION_INT, LOCAL_POSITION_NED at 1 Hz): the companion started its clock on the
# first timed message (since e92147c it asks for its streams at the first heartbeat too), and before its streams
# flow these are the relay's only firmware times (with POSITION off, 49, 6 and 0 of the companion's first frames
# reached ArduPilot late, up to 3.8 s, against 1, 1 and 0 with it; no CPU measurably saved: the note, section 7,
# "CPU per simulated hour, second pass"). SERIAL2
# (params/ardupilot-rover.parm's companion port on a boat; SERIAL1 here) is off: SITL polled its TCP listener
# with 3-4 select() calls every loop (strace), for nobody.
# fcmpc-fly's rig makes the companion's port private: MAV2_OPTIONS bit 1 (NO_FORWARD, "don't forward MAVLink to or
# from this port"; SERIALn_OPTIONS bit 10 before 4.7; MAVLink_routing::check_and_forward returns at once for a
# private channel's frames, which ArduPilot still processes). ArduPilot then no longer copies the companion's
# broadcast frames (10 Hz GPS_INPUT, 5 Hz setpoints, heartbeats, texts) onto SERIAL0, where fcmpc-fly's monitor
# decoded only to drop them (its records come from the companion's own log; nothing it sends is for the
# companion): fly's CPU -23 % on 20 km legs. The tests' rig keeps the forwarding: they read the companion's
# STATUSTEXT on the monitor.
PRIVATE_COMPANION_PORT = {"MAV2_OPTIONS": 2}
_UNREAD_GROUPS = ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA3", "ADSB")
PORT_PARAMS = {"SERIAL1_BAUD": 921, "SERIAL2_PROTOCOL": -1, **{f"MAV1_{group}": 0 for group in _UNREAD_GROUPS},
               **{f"MAV2_{group}": 0 for group in _UNREAD_GROUPS + ("EXTRA1", "EXTRA2") if group != "POSITION"}}
# The motor's field on the compass (sitl.physics.motor_field): the shared binary's JSON backend carries no battery
# current, so SIM_MAG_MOT would act on nothing; the world makes that field itself from the throttle, through
# SIM_MAG1_OFS, over the relay's SERIAL1 link; a world without a relay over SERIAL2 (its own link, every stream
# group off: it reads nothing), which SITL polls three times a loop once connected (strace)
MOTOR_LINK_PARAMS = {"SERIAL2_PROTOCOL": 2, **{f"MAV3_{group}": 0 for group in _UNREAD_GROUPS + ("EXTRA1", "EXTRA2")}}
_MOT = ("SIM_MAG_MOT_X", "SIM_MAG_MOT_Y", "SIM_MAG_MOT_Z")
HOLD_REAL_COMPASS_S = 300.0
# share_core only on a machine with room: pinned, the pair cannot use the other core's idle moments, which a busy
# machine's scheduler gives it. 20 km legs beside main (the JSON note, section 13): 7-14 % less wall a simulated
# hour at a load average of 6-7 on 2 cores, 3-7 % more at 11-17; an idle machine is where the pin pays most.
SHARE_CORE_BELOW_LOAD_PER_CPU = 2.0


def motor_field(params: dict, relay: bool = False) -> tuple[dict, str | None]:
    """ArduPilot's parameters and the world's ``--motor-field`` for a compass's ``params``: a SIM_MAG_MOT
    leaves ArduPilot (where it would act on no current) for the world, with the offsets and soft iron it
    is applied through; without one, (``params``, None). ``relay``: the world has the companion's relay,
    whose SERIAL1 link carries the field (no SERIAL2).

    >>> motor_field({"SIM_MAG_MOT_X": -0.71, "SIM_MAG_MOT_Z": 0.68})[1]
    '-0.71,0,0.68;0,0,0;1,1,1;0,0,0'
    """
    if not any(params.get(name, 0.0) for name in _MOT):
        return dict(params), None

    def vector(prefix: str, default: float) -> str:
        return ",".join(f"{params.get(prefix + axis, default):g}" for axis in "XYZ")

    text = ";".join((vector("SIM_MAG_MOT_", 0.0), vector("SIM_MAG1_OFS_", 0.0), vector("SIM_MAG1_DIA_", 1.0),
                     vector("SIM_MAG1_ODI_", 0.0)))
    return {**params, **{name: 0.0 for name in _MOT}, **({} if relay else MOTOR_LINK_PARAMS)}, text


# LOG_FILE_RATEMAX: ArduPilot's own cap on each streaming message's rate in its dataflash log (AP_Logger's rate
# limiter; every message type stays in the log). Rover logs its EKF cores' XKF1-5/XKQ/XKFS and IMU, PIDs, ATT,
# SIM at 25-50 Hz: 110 MB a simulated hour (3 GB for the Pacific) to pack and write (the JSON note, section 7).
# At 10 Hz a boat's hours-long log keeps every record the rig's analyses read (GPA, XKF, ATT, SIM every 0.1 s
# over minutes-long manoeuvres); the flight does not read its log. INS_LOG_BAT_MASK 0: rover.parm's IMU batch
# sampler (raw gyro and accelerometer bursts for a vibration FFT) off: our world's IMU has no vibration.
LOG_RATE_MAX_HZ = 10
JSON_PARAMS = {"SIM_RATE_HZ": 50, "ARMING_CHECK": ARMING_CHECKS_BUT_INS, "CRUISE_THROTTLE": CRUISE_THROTTLE_PCT,
               "SIM_DRIFT_SPEED": 0, "LOG_FILE_RATEMAX": LOG_RATE_MAX_HZ, "INS_LOG_BAT_MASK": 0, **PORT_PARAMS}


class ArduPilotJsonRig(ArduPilotRig):
    """ArduPilot SITL (--model JSON) + the world's process + the monitor."""

    name = "ArduPilot SITL (our world as its physics, lockstep)"
    companion_args = ("--lockstep",)

    def __init__(self, flight: FirmwareFlight, out: Path) -> None:
        super().__init__(flight, out)
        self.sitl.model = "JSON"
        self.sitl.speedup = 1e6            # ArduPilot never waits on the wall clock: our frames pace it
        self.sitl.params, self.world_motor_field = motor_field({**self.sitl.params, **JSON_PARAMS,
                                                                **PRIVATE_COMPANION_PORT}, relay=True)
        self.motor_field = self.world_motor_field is not None
        self.out = out
        self.flight = flight
        self.world: subprocess.Popen | None = None
        self.core: int | None = None       # the CPU the world and ArduPilot share (share_core)
        self._affinity: set[int] | None = None   # this thread's CPUs before the rig took the pair's core from it

    def start(self):
        f = self.flight
        # the companion starts after the rig's preparation: with a real compass the motor run-up (about 100 s
        # of firmware time after the fixed-yaw calibration) has to fit before the world waits for it
        self.world = start_world(f.instance, f.start, f.current_en_mps, self.out, motor_field=self.world_motor_field,
                                 hold_from_s=HOLD_REAL_COMPASS_S if f.compass.startswith("real") else None)
        monitor = super().start()
        self.core = share_core((self.world.pid, self.sitl.process.pid), f.instance, SHARE_CORE_BELOW_LOAD_PER_CPU)
        if self.core is not None:
            # this thread (the monitor) and what it starts from now on (the companion) keep off the pair's core:
            # left free, the scheduler woke them on it (the relay's writes to the companion are a wake-up there)
            self._affinity = os.sched_getaffinity(0)
            os.sched_setaffinity(0, self._affinity - {self.core})
        return monitor

    def alive(self) -> bool:
        return super().alive() and self.world is not None and self.world.poll() is None

    @property
    def companion_url(self) -> str:
        return f"tcp:127.0.0.1:{relay_port(self.flight.instance)}"

    def stop(self) -> None:
        stop_world(self.world, self.sitl, self.out, shared_core=self.core)
        if self._affinity is not None:
            os.sched_setaffinity(0, self._affinity)    # a Monte Carlo worker flies its next run with every CPU
            self._affinity = None


def share_core(pids: tuple[int, ...], instance: int, below_load_per_cpu: float = math.inf) -> int | None:
    """Put the lockstep pair (the main threads of the world and ArduPilot) on one CPU, the instance's among those
    this process may use (instances side by side take turns), and return it; None on a single CPU, where
    affinity cannot be set, or when the load average (1 min) reaches ``below_load_per_cpu`` times the CPUs.
    Their other threads (ArduPilot's logger, which wakes every wall millisecond) go to the other CPUs. The pair
    takes turns (each waits for the other's frame; left free, only the world's step after its answer overlapped
    ArduPilot's loop), and a wake-up on the other core costs an inter-processor interrupt: a UDP ping-pong on
    this 2-core VM took 54-57 us a round trip across the cores and 12-14 us on one (the JSON note, section 13)."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    if len(cpus) < 2 or not os.getloadavg()[0] < below_load_per_cpu * len(cpus):
        return None
    cpu = cpus[instance % len(cpus)]
    for pid in pids:
        try:
            tids = [int(tid) for tid in os.listdir(f"/proc/{pid}/task")]
        except OSError:
            tids = [pid]
        for tid in tids:
            try:
                os.sched_setaffinity(tid, {cpu} if tid == pid else set(cpus) - {cpu})
            except OSError:
                pass            # a thread gone meanwhile
    return cpu


def start_world(instance: int, home: tuple[float, float], current_en_mps: tuple[float, float],
                out: Path, relay: bool = True, motor_field: str | None = None,
                hold_from_s: float | None = None) -> subprocess.Popen:
    """The world's process for ArduPilot instance ``instance`` (before ArduPilot starts): its log
    ``physics.log`` and, once stopped, its statistics ``physics.json`` in ``out``. Without ``relay``
    no companion link and no lockstep wait (ArduPilot runs as fast as the world answers);
    ``motor_field``: its ``--motor-field`` (:func:`motor_field`); ``hold_from_s``: its ``--hold-from-s``."""
    east, north = current_en_mps
    with open(out / "physics.log", "wb") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "sitl.physics.ardupilot_json", "--instance", str(instance),
             f"--home={home[0]!r},{home[1]!r}", f"--current-en={east!r},{north!r}",   # '=': "-0.04,..." is a value
             "--stats", str(out / "physics.json"), *([] if relay else ["--no-relay"]),
             *([f"--motor-field={motor_field}"] if motor_field else []),
             *(["--hold-from-s", f"{hold_from_s:g}"] if hold_from_s is not None else [])],
            cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log, start_new_session=True)


def stop_world(world: subprocess.Popen | None, sitl, out: Path, **more) -> dict:
    """Stop the world, then ArduPilot (blocked in its wait for a frame it does not act on SIGTERM:
    SIGKILL after a second), each by its PID; returns the world's statistics with ArduPilot's CPU
    seconds and ``more`` added (also written to ``physics.json``)."""
    firmware_cpu_s = _cpu_s(sitl.process)
    stop_process(world, 10.0)
    sitl.stop(timeout_s=1.0)
    path = out / "physics.json"
    try:
        stats = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    stats["ardupilot_cpu_s"] = firmware_cpu_s
    stats.update(more)
    path.write_text(json.dumps(stats, indent=1))
    return stats


def _cpu_s(proc: subprocess.Popen | None) -> float | None:
    """User + system CPU seconds of a running child (Linux /proc), None when unknown."""
    if proc is None or proc.poll() is not None:
        return None
    try:
        with open(f"/proc/{proc.pid}/stat") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
